"""Ray casting and signed distance against a triangle mesh (this module owns every libigl call).

libigl's AABB tree is the one tool used, by two callers: visibility culling (:mod:`.visibility`: which face a
pixel ray hits first) and the bunny scene's SDF bake (:mod:`neuras_distill.scenes.synthetic`: distance at grid
points, signed by the generalized winding number, which tolerates the holes of a scanned mesh). Both go through
the functions here, so a libigl API change is fixed in one place. libigl (``import igl``, about 16 MB
with no dependencies beyond numpy and scipy) is imported on the first call, not with this module.

All coordinates are in the caller's frame (the mesh's vertices, the rays and the points share it); nothing
here moves or scales anything. libigl computes in float64.

Public API:
    raycasting_scene(vertices (V, 3), faces (F, 3)) -> scene
    cast_rays(scene, rays (R, 6)) -> (face ids (R,) int64, -1 for a miss; t_hit (R,) float32, inf for a miss)
    signed_distance(scene, points (..., 3)) -> (...) float32
    surface_distance(scene, points (N, 3)) -> (N,) float32 unsigned
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _igl():
    """The libigl module, imported on first use."""
    import igl  # noqa: PLC0415

    return igl


@dataclass(frozen=True)
class MeshScene:
    """One triangle mesh and libigl's AABB tree over it.

    Attributes:
        vertices: (V, 3) float64 positions; faces: (F, 3) int64 vertex indices; tree: ``igl.AABB`` built on them.
    """

    vertices: np.ndarray
    faces: np.ndarray
    tree: object


def raycasting_scene(vertices: np.ndarray, faces: np.ndarray) -> MeshScene:
    """The mesh with its AABB tree, built once.

    Args:
        vertices: (V, 3) positions (cast to float64).
        faces: (F, 3) vertex indices (cast to int64).
    Returns:
        the scene, to pass to :func:`cast_rays` / :func:`signed_distance` (any number of times).
    """
    v = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    tree = _igl().AABB()
    tree.init(v, f)
    return MeshScene(v, f, tree)


def cast_rays(scene: MeshScene, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First hit of each ray.

    Args:
        scene: from :func:`raycasting_scene`.
        rays: (R, 6) rows (origin xyz, direction xyz) in the mesh's frame; directions need not be unit length
            (``t_hit`` is then in units of the direction's length).
    Returns:
        ids: (R,) int64 index into the mesh's faces of the first face hit, -1 where the ray hits nothing.
        t_hit: (R,) float32 ray parameter of that hit, inf where the ray hits nothing.
    """
    r = np.asarray(rays, dtype=np.float64).reshape(-1, 6)
    if r.shape[0] == 0 or scene.faces.shape[0] == 0:
        return np.full(r.shape[0], -1, np.int64), np.full(r.shape[0], np.inf, np.float32)
    ids, t_hit, _ = scene.tree.intersect_ray_first(scene.vertices, scene.faces, np.ascontiguousarray(r[:, :3]),
                                                   np.ascontiguousarray(r[:, 3:]))
    ids = np.asarray(ids, np.int64).reshape(-1)
    miss = ids < 0
    ids[miss] = -1
    t = np.asarray(t_hit, np.float64).reshape(-1).astype(np.float32)
    t[miss] = np.inf
    return ids, t


def signed_distance(scene: MeshScene, points: np.ndarray) -> np.ndarray:
    """Signed distance of ``points`` to the scene's mesh: negative inside, positive outside.

    The magnitude is the exact distance to the nearest triangle; the sign is inside where the generalized
    winding number (libigl's fast approximation) exceeds 1/2, which holds across small holes in the mesh.

    Args:
        scene: from :func:`raycasting_scene`.
        points: (..., 3) positions in the mesh's frame.
    Returns:
        (...) float32 distances, the shape of ``points`` without its last axis.
    """
    pts = np.asarray(points, dtype=np.float64)
    flat = np.ascontiguousarray(pts.reshape(-1, 3))
    squared, _, _ = scene.tree.squared_distance(scene.vertices, scene.faces, flat)
    winding = _igl().fast_winding_number(scene.vertices, scene.faces, flat)
    d = np.sqrt(np.maximum(np.asarray(squared, np.float64), 0.0)) * np.where(winding > 0.5, -1.0, 1.0)
    return d.astype(np.float32).reshape(pts.shape[:-1])


def surface_distance(scene: MeshScene, points: np.ndarray) -> np.ndarray:
    """(N,) float32 distance from each of ``points`` (N, 3) to the nearest triangle of the scene's mesh."""
    flat = np.ascontiguousarray(np.asarray(points, np.float64).reshape(-1, 3))
    if flat.shape[0] == 0:
        return np.zeros(0, np.float32)
    squared, _, _ = scene.tree.squared_distance(scene.vertices, scene.faces, flat)
    return np.sqrt(np.maximum(np.asarray(squared, np.float64), 0.0)).astype(np.float32)
