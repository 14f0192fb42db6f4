"""Stage 5: train the neural texture (feature atlas, codebook, shader) and the skyboxes on the teacher's
renders, resuming from the last training checkpoint of a killed run."""

from __future__ import annotations

from ...geometry.unwrap import atlas_shape
from ...neural.model import NeuralTextureModel
from ...neural.shader_inputs import ShaderInputs
from ...neural.train import fit
from ...neural.train_batches import TrainingPixels
from ...neural.train_checkpoint import TrainCheckpoint
from .. import choices
from ..cache import digest
from ..stage_results import (
    Backdrop,
    DistilledModel,
    TeacherResult,
    TrainedModel,
    TrainingPlan,
    TrainingViews,
)
from .context import RunContext, settings
from .plan import plateau_stop, training_seconds


def distill_stage(ctx: RunContext, teacher: TeacherResult, plan: TrainingPlan, training: TrainingViews,
                  inputs: ShaderInputs, backdrop: Backdrop) -> DistilledModel:
    """The trained model and skybox (stored as ``distill``; training checkpoints under ``work/checkpoints``)."""
    cfg, t = ctx.cfg, ctx.cfg.texture
    height, side, pages = atlas_shape(training.mesh.stats)
    ctx.clock.start("distill", (f"{pages} pages of " if pages > 1 else "")
                    + f"{side}^2 x {t.feature_dim} feature atlas, "
                               + (f"{t.num_codes} codes, " if t.quantize else "no VQ, ")
                               + f"MLP {t.num_layers}x{t.hidden}{'' if inputs.use_viewdir else ' (no view input)'}"
                               + (f" (shell {t.shell_hidden or t.hidden})" if len(training.mesh.layers()) == 2 else "")
                               + ", "
                               f"{plan.steps} steps" + (f" (at most {plan.time_budget_s:.0f} s)"
                                                        if plan.time_budget_s else ""))
    coarse = choices.coarse_level(t.coarse_factor, plan, ctx.decisions)
    model = NeuralTextureModel.for_atlas(t, height, side, inputs, pages=pages,
                                         mesh_layers=len(training.mesh.layers()), coarse_factor=coarse)
    skybox = backdrop.skybox
    key = digest("distill", ctx.keys["gbuffer"], ctx.keys["plan"], plan.steps, plan.time_budget_s,
                 settings(cfg.texture), settings(cfg.train, ("checkpoint_every_s",)), settings(cfg.skybox),
                 inputs.use_viewdir, inputs.use_facing, inputs.core_viewdir, coarse, skybox is not None,
                 skybox.layers.to_json() if skybox is not None else None, backdrop.clear,
                 *(() if backdrop.sky_pixels is None else ("sky pixels", backdrop.sky_pixels)))
    checkpoint = (TrainCheckpoint(ctx.cache.work / "checkpoints" / f"distill-{key}.pt", key,
                                  every_s=cfg.train.checkpoint_every_s, log=ctx.log) if ctx.cache is not None else None)

    def train() -> TrainedModel:
        gb = training.gbuffer
        train_fn = fit if ctx.pool is None else ctx.pool.fit      # --nproc N: data-parallel over the workers
        views = TrainingPixels(gb.uv, gb.coverage, training.dirs, teacher.images, origins=backdrop.sky_origins,
                               sky_pixels=backdrop.sky_pixels)
        log = train_fn(model, views, steps=plan.steps, config=cfg.train, time_budget_s=training_seconds(ctx, plan),
                       skybox=skybox, checkpoint=checkpoint, device=ctx.device, progress=ctx.step_counter(),
                       stop=plateau_stop(ctx, plan))
        if log.resumed_from_step:
            ctx.log(f"distill: continued from the checkpoint at step {log.resumed_from_step}")
        return TrainedModel.of(model, skybox, log.as_dict())

    trained = ctx.cached("distill", key, train, TrainedModel.save, TrainedModel.load)
    trained.load_into(model, skybox)
    if checkpoint is not None:
        checkpoint.remove()
    if bool(model.vq_skipped):
        touched = int(model.touched.sum())
        choices.vector_quantization_skipped(touched, t.quantize_above, t.num_codes, ctx.decisions)
    ctx.clock.done(key=key, **{k: v for k, v in trained.log.items() if k != "entries"})
    return DistilledModel(model, skybox, trained.log)
