"""Stage 7: the bundle against the field on the held-out cameras: error (PSNR, SSIM, FLIP, interior and
silhouette bands, holes), GL vs torch parity, frame times of both, the plain-texture baseline, the field's
error against run time, and the lane-shifted views of scenes that define them."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from ...bake.bundle import Bundle
from ...playback.projection import shift_cameras
from ...playback.rasterize import rasterize_gbuffer
from ...playback.renderer import BundleRenderer
from ...render.cameras import Cameras
from ...render.far_region import far_steps_at
from ...render.occupancy import OccupancyGrid
from ...render.volume import VolumeRenderer
from .. import evaluate
from ..cache import digest
from ..stage_results import Backdrop, CameraSplit, DistilledModel, Evaluation, FieldViews, TrainingViews
from .context import RunContext, settings

if TYPE_CHECKING:
    from ...fields.base import Field


def evaluation_stage(ctx: RunContext, views: CameraSplit, teacher: VolumeRenderer, training: TrainingViews,
                     distilled: DistilledModel, backdrop: Backdrop, bundle: Bundle) -> Evaluation:
    """Everything the report measures; the field's held-out renders are stored as ``field_views``."""
    cfg, test, origin = ctx.cfg, views.test, training.origin
    ctx.clock.start("evaluate", f"{len(test)} held-out views at {test.width}x{test.height}: field vs bundle")
    parts: dict[str, float] = {}
    mark = [time.perf_counter()]

    def lap(name: str) -> None:
        now = time.perf_counter()
        parts[name] = now - mark[0]
        mark[0] = now

    def render_held_out() -> FieldViews:
        out = evaluate.render_field_views(teacher, test, ctx.progress_printer("field (held-out)"))
        return FieldViews(out.images, out.opacities, out.seconds)

    key = digest("field_views", ctx.fingerprint, test.to_json(), settings(cfg.teacher))
    field_views = ctx.cached("field_views", key, render_held_out, FieldViews.save, FieldViews.load)
    field_images = field_views.images
    lap("field_views")
    player = BundleRenderer(bundle)
    bundle_images = [player.render(test, i) for i in range(len(test))]
    quality = evaluate.compare(bundle_images, field_images)
    lap("bundle_views")
    cull = cfg.geometry.cull_back_faces
    local_test = shift_cameras(test, origin)
    parity = evaluate.gl_torch_parity(distilled.model, training.mesh, local_test, bundle_images[0],
                                      backdrop.clear.numpy(),
                                      lambda m, c: rasterize_gbuffer(m, c, cull_back_faces=cull),
                                      skybox=distilled.skybox, world_cameras=test,
                                      silhouette_blend=player.silhouette_blend)
    lap("parity")
    t_fid = time.perf_counter()
    coverages = evaluate.bundle_coverage(lambda c: rasterize_gbuffer(training.mesh, c, cull_back_faces=cull),
                                         local_test)
    fidelity, flip_maps = evaluate.fidelity(bundle_images, field_images, field_views.opacities, coverages)
    fidelity_seconds = time.perf_counter() - t_fid
    lap("fidelity")
    ablation = None
    if distilled.skybox is not None and cfg.skybox.ablation:
        no_sky = evaluate.compare([player.render(test, i, skybox=False) for i in range(len(test))], field_images)
        ablation = {"psnr_with_skyboxes": quality["psnr"], "psnr_without_skyboxes": no_sky["psnr"],
                    "drop_db": quality["psnr"] - no_sky["psnr"],
                    "how": "the same bundle played without its skybox pass; pixels the mesh misses get the mean "
                           "colour of the training pixels it misses"}
    lap("ablation")
    timing = player.time_frames(test, warmup=5, frames=cfg.eval.fps_frames)
    lap("bundle_timing")
    plain = evaluate.plain_texture_baseline(distilled.model, bundle, training.gbuffer, training.dirs, test,
                                            field_images, bundle_images, coverages, cfg.eval.fps_frames)
    lap("plain_texture")
    grid = curve_occupancy(ctx, teacher)
    far = cfg.teacher.far_steps / cfg.teacher.num_steps        # the far region's samples scale with the box's
    points = evaluate.error_vs_runtime(lambda s: VolumeRenderer(ctx.field, num_steps=s, occupancy=grid,
                                                                far_steps=far_steps_at(s, far)), test,
                                       2 * cfg.teacher.num_steps, cfg.eval.runtime_steps,
                                       cfg.teacher.num_steps, player,
                                       main_render=(field_images[0], field_views.seconds[0]))
    lap("error_vs_runtime")
    extrapolation, extra_views = lane_shift_views(ctx.field, teacher, player, test)
    lap("lane_shifts")
    ctx.clock.done(psnr=quality["psnr"], ssim=quality["ssim"], parity_psnr=parity, flip=fidelity["flip"],
                   hole_fraction=fidelity["hole_fraction"], fidelity_seconds=fidelity_seconds)
    return Evaluation(field_views, bundle_images, quality, parity, fidelity, flip_maps, fidelity_seconds, ablation,
                      timing, player.silhouette_blend, plain, points, extrapolation, extra_views, parts)


def curve_occupancy(ctx: RunContext, teacher: VolumeRenderer):
    """The occupancy grid the error-vs-runtime curve's renderers share, built at most once. A density field's
    does not depend on the step count: the teacher's (for the plain-PyTorch nerfacto field each build cost
    23 s). An SDF's margin grows with the step: one grid for the coarsest step of the curve holds every cell a
    finer march needs (on the NeuS fixture each build cost 5 s of a 40 s test run). "auto" for a field with its
    own grid."""
    if ctx.field.kind == "density" and teacher.occupancy is not None:
        return teacher.occupancy
    if ctx.field.kind != "sdf" or teacher.occupancy is None or callable(getattr(ctx.field, "occupancy_grid", None)):
        return "auto"
    coarsest = min([*ctx.cfg.eval.runtime_steps, ctx.cfg.teacher.num_steps])
    return OccupancyGrid.from_field(ctx.field, ctx.cfg.teacher.occupancy_resolution,
                                    step=teacher.diagonal / max(coarsest, 1))


def lane_shift_views(field: Field, teacher: VolumeRenderer, player: BundleRenderer, test: Cameras,
                     views: int = 2) -> tuple[dict | None, dict]:
    """Extrapolation as the paper evaluates it, for fields that declare lane shifts (``field.lane_shifts``,
    metres): the first ``views`` held-out cameras moved sideways by each shift, field vs bundle.
    Returns ({"+2 m": {"psnr", "ssim"}, ...} or None, {image name: [(field, bundle), ...]})."""
    shifts = getattr(field, "lane_shifts", None)
    if not shifts:
        return None, {}
    sub = test[list(range(min(views, len(test))))]
    results, images = {}, {}
    for shift in shifts:
        cams = sub.lane_shifted(float(shift))
        field_images, _ = evaluate.render_field_timed(teacher, cams)
        bundle_images = [player.render(cams, i) for i in range(len(cams))]
        q = evaluate.compare(bundle_images, field_images)
        results[f"{float(shift):+g} m"] = {"psnr": q["psnr"], "ssim": q["ssim"]}
        images[f"lane_{float(shift):+g}m"] = list(zip(field_images, bundle_images))
    return results, images
