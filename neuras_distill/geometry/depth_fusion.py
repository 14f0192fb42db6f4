"""A surface for a density field from its own depth maps: a truncated signed distance fused over the views.

A trained NeRF is supervised only where rays end: behind its opaque surface the density is whatever the
optimiser left there, and marching cubes turns that into tunnels, pockets and handles. On the Instant-NGP
gradient-ball snapshot the level set had 951,002 faces, the largest component of genus ~2,700 with 3.8x the
sphere's area; xatlas could not unwrap it in 2 x 120 s. Fusing the views' surface depths (where each pixel's
opacity reaches 0.5) the way RGB-D scans are fused (a truncated signed distance averaged over views) gives
the surface the cameras saw and nothing behind it: 333k faces, area within 1.3x, 0.7% folded faces.
Lattice points more than the truncation behind the surface in some view and seen in front of it by none
are inside; points no camera sees are outside.
A partly trained ground is a haze, opaque in some views and not in others: with ``faint`` a pixel whose opacity
passes a lower level votes for a surface where its opacity starts instead of for free space.

Frames: world coordinates; cameras are OpenGL (x right, y up, -z forward) with unit ray directions, so the
volume renderer's depths are Euclidean distances from the camera centre.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy import ndimage

#: A faint region (``faint_regions``) is at least this many pixels wide: the one-pixel band where a silhouette
#: covers pixels in part is not a haze (the half-voxel outset, ``extract.FUSED_OUTSET_VOXELS``, covers it). With
#: one-pixel regions kept, the nerfstudio bunny's soft rims added 144 UV charts and its atlas rule chose 512² over
#: 448², training then touched more texels than the index texture holds (33.44 -> 32.24 dB); at 2 it is unchanged
#: (33.42) and orbit360 keeps most of the gain (holes 0.35% against 0.26%).
FAINT_MIN_WIDTH_PX = 2


def fused_depth_sdf(origin, spacing, shape, cameras, depths: np.ndarray, opacities: np.ndarray, *,
                    truncation: float, opaque: float = 0.5, chunk: int = 1 << 20,
                    faint: tuple[np.ndarray, float] | None = None) -> tuple[np.ndarray, dict]:
    """A truncated signed distance (positive outside, world units) fused from the field's depth maps.

    Per view a lattice point ``x`` projecting onto pixel p gets ``clamp(depth(p) - |x - c|, -t, t)``
    (``t = truncation``) with weight 1 when p is opaque and ``|x - c| < depth(p) + t``; ``+t`` (free space)
    when p is not opaque; nothing when it lies more than ``t`` behind the surface (it is then marked
    "behind"). The fused value is the weighted mean; points with no weight are
    ``-t`` when behind in some view (hidden interior) and ``+t`` otherwise (seen by no camera).

    Args:
        origin: (3,) world position of lattice point (0, 0, 0); spacing: (3,) voxel size; shape: (R0, R1, R2).
        cameras: ``Cameras`` of the views (N); depths, opacities: (N, H, W) the field's depth where each
            pixel's opacity reaches ``opaque`` (distance along the unit ray; ``render.volume``) and opacity.
        faint: optional ((N, H, W) depths, level): a pixel whose opacity exceeds ``level`` but not ``opaque``
            is a faint surface at that depth (the fringe depth: where its opacity starts) instead of free space.
    Returns:
        ((R0, R1, R2) float32 SDF, stats {"fused_views", "fused_weighted_fraction", "fused_hidden_fraction",
        "fused_faint_pixels": the share of the views' pixels taken as a faint surface}).
    """
    origin = np.asarray(origin, dtype=np.float64)
    spacing = np.asarray(spacing, dtype=np.float64)
    shape = tuple(int(s) for s in shape)
    total = int(np.prod(shape))
    acc = np.zeros(total, dtype=np.float64)
    weight = np.zeros(total, dtype=np.float32)
    behind = np.zeros(total, dtype=bool)
    axes = [origin[k] + spacing[k] * np.arange(shape[k]) for k in range(3)]
    t = float(truncation)
    faint_pixels = 0
    for i in range(len(cameras)):
        # depth of the pixel's surface; +inf where it is not opaque (everything along that ray is free)
        own = np.where(opacities[i] > opaque, depths[i], np.inf)
        if faint is not None:
            haze = faint_regions(opacities[i], faint[1], opaque)
            faint_pixels += int(haze.sum())
            own = np.where(haze, faint[0][i], own)
        own = torch.from_numpy(own.astype(np.float64).reshape(-1))
        for sel_np, pixel, dist in _projections(cameras, i, axes, shape, total, chunk):
            d = own[pixel]
            sd = d - dist                                     # +inf on background pixels
            near = sd > -t
            acc[sel_np[near.numpy()]] += sd[near].clamp(-t, t).numpy()
            weight[sel_np[near.numpy()]] += 1.0
            behind[sel_np[(~near).numpy()]] = True
    sdf = np.where(weight > 0, acc / np.maximum(weight, 1.0), np.where(behind, -t, t)).astype(np.float32)
    stats = {"fused_views": len(cameras), "fused_weighted_fraction": float((weight > 0).mean()),
             "fused_hidden_fraction": float(((weight == 0) & behind).mean()),
             "fused_faint_pixels": faint_pixels / max(int(np.prod(opacities.shape)), 1)}
    return sdf.reshape(shape), stats


def faint_regions(opacity: np.ndarray, level: float, opaque: float) -> np.ndarray:
    """(H, W) bool: pixels whose opacity passes ``level`` but not ``opaque``, in regions at least
    :data:`FAINT_MIN_WIDTH_PX` wide (a morphological opening): a haze seen faint, not the one-pixel band where a
    silhouette covers a pixel in part. ``opacity``: (H, W)."""
    mask = (opacity > level) & (opacity <= opaque)
    return ndimage.binary_opening(mask, structure=np.ones((FAINT_MIN_WIDTH_PX, FAINT_MIN_WIDTH_PX), dtype=bool))


def _projections(cameras, i: int, axes, shape, total: int, chunk: int):
    """Yield (lattice indices (M,), pixel indices (M,) long tensor, distances to the camera (M,) float64
    tensor) for the lattice points camera ``i`` sees inside its image, chunk by chunk."""
    c2w = cameras.c2w[i].double().numpy()
    rot_t = torch.from_numpy(c2w[:3, :3].copy())          # row vectors: x_cam = (x - c) @ R
    centre_t = torch.from_numpy(c2w[:3, 3].copy())
    fx, fy = float(cameras.fx[i]), float(cameras.fy[i])
    cx, cy = float(cameras.cx[i]), float(cameras.cy[i])
    h, w = cameras.height, cameras.width
    for start in range(0, total, chunk):
        idx = np.arange(start, min(start + chunk, total))
        i0, rest = np.divmod(idx, shape[1] * shape[2])
        i1, i2 = np.divmod(rest, shape[2])
        rel = torch.from_numpy(np.stack([axes[0][i0], axes[1][i1], axes[2][i2]], axis=1)) - centre_t
        cam = rel @ rot_t                                  # camera frame: -z forward
        z = -cam[:, 2]
        ahead = z > 1e-9
        zs = torch.where(ahead, z, torch.ones_like(z))
        u = torch.round(fx * cam[:, 0] / zs + cx - 0.5).long()
        v = torch.round(cy - fy * cam[:, 1] / zs - 0.5).long()
        inside = ahead & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        if not bool(inside.any()):
            continue
        sel = torch.nonzero(inside).flatten()
        yield idx[sel.numpy()], v[sel] * w + u[sel], rel[sel].norm(dim=1)


__all__ = ["fused_depth_sdf"]
