"""Visibility culling: drop faces that no training camera sees (the only open3d importer in geometry/).

The pixel-centre rays of every camera (``Cameras.rays`` at a subsampled resolution, at most
``max_rays_per_camera`` rays, same field of view) are cast against the mesh with open3d's
``RaycastingScene``; a face is kept when at least one ray hits it first. Because the rays are subsampled,
small or grazing faces near silhouettes can be missed; ``dilate=True`` (default) also keeps the one-ring
neighbours (faces sharing a vertex) of every seen face so no cracks open at silhouettes. Unreferenced vertices
are then dropped.
"""

from __future__ import annotations

import math
import time

import numpy as np
import open3d as o3d

from ..errors import BadInputError
from .mesh import MeshData


def seen_faces(mesh: MeshData, cameras, *, max_rays_per_camera: int = 65536) -> tuple[np.ndarray, int]:
    """(F,) bool mask of faces hit first by at least one subsampled pixel ray, and the number of rays cast."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(mesh.vertices, dtype=np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(mesh.faces, dtype=np.uint32)))
    w, h = cameras.width, cameras.height
    scale = min(1.0, math.sqrt(max(1, int(max_rays_per_camera)) / float(w * h)))
    if scale < 1.0:
        cameras = cameras.resized(max(1, int(w * scale)), max(1, int(h * scale)))
    invalid = o3d.t.geometry.RaycastingScene.INVALID_ID
    seen = np.zeros(mesh.num_faces, dtype=bool)
    total = 0
    for i in range(len(cameras)):
        o, d = cameras.rays(i)
        rays = np.concatenate([o.reshape(-1, 3).numpy(), d.reshape(-1, 3).numpy()], axis=1).astype(np.float32)
        total += rays.shape[0]
        ids = scene.cast_rays(o3d.core.Tensor(rays))["primitive_ids"].numpy().reshape(-1)
        ids = ids[ids != invalid]
        seen[ids.astype(np.int64)] = True
    return seen, total


def cull_unseen_faces(mesh: MeshData, cameras, *, max_rays_per_camera: int = 65536, dilate: bool = True) -> MeshData:
    """Remove faces no camera sees.

    Args:
        mesh: vertices (V, 3), faces (F, 3) in world units (uvs, if any, are carried along).
        cameras: ``Cameras`` (N views); their pixel rays are subsampled to about ``max_rays_per_camera`` each.
        dilate: also keep faces sharing a vertex with a seen face.

    Returns:
        MeshData with stats ``cull_faces_in``, ``cull_seen``, ``culled_faces``, ``cull_rays``, ``cull_seconds``.

    Raises:
        BadInputError: the mesh is empty or no camera sees any face.
    """
    if mesh.num_faces == 0:
        raise BadInputError("cannot cull an empty mesh (no faces)")
    t0 = time.perf_counter()
    seen, rays = seen_faces(mesh, cameras, max_rays_per_camera=max_rays_per_camera)
    n_seen = int(seen.sum())
    if n_seen == 0:
        raise BadInputError(f"no training camera sees the extracted geometry ({len(cameras)} cameras, {rays} rays, "
                            f"{mesh.num_faces} faces): check that the cameras look at the field's box and use the "
                            "same world frame as the field")
    keep = seen
    if dilate:
        vert_seen = np.zeros(mesh.num_vertices, dtype=bool)
        vert_seen[mesh.faces[seen].reshape(-1)] = True
        keep = vert_seen[mesh.faces].any(axis=1)
    faces = mesh.faces[keep]
    used = np.zeros(mesh.num_vertices, dtype=bool)
    used[faces.reshape(-1)] = True
    remap = (np.cumsum(used) - 1).astype(np.int64)
    stats = dict(mesh.stats)
    stats.update(cull_faces_in=mesh.num_faces, cull_seen=n_seen, culled_faces=int((~keep).sum()), cull_rays=rays,
                 cull_seconds=time.perf_counter() - t0)
    uvs = None if mesh.uvs is None else mesh.uvs[used]
    return MeshData(mesh.vertices[used], remap[faces], uvs, stats)


__all__ = ["cull_unseen_faces", "seen_faces"]
