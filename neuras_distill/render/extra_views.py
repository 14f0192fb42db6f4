"""Extra training views around the capture's cameras, rendered by the field (the teacher) like the others.

A bundle is played from wherever its user moves, while a capture's cameras sample a path (an orbit, a helix).
Off that path the bundle's error grows fast although the field itself changes little: on the Instant-NGP ball
fixture (one bundle, training cameras turned about the ball's centre) the interior scored 40.7 dB
at the training cameras, 39.1 turned by 3 degrees, 36.4 by 7 and 33.5 by 12; its held-out cameras sit 6.5-8.5
degrees from the nearest training camera. The field can render any view, so the run adds views between and
around the training cameras: each a training camera turned about its look-at point (its median first-hit
distance, :func:`look_at_distances`) by a random angle about a random axis in its image plane (no roll), the
angles uniform over a disc of ``max_deg`` (:func:`extra_views`). The held-out cameras are never looked at.

Cameras on a path through the scene (a drive) would leave the path when turned about a point ahead; there the
run can add views along the path instead (:func:`path_views`): each between a training camera and its nearest
neighbour, turned about its own centre. On the embedded city a held-out camera's first metres of road are seen
by no training camera closer than the next one back (8.7 m), and they play blurred and broken.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from .cameras import Cameras


def look_at_distances(renderer, cameras: Cameras, width: int = 32) -> np.ndarray:
    """(N,) float64 median first-hit distance of each camera's rays (``renderer``: a VolumeRenderer; the
    cameras rendered ``width`` pixels wide, opaque pixels only), inf where a camera sees nothing opaque."""
    small = cameras.resized(max(4, int(width)))
    out = np.full(len(cameras), np.inf)
    for i in range(len(small)):
        r = renderer.render(small, i)
        hit = r["opacity"] > 0.5
        if hit.any():
            _, d = small.rays(i)
            forward = -small.c2w[i, :3, 2].numpy()
            along = (d.numpy() @ forward)[hit]                       # depth is along the ray; distance along z
            out[i] = float(np.median(r["depth"][hit] * along))
    return out


def rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) float64 rotation by ``angle`` radians about the unit ``axis`` (Rodrigues)."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def turned_about_look_at(c2w: np.ndarray, distance: float, axis: np.ndarray, angle: float) -> np.ndarray:
    """(4, 4) float64 camera-to-world of the camera ``c2w`` ((4, 4), -z forward) turned by ``angle`` radians
    about the unit world ``axis`` through its look-at point ``distance`` ahead of it."""
    rot, eye = c2w[:3, :3], c2w[:3, 3]
    target = eye - float(distance) * rot[:, 2]
    r = rotation_about(axis, angle)
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = r @ rot, target + r @ (eye - target)
    return pose


def random_turn(rng: np.random.Generator, c2w: np.ndarray, max_deg: float) -> tuple[np.ndarray, float]:
    """A turn of the camera ``c2w`` ((4, 4), -z forward) without roll: the unit world axis ``cos(phi) y +
    sin(phi) x`` of its own frame and the angle ``max_deg * sqrt(u)`` in radians (u, phi uniform: the turns
    cover a disc of ``max_deg`` evenly)."""
    phi = rng.uniform(0.0, 2.0 * math.pi)
    angle = math.radians(float(max_deg)) * math.sqrt(rng.uniform())
    return math.cos(phi) * c2w[:3, 1] + math.sin(phi) * c2w[:3, 0], angle


def with_poses(cameras: Cameras, poses: list[np.ndarray], source: list[int]) -> Cameras:
    """Cameras at ``poses`` ((4, 4) camera-to-world each) with the intrinsics and image size of
    ``cameras[source[j]]``."""
    k = torch.as_tensor(source)
    return Cameras(torch.as_tensor(np.stack(poses)).float(), cameras.fx[k], cameras.fy[k], cameras.cx[k],
                   cameras.cy[k], cameras.width, cameras.height)


def extra_views(cameras: Cameras, distances: np.ndarray, count: int, max_deg: float, seed: int = 0) -> Cameras | None:
    """``count`` cameras near ``cameras`` (N, any size): camera ``order[j % M]`` of the M cameras with a finite
    distance (a seeded permutation) turned about its look-at point ``eye - distances[i] * z`` by an angle
    ``max_deg * sqrt(u)`` degrees about the axis ``cos(phi) y + sin(phi) x`` of its own frame (u, phi uniform:
    the angles cover a disc evenly). Intrinsics and image size are the source camera's. None when no camera
    has a finite distance or ``count`` is 0."""
    usable = np.flatnonzero(np.isfinite(distances))
    if count <= 0 or usable.size == 0:
        return None
    rng = np.random.default_rng(seed)
    order = rng.permutation(usable)
    poses, source = [], []
    for j in range(int(count)):
        i = int(order[j % order.size])
        c2w = cameras.c2w[i].double().numpy()
        axis, angle = random_turn(rng, c2w, max_deg)
        poses.append(turned_about_look_at(c2w, distances[i], axis, angle))
        source.append(i)
    return with_poses(cameras, poses, source)


def path_views(cameras: Cameras, count: int, max_deg: float, seed: int = 0) -> Cameras | None:
    """``count`` cameras along the path of ``cameras`` (N >= 2, any size): camera ``order[j % N]`` (a seeded
    permutation) moved a uniform 25-75% of the way to its nearest neighbour (by centre distance) and turned
    about its own centre by ``max_deg * sqrt(u)`` degrees about the axis ``cos(phi) y + sin(phi) x`` of its own
    frame (no roll; the angles cover a disc evenly). Intrinsics and image size are the source camera's. None
    when ``count`` is 0 or there is a single camera."""
    n = len(cameras)
    if count <= 0 or n < 2:
        return None
    centres = cameras.centers.double().numpy()
    gaps = np.linalg.norm(centres[:, None] - centres[None], axis=-1)      # (N, N): 32 MB at 2000 cameras
    np.fill_diagonal(gaps, np.inf)
    nearest = gaps.argmin(axis=1)
    rng = np.random.default_rng(seed)
    order = rng.permutation(n)
    poses, source = [], []
    for j in range(int(count)):
        i = int(order[j % n])
        c2w = cameras.c2w[i].double().numpy()
        t = rng.uniform(0.25, 0.75)
        axis, angle = random_turn(rng, c2w, max_deg)
        pose = np.eye(4)
        pose[:3, :3] = rotation_about(axis, angle) @ c2w[:3, :3]
        pose[:3, 3] = (1.0 - t) * centres[i] + t * centres[nearest[i]]
        poses.append(pose)
        source.append(i)
    return with_poses(cameras, poses, source)


def inside_box(cameras: Cameras, aabb) -> np.ndarray:
    """(N,) bool: camera centres inside the box ``aabb`` ((2, 3) min, max)."""
    box = torch.as_tensor(aabb, dtype=torch.float64).reshape(2, 3).numpy()
    c = cameras.centers.double().numpy()
    return ((c >= box[0]) & (c <= box[1])).all(axis=1)
