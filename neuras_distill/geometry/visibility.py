"""Visibility culling: drop faces that no camera near the training set sees.

The pixel-centre rays of every camera (``Cameras.rays`` at a subsampled resolution, at most
``max_rays_per_camera`` rays, same field of view) are cast against the mesh (:mod:`.raycast`, libigl's
AABB tree); a face is kept when at least one ray hits it first. Because the rays are subsampled,
small or grazing faces near silhouettes can be missed; ``dilate=True`` (default) also keeps the one-ring
neighbours (faces sharing a vertex) of every seen face so no cracks open at silhouettes. Unreferenced vertices
are then dropped.

Culling is conservative (``margin_deg``, default 15 degrees): faces seen by *cameras near the training set*
are kept too, not only faces the training cameras see. A held-out or user camera slightly outside the
training range (lower on an orbit, a lane to the side) otherwise looked into jagged holes: on the
gradient-ball scene, whose held-out views sit a few degrees below their training neighbours, the bottom of
the ball was culled and the held-out views showed the background there. Each training camera gets four
neighbours turned by +-``margin_deg`` about its own up and right axes around the point it looks at (the
median first-hit distance along its rays), which is what an orbit, a nearby viewpoint or a lane change
sees. Faces only the neighbours see get texels but no training samples; the model fills their texels from
the nearest trained texel (``NeuralTextureModel.fill_unseen_texels``).
"""

from __future__ import annotations

import math
import time

import numpy as np
import torch

from ..config import GeometryConfig
from ..errors import BadInputError
from ..render.extra_views import turned_about_look_at
from .mesh import MeshData
from .raycast import cast_rays, raycasting_scene

#: The library's defaults are the configuration's (one place: ``config.py``).
_GEOMETRY = GeometryConfig()


def seen_faces(mesh: MeshData, cameras, *, max_rays_per_camera: int = 65536, scene=None,
               front_only: bool = False) -> tuple[np.ndarray, int, np.ndarray]:
    """(F,) bool mask of faces hit first by at least one subsampled pixel ray, the number of rays cast, and
    (N,) float64 median first-hit distance per camera (inf for a camera whose rays hit nothing).
    ``front_only``: count only hits on a face's front (a camera that ended up inside the geometry, e.g. a
    neighbour camera below a street's ground, sees back faces no real view shows)."""
    scene = scene or _raycasting_scene(mesh)
    w, h = cameras.width, cameras.height
    scale = min(1.0, math.sqrt(max(1, int(max_rays_per_camera)) / float(w * h)))
    if scale < 1.0:
        cameras = cameras.resized(max(1, int(w * scale)), max(1, int(h * scale)))
    seen = np.zeros(mesh.num_faces, dtype=bool)
    distances = np.full(len(cameras), np.inf)
    normals = None
    total = 0
    for i in range(len(cameras)):
        o, d = cameras.rays(i)
        rays = np.concatenate([o.reshape(-1, 3).numpy(), d.reshape(-1, 3).numpy()], axis=1).astype(np.float32)
        total += rays.shape[0]
        ids, t_hit = cast_rays(scene, rays)
        hit = ids >= 0
        if front_only:
            normals = normals if normals is not None else mesh.face_normals()
            hit[hit] = np.einsum("ij,ij->i", normals[ids[hit]], rays[hit, 3:]) < 0
        seen[ids[hit]] = True
        if hit.any():
            distances[i] = float(np.median(t_hit[hit]))
    return seen, total, distances


def missed_opaque_fraction(mesh: MeshData, cameras, opacity: np.ndarray, *, threshold: float = 0.05,
                           stride: int = 4, reach: int = 6, inset: int = 0) -> float:
    """Fraction of the field's fringe pixels whose ray misses ``mesh``.

    Fringe pixels: pixels where the field is at least ``threshold`` opaque and that lie within ``reach``
    strided pixels of a pixel the mesh covers (what surrounds the mesh's silhouette; isolated floaters farther
    out are not the fringe, and chasing them would grow the mesh into the floaters' fog).

    Args:
        mesh: vertices (V, 3), faces (F, 3) in the cameras' world frame.
        cameras: ``Cameras`` (N views, W x H).
        opacity: (N, H, W) the field's opacity of those views (the teacher's accumulated alpha).
        stride: only every ``stride``-th pixel row and column is cast (pixel-centre rays, as rendered).
        inset: count only pixels at least this many (full-resolution) pixels inside the opaque region: holes in
            a surface, not its silhouette's rim (where a mesh at a density level sits a little inside).
    Returns:
        missed / fringe pixels over the strided pixels (0.0 when there are none).
    """
    from scipy import ndimage

    scene = _raycasting_scene(mesh)
    missed = wanted = 0
    for i in range(len(cameras)):
        opaque = np.asarray(opacity[i]) >= threshold
        if inset:
            opaque = ndimage.binary_erosion(opaque, iterations=int(inset))
        want = opaque[::stride, ::stride]
        if not want.any():
            continue
        o, d = cameras.rays(i)
        o, d = o[::stride, ::stride], d[::stride, ::stride]
        rays = np.concatenate([o.reshape(-1, 3).numpy(), d.reshape(-1, 3).numpy()], axis=1).astype(np.float32)
        hit = (cast_rays(scene, rays)[0] >= 0).reshape(want.shape)
        want &= ndimage.binary_dilation(hit, iterations=reach) if hit.any() else False
        missed += int((want & ~hit).sum())
        wanted += int(want.sum())
    return missed / wanted if wanted else 0.0


def seen_surface_points(mesh: MeshData, cameras, depths: np.ndarray, opacity: np.ndarray, *, tolerance: float,
                        threshold: float = 0.5) -> np.ndarray:
    """(M, 3) float64 points where the training views see ``mesh`` as the field's own surface: the first hit of
    each pixel ray whose opacity reaches ``threshold`` and whose hit lies within ``tolerance`` (world units) of the
    field's surface depth there. A piece of the mesh holding such points shows what the field's picture shows
    (a floor tile a partly trained field made darker and set apart from its neighbours), not a floater.

    Args:
        mesh: vertices (V, 3), faces (F, 3) in the cameras' world frame.
        cameras: ``Cameras`` (N views, W x H).
        depths, opacity: (N, H, W) the field's surface depths (distance along the unit ray where the opacity
            reaches 0.5; ``render.volume``) and opacities in those views.
    """
    scene = _raycasting_scene(mesh)
    found = []
    for i in range(len(cameras)):
        opaque = (np.asarray(opacity[i]) >= threshold) & (np.asarray(depths[i]) > 0)
        if not opaque.any():
            continue
        o, d = cameras.rays(i)
        o, d = o.reshape(-1, 3).numpy()[opaque.reshape(-1)], d.reshape(-1, 3).numpy()[opaque.reshape(-1)]
        rays = np.concatenate([o, d], axis=1).astype(np.float32)
        ids, t_hit = cast_rays(scene, rays)
        near = (ids >= 0) & (np.abs(t_hit - np.asarray(depths[i]).reshape(-1)[opaque.reshape(-1)]) <= tolerance)
        found.append(o[near].astype(np.float64) + d[near].astype(np.float64) * t_hit[near, None])
    return np.concatenate(found) if found else np.zeros((0, 3))


def _raycasting_scene(mesh: MeshData):
    """The ray-casting scene of ``mesh`` (vertices (V, 3), faces (F, 3)) in its own frame."""
    return raycasting_scene(mesh.vertices, mesh.faces)


def neighbour_cameras(cameras, distances: np.ndarray, margin_deg: float):
    """Cameras near the given ones: each turned by +-``margin_deg`` about its own up and right axes around
    its look-at point (``distances[i]`` along its optical axis: the median first-hit distance of its rays).
    Cameras with an infinite distance (seeing nothing) get no neighbours. Returns a ``Cameras`` (4 per usable camera,
    same intrinsics) or None."""
    from ..render.cameras import Cameras

    poses, keep = [], []
    angle = np.radians(float(margin_deg))
    for i in range(len(cameras)):
        if not np.isfinite(distances[i]):
            continue
        c2w = cameras.c2w[i].double().numpy()
        for axis in (c2w[:3, 1], c2w[:3, 0]):
            for sign in (1.0, -1.0):
                poses.append(turned_about_look_at(c2w, distances[i], axis, sign * angle))
                keep.append(i)
    if not poses:
        return None
    k = torch.as_tensor(keep)
    return Cameras(torch.as_tensor(np.stack(poses)).float(), cameras.fx[k], cameras.fy[k], cameras.cx[k],
                   cameras.cy[k], cameras.width, cameras.height)


def cull_unseen_faces(mesh: MeshData, cameras, *, max_rays_per_camera: int = 65536, dilate: bool = True,
                      margin_deg: float = _GEOMETRY.cull_margin_deg) -> MeshData:
    """Remove faces no camera near the training cameras sees.

    Args:
        mesh: vertices (V, 3), faces (F, 3) in world units (uvs, if any, are carried along).
        cameras: ``Cameras`` (N views); their pixel rays are subsampled to about ``max_rays_per_camera`` each.
        dilate: also keep faces sharing a vertex with a seen face.
        margin_deg: also keep faces seen by each camera turned by this angle about its look-at point
            (:func:`neighbour_cameras`); 0 keeps only what the cameras themselves see.

    Returns:
        MeshData with stats ``cull_faces_in``, ``cull_seen`` (seen by the cameras), ``cull_seen_nearby``
        (seen only by their neighbours), ``culled_faces``, ``cull_rays``, ``cull_margin_deg``,
        ``cull_seconds``.

    Raises:
        BadInputError: the mesh is empty or no camera sees any face.
    """
    if mesh.num_faces == 0:
        raise BadInputError("cannot cull an empty mesh (no faces)")
    t0 = time.perf_counter()
    scene = _raycasting_scene(mesh)
    seen, rays, distances = seen_faces(mesh, cameras, max_rays_per_camera=max_rays_per_camera, scene=scene)
    n_seen = int(seen.sum())
    if n_seen == 0:
        raise BadInputError(f"no training camera sees the extracted geometry ({len(cameras)} cameras, {rays} rays, "
                            f"{mesh.num_faces} faces): check that the cameras look at the field's box and use the "
                            "same world frame as the field")
    nearby = np.zeros_like(seen)
    neighbours = neighbour_cameras(cameras, distances, margin_deg) if margin_deg > 0 else None
    if neighbours is not None:
        nearby, more_rays, _ = seen_faces(mesh, neighbours, max_rays_per_camera=max_rays_per_camera // 4,
                                          scene=scene, front_only=True)
        rays += more_rays
        nearby &= ~seen
    keep = seen | nearby
    if dilate:
        vert_seen = np.zeros(mesh.num_vertices, dtype=bool)
        vert_seen[mesh.faces[keep].reshape(-1)] = True
        keep = vert_seen[mesh.faces].any(axis=1)
    faces = mesh.faces[keep]
    used = np.zeros(mesh.num_vertices, dtype=bool)
    used[faces.reshape(-1)] = True
    remap = (np.cumsum(used) - 1).astype(np.int64)
    stats = dict(mesh.stats)
    stats.update(cull_faces_in=mesh.num_faces, cull_seen=n_seen, cull_seen_nearby=int(nearby.sum()),
                 culled_faces=int((~keep).sum()), cull_rays=rays, cull_margin_deg=float(margin_deg),
                 cull_seconds=time.perf_counter() - t0)
    uvs = None if mesh.uvs is None else mesh.uvs[used]
    return MeshData(mesh.vertices[used], remap[faces], uvs, stats)


__all__ = ["cull_unseen_faces", "missed_opaque_fraction", "neighbour_cameras", "seen_faces", "seen_surface_points"]
