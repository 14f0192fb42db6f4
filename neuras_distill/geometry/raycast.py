"""Ray casting and signed distance against a triangle mesh (this module owns every open3d call).

open3d's ``RaycastingScene`` is the one tool used, by two callers: visibility culling
(:mod:`.visibility`: which face a pixel ray hits first) and the bunny scene's SDF bake
(:mod:`neuras_distill.scenes.synthetic`: signed distance at grid points, with a majority vote over several
rays for the sign). Both go through the three functions here, so an open3d API change is fixed in one place.
open3d (about 1.8 s to import) is imported on the first call, not with this module, so importing the package or
``nd.distill`` does not pay for it.

All coordinates are in the caller's frame (the mesh's vertices, the rays and the points share it); nothing
here moves or scales anything.

Public API:
    raycasting_scene(vertices (V, 3), faces (F, 3)) -> scene
    cast_rays(scene, rays (R, 6)) -> (face ids (R,) int64, -1 for a miss; t_hit (R,) float32, inf for a miss)
    signed_distance(scene, points (..., 3), nsamples) -> (...) float32
"""

from __future__ import annotations

import numpy as np


def _open3d():
    """The open3d module, imported on first use."""
    import open3d  # noqa: PLC0415

    return open3d


def raycasting_scene(vertices: np.ndarray, faces: np.ndarray):
    """An open3d ``RaycastingScene`` holding one triangle mesh.

    Args:
        vertices: (V, 3) positions (cast to float32).
        faces: (F, 3) vertex indices (cast to uint32, the dtype open3d stores); geometry id 0.
    Returns:
        the scene, to pass to :func:`cast_rays` / :func:`signed_distance` (any number of times).
    """
    o3d = _open3d()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(faces, dtype=np.uint32)))
    return scene


def cast_rays(scene, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First hit of each ray.

    Args:
        scene: from :func:`raycasting_scene`.
        rays: (R, 6) float32 rows (origin xyz, direction xyz) in the mesh's frame; directions need not be unit
            length (``t_hit`` is then in units of the direction's length).
    Returns:
        ids: (R,) int64 index into the mesh's faces of the first face hit, -1 where the ray hits nothing.
        t_hit: (R,) float32 ray parameter of that hit, inf where the ray hits nothing.
    """
    o3d = _open3d()
    hits = scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays, dtype=np.float32)))
    raw = hits["primitive_ids"].numpy().reshape(-1)
    ids = raw.astype(np.int64)
    ids[raw == o3d.t.geometry.RaycastingScene.INVALID_ID] = -1
    return ids, hits["t_hit"].numpy().reshape(-1)


def signed_distance(scene, points: np.ndarray, nsamples: int) -> np.ndarray:
    """Signed distance of ``points`` to the scene's mesh: negative inside, positive outside.

    Args:
        scene: from :func:`raycasting_scene`.
        points: (..., 3) positions (cast to float32) in the mesh's frame.
        nsamples: rays cast per point for the inside/outside vote (odd; open3d's majority vote, which
            tolerates small holes in the mesh).
    Returns:
        (...) float32 distances, the shape of ``points`` without its last axis.
    """
    pts = np.ascontiguousarray(points, dtype=np.float32)
    return scene.compute_signed_distance(_open3d().core.Tensor(pts), nsamples=int(nsamples)).numpy()


__all__ = ["cast_rays", "raycasting_scene", "signed_distance"]
