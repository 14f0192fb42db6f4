"""Stage 4: rasterize the training views' G-buffers (OpenGL) in the run's local frame (``RunContext.origin``: the
mesh is already in it), and decide what the bundle shows where the mesh is not (skyboxes or a clear colour)."""

from __future__ import annotations

import numpy as np
import torch

from ...geometry.mesh import MeshData
from ...neural.model import view_inputs
from ...neural.shader_inputs import ShaderInputs
from ...neural.skybox import SkyboxGround, SkyboxLayers, plan_layers
from ...playback.rasterize import rasterize_gbuffer
from ...render.far_region import opaque_depths
from .. import choices, rules
from ..cache import digest
from ..stage_results import (
    Backdrop,
    CameraSplit,
    GeometryResult,
    TeacherResult,
    TrainingViews,
    load_gbuffer,
)
from .context import RunContext


def gbuffer_stage(ctx: RunContext, views: CameraSplit, teacher: TeacherResult, geometry: GeometryResult,
                  inputs: ShaderInputs) -> tuple[TrainingViews, Backdrop]:
    """The G-buffers of the training views (stored as ``gbuffer``), the shader's view inputs, and the backdrop."""
    from ...neural.skybox import SkyboxModel

    cfg, train, mesh = ctx.cfg, views.train, geometry.mesh
    ctx.clock.start("gbuffer", f"rasterizing {mesh.num_faces} faces for {len(train)} views (OpenGL)")
    smoothing = choices.shading_normals(mesh, inputs.use_facing or inputs.reflect, cfg.texture.normal_smoothing,
                                        ctx.decisions, roughness=inputs.normal_roughness_deg)
    local_mesh = MeshData(mesh.vertices, mesh.faces, mesh.uvs, mesh.stats, core_faces=mesh.core_faces,
                          normal_smoothing=smoothing)
    key = digest("gbuffer", ctx.keys["geometry"], train.to_json(), cfg.geometry.cull_back_faces,
                 *(("normal smoothing", smoothing) if smoothing else ()))
    local_cameras = ctx.local(train)
    cull = cfg.geometry.cull_back_faces
    gbuffer = ctx.cached_files("gbuffer", key,
                               lambda folder: rasterize_gbuffer(local_mesh, local_cameras, cull_back_faces=cull,
                                                                out=folder),
                               lambda folder: load_gbuffer(folder, mmap=True),
                               lambda: rasterize_gbuffer(local_mesh, local_cameras, cull_back_faces=cull))
    dirs = shader_view_inputs(ctx, train, gbuffer, inputs, local_mesh.core_faces)
    use_skybox, reason = choices.skyboxes(cfg.skybox.mode, gbuffer.coverage, ctx.background, ctx.decisions)
    skybox, sky_origins, sky_pixels = None, None, None
    if use_skybox:
        sb = cfg.skybox
        region = getattr(ctx.field, "far_region", None)
        sky_pixels = choices.sky_training_pixels(
            teacher.surface_depths, teacher.fringe_depths, gbuffer.coverage, train.centers.numpy(), dirs[..., :3],
            ctx.field.aabb, ctx.decisions, opacities=teacher.opacities,
            seen_through=None if region is None else lambda fringe: _opaque_beyond_box(ctx, train, dirs, fringe))
        layers = views.sky_layers
        learnt = ~gbuffer.coverage if sky_pixels is None else sky_pixels
        up = train.c2w[:, :3, 1].double().mean(0).numpy()
        share = rules.below_horizon_share(dirs[..., :3], learnt, up)
        if sb.layers == 0:        # automatic: finer depth layers for skyboxes that hold ground
            count = choices.skybox_layers(share, ctx.decisions)
            if count != layers.num_layers:
                layers = plan_layers(ctx.field.aabb, train.centers.double().numpy(), num_layers=count,
                                     near=float(layers.half_sizes[0]), far=float(layers.half_sizes[-1]),
                                     resolution=layers.resolution)
        layers = _on_the_ground(ctx, train, dirs, learnt, up, share, layers)
        codes = sb.num_codes or choices.skybox_codes(share, ctx.decisions)
        skybox = SkyboxModel(layers, feature_dim=sb.feature_dim, num_codes=codes, hidden=sb.hidden)
        sky_origins = layers.relative(train.centers.double().numpy()).numpy()
    missed = ~gbuffer.coverage
    if use_skybox or (missed.any() and not ctx.background.constant):
        # the clear colour: what the missed training pixels show on average (skyboxes draw over it)
        clear = torch.as_tensor(teacher.images[missed].mean(axis=0) if missed.any() else np.zeros(3),
                                dtype=torch.float32)
    else:
        clear = ctx.background.colour
    ctx.clock.done(key=key, coverage=float(gbuffer.coverage.mean()), skyboxes=use_skybox, skybox_reason=reason)
    return TrainingViews(ctx.origin, local_mesh, gbuffer, dirs), Backdrop(skybox, sky_origins, reason, clear, sky_pixels)


def shader_view_inputs(ctx: RunContext, train, gbuffer, inputs: ShaderInputs, core_faces: int | None) -> np.ndarray:
    """(N, H, W, C) float32 ``neural.model.view_inputs`` of every training pixel (world ray directions first,
    reflected about the shading normal where the mesh covers the pixel with ``inputs.reflect``),
    filled view by view into ``ctx.scratch_array`` (memory-mapped in the work area): like the G-buffers, never
    all in memory at once."""
    n, h, w = gbuffer.coverage.shape
    columns = 3 + int(inputs.use_facing) + int(core_faces is not None)
    dirs = ctx.scratch_array("view_inputs", (n, h, w, columns), np.float32)
    for i in range(n):
        normal = None if gbuffer.normal is None else gbuffer.normal[i]
        dirs[i] = view_inputs(train.rays(i)[1].numpy(), gbuffer.face_id[i], normal, inputs.use_facing, core_faces,
                              reflect=inputs.reflect)
    return dirs


def _on_the_ground(ctx: RunContext, train, dirs, learnt, up: np.ndarray, share_below: float,
                   layers: SkyboxLayers) -> SkyboxLayers:
    """``layers`` cut by the field's ground (``choices.skybox_ground``) when they hold one.

    Probes at most ``rules.GROUND_PROBE_RAYS`` of the skyboxes' training pixels (``learnt`` (N, H, W) bool) that
    look below the horizon, evenly over them in view order: where each ray (``dirs`` (N, H, W, 3+) world, from
    the training camera's centre) first reaches opacity 0.5 over the field's whole extent, marched in the run's
    local frame (``ctx.origin``).
    """
    up = up / max(float(np.linalg.norm(up)), 1e-30)
    region = getattr(ctx.field, "far_region", None)
    if share_below < rules.SKY_GROUND_SHARE or region is None:
        choices.skybox_ground(share_below, None, np.zeros(0), ctx.decisions)
        return layers
    limit = -np.sin(np.radians(rules.SKY_HORIZON_DEG))
    picked = [np.asarray(learnt[i]).reshape(-1) & (np.asarray(dirs[i, ..., :3]).reshape(-1, 3) @ up < limit)
              for i in range(len(train))]
    o, d, _ = _probe_rays(ctx, train, dirs, picked, rules.GROUND_PROBE_RAYS)
    t = opaque_depths(ctx.local_field, region, o, d, steps=rules.GROUND_PROBE_STEPS)
    reached = torch.isfinite(t)
    hits = (o[reached] + t[reached, None] * d[reached]).numpy() + (ctx.origin - layers.center)
    camera_heights = (train.centers.double().numpy() - layers.center) @ up
    heights, measured = rules.ground_heights(hits, up, layers.half_sizes, camera_heights)
    hit_share = float(reached.double().mean()) if len(t) else 0.0
    if not choices.skybox_ground(share_below, hit_share, heights, ctx.decisions, probed_rays=int(len(t)),
                                 **measured):
        return layers
    return SkyboxLayers(layers.center, layers.half_sizes, layers.resolution, SkyboxGround(up, heights))


def _probe_rays(ctx: RunContext, train, dirs, picked: list[np.ndarray], limit: int
                ) -> tuple[torch.Tensor, torch.Tensor, list[np.ndarray]]:
    """At most ``limit`` of the training pixels marked in ``picked`` (per view, (H*W,) bool), evenly over them
    in view order: (origins (R, 3) float64 in the run's local frame (``ctx.origin``: small numbers), directions
    (R, 3) float64 world, the chosen pixel numbers of each view)."""
    chosen = [np.flatnonzero(p) for p in picked]
    stride = max(1, -(-sum(len(p) for p in chosen) // limit))
    origins, directions, seen = [], [], 0
    for i, p in enumerate(chosen):
        chosen[i] = p[(-seen) % stride::stride]
        seen += len(p)
        directions.append(np.asarray(dirs[i, ..., :3]).reshape(-1, 3)[chosen[i]].astype(np.float64))
        origins.append(np.repeat(train.centers[i].double().numpy()[None], len(chosen[i]), axis=0))
    o = torch.from_numpy(np.concatenate(origins) - ctx.origin)
    return o, torch.from_numpy(np.concatenate(directions)), chosen


def _opaque_beyond_box(ctx: RunContext, train, dirs, candidates: np.ndarray) -> np.ndarray:
    """(N, H, W) bool: the ``candidates`` (N, H, W) bool training pixels whose whole ray, marched through the
    field's far region, first reaches opacity 0.5 outside the foreground box grown by
    ``rules.NEAR_MISS_BOX_MARGIN`` of its diagonal (at most ``rules.SEE_THROUGH_PROBE_RAYS`` of them probed)."""
    n, h, w = candidates.shape
    out = np.zeros((n, h * w), bool)
    if not candidates.any():
        return out.reshape(n, h, w)
    o, d, chosen = _probe_rays(ctx, train, dirs, [candidates[i].reshape(-1) for i in range(n)],
                               rules.SEE_THROUGH_PROBE_RAYS)
    t = opaque_depths(ctx.local_field, ctx.field.far_region, o, d, steps=rules.SEE_THROUGH_PROBE_STEPS)
    box = torch.as_tensor(ctx.field.aabb).double().reshape(2, 3).cpu().numpy() - ctx.origin
    grow = rules.NEAR_MISS_BOX_MARGIN * float(np.linalg.norm(box[1] - box[0]))
    reached = torch.isfinite(t).numpy()
    hit = (o + torch.where(torch.isfinite(t), t, torch.zeros_like(t))[:, None] * d).numpy()
    beyond = reached & ~np.all((hit >= box[0] - grow) & (hit <= box[1] + grow), axis=1)
    start = 0
    for i, pixels in enumerate(chosen):
        out[i, pixels] = beyond[start:start + len(pixels)]
        start += len(pixels)
    return out.reshape(n, h, w)
