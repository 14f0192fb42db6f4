"""OpenGL view / projection matrices from the pinhole cameras of ``render/cameras.py``.

This module owns the one piece of maths that makes rasterized images line up with ``Cameras.rays``.

Derivation. A camera-space point (x, y, z), z < 0, lies on the ray of the continuous image coordinate
    u_px = cx + fx * x / (-z),      v_px = cy - fy * y / (-z)
(pixel (u, v) has its centre at (u + 0.5, v + 0.5), row 0 at the top). GL maps NDC to window coordinates
with the viewport (0, 0, W, H): x_win = (x_ndc + 1) W / 2, y_win = (y_ndc + 1) H / 2, and samples window
pixel (x, y_gl) at its centre (x + 0.5, y_gl + 0.5). Reading the framebuffer back with rows flipped puts
window row y_gl at image row v = H - 1 - y_gl, i.e. y_win = H - v_px. Solving with w_clip = -z gives

    [ 2fx/W   0       1 - 2cx/W          0            ]
    [ 0       2fy/H   2cy/H - 1          0            ]
    [ 0       0       -(f + n)/(f - n)   -2fn/(f - n) ]
    [ 0       0       -1                 0            ]

so the GL sample of window pixel (x, y_gl) is exactly the ray of image pixel (x, H - 1 - y_gl).
"""

from __future__ import annotations

import math

import numpy as np


def projection_matrix(fx: float, fy: float, cx: float, cy: float, width: int, height: int,
                      near: float, far: float) -> np.ndarray:
    """(4, 4) float64 OpenGL clip matrix (column vectors: clip = P @ [x, y, z, 1]) for pinhole intrinsics in
    pixels, camera looking down -z, ``0 < near < far`` (view-space depths). See the module docstring."""
    if not (near > 0 and far > near and math.isfinite(far)):
        raise ValueError(f"need 0 < near < far < inf, got near={near}, far={far}")
    w, h = float(width), float(height)
    p = np.zeros((4, 4), dtype=np.float64)
    p[0, 0] = 2.0 * fx / w
    p[0, 2] = 1.0 - 2.0 * cx / w
    p[1, 1] = 2.0 * fy / h
    p[1, 2] = 2.0 * cy / h - 1.0
    p[2, 2] = -(far + near) / (far - near)
    p[2, 3] = -2.0 * far * near / (far - near)
    p[3, 2] = -1.0
    return p


def view_matrix(c2w) -> np.ndarray:
    """(4, 4) float64 world-to-camera matrix from a (4, 4) or (3, 4) rigid camera-to-world pose."""
    m = np.asarray(c2w, dtype=np.float64)
    rot, t = m[:3, :3], m[:3, 3]
    out = np.eye(4, dtype=np.float64)
    out[:3, :3] = rot.T
    out[:3, 3] = -rot.T @ t
    return out


def mesh_bounds(vertices) -> np.ndarray:
    """(2, 3) float64 [min, max] corners of the axis-aligned box of (V, 3) vertices."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    if v.shape[0] == 0:
        return np.zeros((2, 3))
    return np.stack([v.min(axis=0), v.max(axis=0)])


def near_far_for(bounds, camera_center, c2w=None, *, min_ratio: float = 1e-4) -> tuple[float, float]:
    """A tight (near, far) view-depth range, 0 < near < far, that contains the box ``bounds`` (2, 3).

    With ``c2w`` (4, 4) the range comes from the view-space depths of the 8 (slightly padded) box corners --
    depth is linear, so its extremes over the box are at corners. Without it, only ``camera_center`` (3,) is
    known: far is the largest corner distance and near half the distance to the box (safe for fields of view
    up to about 110 degrees on the diagonal). near is never below ``min_ratio * far`` (24-bit depth buffer).
    """
    b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
    c = np.asarray(camera_center, dtype=np.float64).reshape(3)
    diag = float(np.linalg.norm(b[1] - b[0]))
    pad = 0.01 * diag + 1e-6 * max(1.0, float(np.abs(b).max()), float(np.abs(c).max()))
    lo, hi = b[0] - pad, b[1] + pad
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    if c2w is not None:
        view = view_matrix(c2w)
        depth = -(corners @ view[:3, :3].T + view[:3, 3])[:, 2]
        far = float(depth.max())
        near_raw = float(depth.min())
    else:
        far = float(np.linalg.norm(corners - c, axis=1).max())
        near_raw = 0.5 * float(np.linalg.norm(c - np.clip(c, lo, hi)))
    if not far > 0:  # the whole box is behind the camera: nothing is visible; any valid range will do
        far = max(diag, 1.0)
    near = max(near_raw, far * min_ratio)
    if not far > near:
        far = near * 2.0
    return near, far


def mvp_for(cameras, i: int, near: float, far: float) -> np.ndarray:
    """(4, 4) float64 model-view-projection (world -> clip) of camera ``i`` of ``cameras``."""
    p = projection_matrix(float(cameras.fx[i]), float(cameras.fy[i]), float(cameras.cx[i]), float(cameras.cy[i]),
                          cameras.width, cameras.height, near, far)
    return p @ view_matrix(cameras.c2w[i].double().numpy())


def camera_near_far(bounds, cameras, i: int) -> tuple[float, float]:
    """:func:`near_far_for` for camera ``i`` using its full pose (the tight variant)."""
    c2w = cameras.c2w[i].double().numpy()
    return near_far_for(bounds, c2w[:3, 3], c2w)


def screen_box(bounds, mvp: np.ndarray, width: int, height: int, margin: int = 2) -> tuple[int, int, int, int]:
    """(x, y, w, h) GL window rectangle (origin bottom-left) containing the projection of the box ``bounds``
    (2, 3) under ``mvp`` (4, 4), grown by ``margin`` pixels and clamped to the viewport; the whole viewport
    when a box corner lies on or behind the camera plane (the projection is then unbounded)."""
    b = np.asarray(bounds, np.float64)
    corners = np.array([[b[i, 0], b[j, 1], b[k, 2], 1.0] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    clip = corners @ np.asarray(mvp, np.float64).T
    if (clip[:, 3] <= 1e-9).any():
        return 0, 0, int(width), int(height)
    ndc = clip[:, :2] / clip[:, 3:4]
    x0 = int(np.floor((ndc[:, 0].min() + 1) * 0.5 * width)) - margin
    x1 = int(np.ceil((ndc[:, 0].max() + 1) * 0.5 * width)) + margin
    y0 = int(np.floor((ndc[:, 1].min() + 1) * 0.5 * height)) - margin
    y1 = int(np.ceil((ndc[:, 1].max() + 1) * 0.5 * height)) + margin
    x0, y0 = max(0, x0), max(0, y0)
    x1, y1 = min(int(width), x1), min(int(height), y1)
    return x0, y0, max(0, x1 - x0), max(0, y1 - y0)


def shift_cameras(cameras, offset):
    """``cameras`` with every centre moved by ``-offset`` (3,) (computed in float64): the cameras in a frame
    centred on ``offset``, e.g. a bundle's origin, so GL works on small float32 coordinates."""
    from ..render.cameras import Cameras

    offset = np.asarray(offset, dtype=np.float64).reshape(3)
    if not offset.any():
        return cameras
    c2w = cameras.c2w.double().numpy().copy()
    c2w[:, :3, 3] -= offset
    return Cameras(c2w.astype(np.float32), cameras.fx, cameras.fy, cameras.cx, cameras.cy, cameras.width,
                   cameras.height)


def gl_matrix(m) -> bytes:
    """Bytes of a (4, 4) matrix as a GLSL ``mat4`` uniform expects (column-major float32)."""
    return np.ascontiguousarray(np.asarray(m, dtype=np.float64).T, dtype=np.float32).tobytes()
