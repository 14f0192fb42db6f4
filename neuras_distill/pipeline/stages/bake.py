"""Stage 6: bake the trained model into the bundle OpenGL plays (quantized feature textures, the shader as
GLSL, the mesh relative to the scene's origin, the plain RGB texture) and save it into the run folder."""

from __future__ import annotations

from ...bake.bundle import Bundle, bake
from ...bake.plain_texture import plain_texture_rgb8
from ...playback.shaders import VERTEX_SHADER
from .. import choices, rules
from ..stage_results import Backdrop, CameraSplit, DistilledModel, TeacherResult, TrainingViews
from .context import RunContext


def bake_stage(ctx: RunContext, views: CameraSplit, teacher: TeacherResult, training: TrainingViews,
               distilled: DistilledModel, backdrop: Backdrop) -> Bundle:
    """The bundle, with every decision taken so far in its manifest's ``left_out`` (the bake adds the codes it
    dropped); saved as ``<run>/bundle``."""
    cfg = ctx.cfg
    ctx.clock.start("bake", "quantized features -> textures, MLP -> GLSL")
    blend = choices.silhouette_blend(cfg.texture.soft_silhouettes, rules.fringe_width_pixels(teacher.opacities),
                                     views.train, views.test, ctx.decisions)
    left_out = ctx.decisions.left_out()
    bundle = bake(distilled.model, training.mesh, background_color=backdrop.clear.tolist(),
                  vertex_shader=VERTEX_SHADER,
                  extra_manifest={"left_out": left_out, "view_dependence": distilled.model.use_viewdir,
                                  "cull_back_faces": cfg.geometry.cull_back_faces, "silhouette_blend": blend},
                  skybox=distilled.skybox, origin=training.origin)
    choices.baked_leftovers(bundle.manifest["left_out"][len(left_out):], ctx.decisions)
    # the plain RGB texture (the glTF export's base colour, the report's baseline) travels in the bundle
    gb = training.gbuffer
    bundle.plain_rgb = plain_texture_rgb8(distilled.model, bundle.mesh, gb.uv, gb.coverage, training.dirs)
    if ctx.root is not None:
        bundle.save(ctx.root / "bundle")
    ctx.clock.done(num_codes=int(bundle.manifest.get("num_codes", cfg.texture.num_codes)))
    return bundle
