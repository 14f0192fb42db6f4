"""Stages 1 and 2: split the cameras and volume-render the training views (the teacher)."""

from __future__ import annotations

import json
import time

import numpy as np

from ...errors import require
from ...render.cameras import Cameras
from ...render.volume import VolumeRenderer
from .. import choices, evaluate, rules
from ..cache import digest
from ..stage_results import CameraSplit, TeacherResult
from .context import RunContext, settings


def split_cameras(ctx: RunContext, cameras: Cameras, held_out: Cameras | None = None) -> CameraSplit:
    """Hold out every ``cameras.test_every``-th camera (or, given ``held_out``, train on every one of
    ``cameras`` and evaluate on ``held_out``), size both sets, write ``cameras.json`` and plan the skybox layers
    (which checks the user's distances before any rendering)."""
    from ...neural.skybox import plan_layers

    cfg = ctx.cfg
    if held_out is None:
        ctx.clock.start("cameras", f"{len(cameras)} cameras, holding out every {cfg.cameras.test_every}th")
        train_full, test_full = cameras.split(cfg.cameras.test_every)
    else:
        ctx.clock.start("cameras", f"{len(cameras)} training cameras, {len(held_out)} held out as given")
        train_full, test_full = cameras, held_out
    train_width = rules.capped_width(cfg.teacher.train_width, train_full.width)
    eval_width = (rules.capped_width(cfg.eval.width, test_full.width, cfg.eval.max_upscale) if cfg.eval.width
                  else test_full.width)
    choices.render_widths(test_full.width, train_width, eval_width, cfg, ctx.decisions)
    train = with_extra_views(ctx, train_full.resized(train_width), cameras)
    test = test_full.resized(eval_width) if cfg.eval.width else test_full    # 0: the cameras' own size
    if ctx.root is not None:
        (ctx.root / "cameras.json").write_text(json.dumps({"train": train.to_json(), "test": test.to_json()}))
    sky_layers = None
    if cfg.skybox.mode != "off":
        sky = cfg.skybox
        sky_layers = plan_layers(ctx.field.aabb, cameras.centers.double().numpy(),
                                 num_layers=sky.layers or rules.SKY_LAYERS[0],
                                 near=sky.near or None, far=sky.far or None, resolution=sky.resolution)
    ctx.clock.done(train=len(train), test=len(test), train_size=[train.width, train.height],
                   test_size=[test.width, test.height])
    return CameraSplit(train, test, sky_layers)


def with_extra_views(ctx: RunContext, train: Cameras, cameras: Cameras) -> Cameras:
    """``train`` followed by the extra views the run adds around it (``choices.extra_views``): whether the mesh
    will get a fringe shell is judged as the geometry stage judges it (the threshold scales with the views'
    width) on at most 8 of the training views at half their width (a sixteenth of the teacher's work at most:
    the nerfstudio fixture's field took 68 s for 8 views at full width), the look-at distances from a
    32-pixel-wide render of each; the views seeded by ``train.seed``. Cameras inside the field's box (a path
    through the scene) get views along their path (``extra_views.path_views``) when turned "on"."""
    from ...render import extra_views

    c = ctx.cfg.cameras
    inside = extra_views.inside_box(cameras, ctx.field.aabb)
    if c.extra_views == "off" or (c.extra_views == "auto" and inside.any()):
        choices.extra_views(c.extra_views, inside, False, len(train), c.extra_views_fraction, ctx.decisions)
        return train
    if inside.any():                # "on" for a path through the scene: views along it, not turned off it
        count = choices.extra_views(c.extra_views, inside, False, len(train), c.extra_views_fraction, ctx.decisions)
        return train.joined(extra_views.path_views(train, count, c.extra_views_deg, ctx.cfg.train.seed))
    probe = ctx.volume_renderer
    shell = False
    if c.extra_views == "auto":
        sample = train[list(range(0, len(train), max(1, len(train) // 8)))[:8]].resized(max(64, train.width // 2))
        opacities = np.stack([probe.render(sample, i)["opacity"] for i in range(len(sample))])
        shell = choices.fringe_shell(ctx.cfg.geometry.enclose_fringe, opacities, ctx.background,
                                     choices.Decisions())
    count = choices.extra_views(c.extra_views, inside, shell, len(train), c.extra_views_fraction, ctx.decisions)
    if count == 0:
        return train
    distances = extra_views.look_at_distances(probe, train)
    return train.joined(extra_views.extra_views(train, distances, count, c.extra_views_deg, ctx.cfg.train.seed))


def render_teacher(ctx: RunContext, views: CameraSplit) -> tuple[VolumeRenderer, TeacherResult]:
    """The field's renders of the training views (stored as ``teacher``): (the volume renderer, reused for the
    held-out views, the renders)."""
    cfg, train = ctx.cfg, views.train
    ctx.clock.start("teacher", f"volume-rendering {len(train)} training views at {train.width}x{train.height}, "
                               f"{cfg.teacher.num_steps} steps/ray")
    teacher = ctx.volume_renderer

    def render_lists():
        t0 = time.perf_counter()
        render_views = ctx.pool.render_views if ctx.pool is not None else evaluate.render_field_views
        out = render_views(teacher, train, ctx.progress_printer("teacher"), depths=True)
        return out, time.perf_counter() - t0

    def render() -> TeacherResult:
        out, seconds = render_lists()
        return TeacherResult(np.stack(out.images).astype(np.float32), np.stack(out.opacities),
                             np.stack(out.surface_depths), np.stack(out.fringe_depths), seconds=seconds)

    key = digest("teacher", ctx.fingerprint, train.to_json(), settings(cfg.teacher))
    # written view by view, then memory-mapped: the renders are not held in memory through the later stages
    result = ctx.cached_files("teacher", key, lambda folder: TeacherResult.write_views(folder, *render_lists()),
                              lambda folder: TeacherResult.load(folder, mmap=True), render)
    require(bool(np.isfinite(result.images).all()), "the field renders NaN or Inf colours; check its parameters")
    ctx.clock.done(views=len(train), key=key, render_seconds=result.seconds)
    return teacher, result
