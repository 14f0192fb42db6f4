"""Stage 4: rasterize the training views' G-buffers (OpenGL) relative to the scene's origin, and decide what
the bundle shows where the mesh is not (skyboxes or a clear colour)."""

from __future__ import annotations

import numpy as np
import torch

from ...geometry.mesh import MeshData
from ...neural.model import view_inputs
from ...playback.projection import shift_cameras
from ...playback.rasterize import rasterize_gbuffer
from .. import choices
from ..cache import digest
from ..stage_results import Backdrop, CameraSplit, GeometryResult, ShaderInputs, TeacherResult, TrainingViews
from ..stage_results import load_gbuffer, save_gbuffer
from .context import RunContext


def scene_origin(field) -> np.ndarray:
    """(3,) float64: the foreground box's centre. GL and training work relative to it, so a scene far from its
    world origin keeps float32 precision."""
    aabb64 = np.asarray(torch.as_tensor(field.aabb).double().reshape(2, 3).cpu().numpy())
    return 0.5 * (aabb64[0] + aabb64[1])


def gbuffer_stage(ctx: RunContext, views: CameraSplit, teacher: TeacherResult, geometry: GeometryResult,
                  inputs: ShaderInputs) -> tuple[TrainingViews, Backdrop]:
    """The G-buffers of the training views (stored as ``gbuffer``), the shader's view inputs, and the backdrop."""
    from ...neural.skybox import SkyboxModel

    cfg, train, mesh = ctx.cfg, views.train, geometry.mesh
    ctx.clock.start("gbuffer", f"rasterizing {mesh.num_faces} faces for {len(train)} views (OpenGL)")
    origin = scene_origin(ctx.field)
    smoothing = choices.shading_normals(mesh, inputs.use_facing, cfg.texture.normal_smoothing, ctx.decisions)
    local_mesh = MeshData((mesh.vertices.astype(np.float64) - origin).astype(np.float32), mesh.faces, mesh.uvs,
                          mesh.stats, core_faces=mesh.core_faces, normal_smoothing=smoothing)
    key = digest("gbuffer", ctx.keys["geometry"], train.to_json(), cfg.geometry.cull_back_faces,
                 *(("normal smoothing", smoothing) if smoothing else ()))
    gbuffer = ctx.cached("gbuffer", key,
                         lambda: rasterize_gbuffer(local_mesh, shift_cameras(train, origin),
                                                   cull_back_faces=cfg.geometry.cull_back_faces),
                         save_gbuffer, load_gbuffer)
    ray_dirs = np.stack([train.rays(i)[1].numpy() for i in range(len(train))])      # (N, H, W, 3) world
    dirs = view_inputs(ray_dirs, gbuffer.face_id, gbuffer.normal, inputs.use_facing, local_mesh.core_faces)
    use_skybox, reason = choices.skyboxes(cfg.skybox.mode, gbuffer.coverage, ctx.background, ctx.decisions)
    skybox, sky_origins, sky_pixels = None, None, None
    if use_skybox:
        sb = cfg.skybox
        skybox = SkyboxModel(views.sky_layers, feature_dim=sb.feature_dim, num_codes=sb.num_codes, hidden=sb.hidden)
        sky_origins = views.sky_layers.relative(train.centers.double().numpy()).numpy()
        sky_pixels = choices.sky_training_pixels(teacher.surface_depths, gbuffer.coverage, train.centers.numpy(),
                                                 ray_dirs, ctx.field.aabb, ctx.decisions)
    missed = ~gbuffer.coverage
    if use_skybox or (missed.any() and not ctx.background.constant):
        # the clear colour: what the missed training pixels show on average (skyboxes draw over it)
        clear = torch.as_tensor(teacher.images[missed].mean(axis=0) if missed.any() else np.zeros(3),
                                dtype=torch.float32)
    else:
        clear = ctx.background.colour
    ctx.clock.done(key=key, coverage=float(gbuffer.coverage.mean()), skyboxes=use_skybox, skybox_reason=reason)
    return TrainingViews(origin, local_mesh, gbuffer, dirs), Backdrop(skybox, sky_origins, reason, clear, sky_pixels)
