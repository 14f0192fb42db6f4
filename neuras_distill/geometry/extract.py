"""The geometry stage: field -> textured-ready mesh (sample -> marching cubes -> clean -> smooth if rough ->
decimate -> cull -> unwrap).

Owns only the order of the steps and the stats they leave in ``MeshData.stats``; each step lives in its own
module (grid, marching, cleanup, visibility, unwrap). Prints nothing.
"""

from __future__ import annotations

import time

from .depth_fusion import fused_depth_sdf
from .cleanup import clean_mesh, decimate, smooth_rough
from .marching import marching_cubes_field
from .mesh import MeshData
from .unwrap import unwrap
from .visibility import cull_unseen_faces, missed_opaque_fraction

#: Truncation of the fused depth SDF in voxels: beyond the 4-voxel fringe offsets ``marching.outward_levels``
#: tries, so those levels stay inside the fused values' range.
FUSION_TRUNCATION_VOXELS = 6.0


def extract_mesh(field, train_cameras, *, grid_resolution: int = 192, face_budget: int = 40_000,
                 texture_resolution: int = 1024, unwrap_timeout_s: float = 120.0, cull_unseen: bool = True,
                 density_level: float | None = None, max_unwrap_faces: int = 200_000,
                 choose_resolution=None, cull_margin_deg: float = 15.0, field_opacity=None,
                 field_depth=None) -> MeshData:
    """Extract, simplify, cull and unwrap the surface of ``field``.

    Args:
        field: Field (kind, aabb, geometry).
        train_cameras: ``Cameras`` used for visibility culling (ignored when ``cull_unseen`` is False).
        grid_resolution: marching-cubes lattice points along the longest box side.
        face_budget: maximum faces after decimation (int >= 4).
        texture_resolution: side of the square atlas the distiller uses (uv layout and padding target it).
        unwrap_timeout_s: time limit per xatlas attempt.
        density_level: iso-level override for density fields.
        cull_margin_deg: culling keeps what cameras turned by this angle around the training cameras' look-at
            points see (``visibility.cull_unseen_faces``).
        field_opacity: optional (N, H, W) opacity of the field in ``train_cameras``: the iso-level then moves
            outwards until the mesh encloses the field's soft fringe (``marching.marching_cubes_field``).
        field_depth: optional ((N, H, W) surface depths, (N, H, W) opacities) of the field in ``train_cameras``:
            a density field whose level set is foam (a trained NeRF's unsupervised interior) is then meshed
            from these fused depth maps (``depth_fusion.fused_depth_sdf``, ``marching.FOAM_HANDLES``).
        choose_resolution: optional callable (unwrapped MeshData) -> atlas side; the mesh is first unwrapped
            at ``texture_resolution``, then again at the chosen side when it differs (the padding is laid out
            in texels of the final atlas). ``stats['uv_resolution']`` holds the side used.

    Returns:
        MeshData with uvs and ``stats``: ``faces_marching_cubes``, ``faces_after_clean``,
        ``faces_after_decimation``, ``culled_faces``, ``faces_final``, ``vertices_final``, ``uv_charts``,
        ``seconds_{marching_cubes,clean,decimate,cull,unwrap,total}`` plus each step's own keys.

    Raises:
        BadInputError: no surface in the box, bad budget, cameras seeing nothing, unwrap failure.
    """
    t_start = time.perf_counter()
    timings = {}

    t = time.perf_counter()
    fringe_check = None
    if field_opacity is not None:
        def fringe_check(candidate: MeshData) -> float:
            return missed_opaque_fraction(candidate, train_cameras, field_opacity)
    fusion = None
    if field_depth is not None:
        depths, opacities = field_depth

        def fusion(spec):
            return fused_depth_sdf(spec.origin, spec.spacing, spec.shape, train_cameras, depths, opacities,
                                   truncation=FUSION_TRUNCATION_VOXELS * float(spec.spacing.max()))
    mesh = marching_cubes_field(field, grid_resolution, level=density_level, fringe_check=fringe_check,
                                depth_fusion=fusion)
    timings["marching_cubes"] = time.perf_counter() - t  # includes grid sampling
    n_mc = mesh.num_faces

    t = time.perf_counter()
    mesh = smooth_rough(clean_mesh(mesh))
    timings["clean"] = time.perf_counter() - t
    n_clean = mesh.num_faces

    t = time.perf_counter()
    mesh = decimate(mesh, face_budget)
    timings["decimate"] = time.perf_counter() - t
    n_dec = mesh.num_faces

    culled = 0
    if cull_unseen:
        t = time.perf_counter()
        mesh = cull_unseen_faces(mesh, train_cameras, margin_deg=cull_margin_deg)
        timings["cull"] = time.perf_counter() - t
        culled = int(mesh.stats.get("culled_faces", 0))

    t = time.perf_counter()
    unwrapped = unwrap(mesh, timeout_s=unwrap_timeout_s, max_faces=max_unwrap_faces, resolution=texture_resolution)
    if choose_resolution is not None:
        chosen = int(choose_resolution(unwrapped))
        if chosen != int(texture_resolution):
            unwrapped = unwrap(mesh, timeout_s=unwrap_timeout_s, max_faces=max_unwrap_faces, resolution=chosen)
    mesh = unwrapped
    timings["unwrap"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t_start

    mesh.stats.update(faces_marching_cubes=n_mc, faces_after_clean=n_clean, faces_after_decimation=n_dec,
                      culled_faces=culled, faces_final=mesh.num_faces, vertices_final=mesh.num_vertices,
                      chart_count=mesh.stats.get("uv_charts"),
                      **{f"seconds_{k}": v for k, v in timings.items()})
    return mesh


__all__ = ["extract_mesh"]
