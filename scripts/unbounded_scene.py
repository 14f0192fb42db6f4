"""An unbounded 360-degree scene ray-cast in closed form: the dataset of the unbounded nerfstudio fixture.

Two objects (a red sphere and a blue box) on a checkered ground plane that reaches a distant backdrop (a
cylinder of radius :data:`BACKDROP_RADIUS` with a skyline of buildings, striped by floor), and a sky gradient
above it. Two grounds (``ground=``): "soft", a low-contrast checker fading out within a few metres, and
"checker", a high-contrast one (near-black and near-white squares) that keeps its contrast to the horizon.
World frame: z up, metres. Cameras: a full orbit at radius 3, 1.2 m up, looking at the objects;
OpenGL convention (x right, y up, looking down -z), as nerfstudio's ``transforms.json`` stores them.

:func:`render_view` returns an (H, W, 3) float image in [0, 1] (2x2 supersampled); :func:`orbit_c2w` the poses.
Used by ``scripts/make_nerfstudio_unbounded_fixture.py`` only (numpy, no package import).
"""

from __future__ import annotations

import math

import numpy as np

BACKDROP_RADIUS = 30.0
GROUND_EXTENT = BACKDROP_RADIUS
SPHERE = (np.array([-0.55, 0.1, 0.45]), 0.45)
BOX = (np.array([0.45, -0.35, 0.0]), np.array([1.05, 0.25, 0.7]))


def orbit_c2w(n: int, radius: float = 3.0, height: float = 1.2, target=(0.0, 0.0, 0.9)) -> np.ndarray:
    """(n, 4, 4) camera-to-world matrices on a full circle, OpenGL convention."""
    target = np.asarray(target, dtype=np.float64)
    out = np.zeros((n, 4, 4))
    for i in range(n):
        a = 2 * math.pi * i / n
        eye = np.array([radius * math.cos(a), radius * math.sin(a), height])
        back = eye - target
        back /= np.linalg.norm(back)
        right = np.cross([0.0, 0.0, 1.0], back)
        right /= np.linalg.norm(right)
        up = np.cross(back, right)
        out[i, :3, 0], out[i, :3, 1], out[i, :3, 2], out[i, :3, 3] = right, up, back, eye
        out[i, 3, 3] = 1.0
    return out


def _skyline(theta: np.ndarray) -> np.ndarray:
    """Building heights (m) of the backdrop at azimuth theta: 48 blocks of pseudo-random height, 4..14 m."""
    block = np.floor((theta % (2 * math.pi)) / (2 * math.pi) * 48).astype(np.int64)
    return 4.0 + 10.0 * ((block * 7919 % 97) / 96.0)


GROUNDS = ("soft", "checker")


def _ground_colour(p: np.ndarray, r: np.ndarray, ground: str) -> np.ndarray:
    """(N, 3) colour of the ground at points ``p`` (N, 3), ``r`` (N,) their distance from the z axis."""
    square = (np.floor(p[:, 0]) + np.floor(p[:, 1])) % 2
    if ground == "checker":     # 0.06 against 0.9, fading slowly to mid-grey far away (no aliasing at the horizon)
        fade = np.exp(-r / 40.0)
        check = 0.48 + (square - 0.5) * 0.84 * fade
        return np.stack([check, check * 0.97, check * 0.92], axis=1)
    check = square * np.exp(-r / 6.0)   # fades out: no far aliasing
    return np.stack([0.40 + 0.25 * check, 0.55 + 0.15 * check, 0.32 + 0.10 * check], axis=1)


def _shade(o: np.ndarray, d: np.ndarray, ground: str = "soft") -> np.ndarray:
    """Colour (N, 3) of rays o, d (N, 3), d unit."""
    with np.errstate(invalid="ignore", over="ignore"):
        return _shade_rays(o, d, ground)


def _shade_rays(o: np.ndarray, d: np.ndarray, ground_kind: str) -> np.ndarray:
    n = o.shape[0]
    t_best = np.full(n, np.inf)
    colour = np.zeros((n, 3))
    light = np.array([0.4, -0.3, 0.85])
    light /= np.linalg.norm(light)

    # sky: a gradient with the elevation
    elev = np.clip(d[:, 2], -1, 1)
    sky = np.stack([0.55 + 0.25 * (1 - elev), 0.70 + 0.15 * (1 - elev), 0.95 * np.ones(n)], axis=1)
    colour[:] = np.clip(sky, 0, 1)

    # backdrop cylinder x^2 + y^2 = R^2 (from inside), skyline height
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = 2 * (o[:, 0] * d[:, 0] + o[:, 1] * d[:, 1])
    c = o[:, 0] ** 2 + o[:, 1] ** 2 - BACKDROP_RADIUS ** 2
    disc = np.maximum(b * b - 4 * a * c, 0)
    t = (-b + np.sqrt(disc)) / np.maximum(2 * a, 1e-12)
    p = o + t[:, None] * d
    theta = np.arctan2(p[:, 1], p[:, 0])
    hit = (t > 0) & (p[:, 2] >= 0) & (p[:, 2] <= _skyline(theta))
    floor = np.floor(p[:, 2] / 1.5).astype(np.int64)
    window = ((np.floor(theta * BACKDROP_RADIUS / 1.2).astype(np.int64) + floor) % 3 == 0)
    base = np.stack([0.45 + 0.1 * (floor % 2), 0.42 + 0.05 * (floor % 3), 0.40 * np.ones(n)], axis=1)
    wall = np.where(window[:, None], base * 0.55, base)
    upd = hit & (t < t_best)
    colour[upd], t_best[upd] = wall[upd], t[upd]

    # ground plane z = 0, a checker of 1 m squares
    t = np.where(d[:, 2] < -1e-9, -o[:, 2] / np.where(d[:, 2] < -1e-9, d[:, 2], -1.0), np.inf)
    p = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
    r = np.hypot(p[:, 0], p[:, 1])
    hit = np.isfinite(t) & (t > 0) & (r < GROUND_EXTENT)
    ground = _ground_colour(p, r, ground_kind)
    upd = hit & (t < t_best)
    colour[upd], t_best[upd] = ground[upd], t[upd]

    # the sphere
    centre, radius = SPHERE
    oc = o - centre
    bb = (oc * d).sum(1)
    cc = (oc * oc).sum(1) - radius ** 2
    disc = bb * bb - cc
    t = np.where(disc > 0, -bb - np.sqrt(np.maximum(disc, 0)), np.inf)
    upd = (t > 0) & (t < t_best)
    normal = (o + t[:, None] * d - centre) / radius
    lam = 0.35 + 0.65 * np.clip((normal * light).sum(1), 0, 1)
    colour[upd] = (np.array([0.85, 0.2, 0.15])[None] * lam[:, None])[upd]
    t_best[upd] = t[upd]

    # the box (slab test), each face its own shade
    lo, hi = BOX
    inv = 1.0 / np.where(np.abs(d) < 1e-12, 1e-12, d)
    t0, t1 = (lo - o) * inv, (hi - o) * inv
    tmin, tmax = np.minimum(t0, t1).max(1), np.maximum(t0, t1).min(1)
    face = np.minimum(t0, t1).argmax(1)
    upd = (tmax >= tmin) & (tmin > 0) & (tmin < t_best)
    shade = np.array([0.75, 0.9, 1.0])[face]
    colour[upd] = (np.array([0.15, 0.3, 0.8])[None] * shade[:, None])[upd]
    return np.clip(colour, 0, 1)


def render_view(c2w: np.ndarray, width: int, height: int, focal: float, supersample: int = 2,
                ground: str = "soft") -> np.ndarray:
    """(H, W, 3) float64 image of camera ``c2w`` (4, 4), focal length in pixels, pixel centres at +0.5, with the
    ground ``ground`` (one of :data:`GROUNDS`)."""
    s = supersample
    offs = (np.arange(s) + 0.5) / s
    acc = np.zeros((height, width, 3))
    for oy in offs:
        for ox in offs:
            u, v = np.meshgrid(np.arange(width) + ox, np.arange(height) + oy)
            d_cam = np.stack([(u - width / 2) / focal, -(v - height / 2) / focal, -np.ones_like(u)], axis=-1)
            d = d_cam.reshape(-1, 3) @ c2w[:3, :3].T
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            o = np.broadcast_to(c2w[:3, 3], d.shape)
            acc += _shade(o, d, ground).reshape(height, width, 3)
    return acc / (s * s)
