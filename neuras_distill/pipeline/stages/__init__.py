"""The run's stages, each a function of the run's context (:class:`RunContext`) and earlier stages' results
(``pipeline.stage_results``) returning its own; ``pipeline.run._run`` calls them in order."""

from .bake import bake_stage
from .context import RunContext, StageClock, seed_stage
from .distill import distill_stage
from .evaluation import evaluation_stage
from .gbuffer import gbuffer_stage
from .geometry import geometry_stage, used_texels
from .plan import fix_steps, plan_limits
from .teacher import render_teacher, split_cameras

__all__ = ["RunContext", "StageClock", "seed_stage", "split_cameras", "render_teacher", "plan_limits",
           "geometry_stage", "used_texels", "fix_steps", "gbuffer_stage", "distill_stage", "bake_stage",
           "evaluation_stage"]
