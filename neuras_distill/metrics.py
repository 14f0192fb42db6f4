"""Image error metrics: PSNR and SSIM between a rendered and a reference image.

Both take (H, W, 3) float arrays in [0, 1] (data range 1). PSNR clamps the MSE at 1e-10 so identical images
give 100 dB instead of inf; averages over several images are means of per-image values, never pooled MSE.
A NaN or Inf pixel (in the compared region) makes PSNR and SSIM NaN: never a finite, good-looking score
(before this rule a NaN pixel gave PSNR 100 dB, the best possible; tests/stability/test_metrics.py).
SSIM uses an 11x11 Gaussian window (sigma 1.5), C1 = 0.01^2, C2 = 0.03^2, computed in float64 and averaged
over the valid (un-padded) region and the three channels, as in Wang et al. 2004.

Region metrics split a view by the field's own opacity (H, W) of that view:
- silhouette band: pixels within ``band`` px (default ``band_width``: max(2, round(0.004 * image diagonal)),
  9 px at 1920x1080) of the boundary of the mask ``opacity > 0.5`` on either side, plus every pixel with
  0.02 < opacity < 0.98 (the soft fringe);
- interior: pixels with opacity > 0.98 that are not in the band;
- hole: the field is opaque (opacity > 0.5) but the bundle's mesh covers no pixel there.
A third split reads the field's own image: the smooth region is every pixel whose 5x5 neighbourhood has a luma
standard deviation below 0.01 (flat walls, sky, plain floor). Mottling shows there first.
FLIP lives in ``flip_metric`` (the one module that imports flip-evaluator) and is re-exported here.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import distance_transform_edt, gaussian_filter, uniform_filter

from .flip_metric import flip  # noqa: F401  (re-exported: metrics.flip)

MAX_PSNR = 100.0
OPAQUE = 0.5          # the field's mask: opacity > OPAQUE
FRINGE = (0.02, 0.98)  # soft fringe: FRINGE[0] < opacity < FRINGE[1]; interior: opacity > FRINGE[1]
SMOOTH_WINDOW = 5      # side in pixels of the neighbourhood ``smooth_mask`` measures
SMOOTH_LUMA_STD = 0.01  # a pixel is smooth when its neighbourhood's luma standard deviation is below this
LUMA_WEIGHTS = (0.2126, 0.7152, 0.0722)  # Rec. 709 luma of linear RGB


def psnr(image: np.ndarray, reference: np.ndarray, mask: np.ndarray | None = None) -> float:
    """PSNR in dB of (H, W, 3) ``image`` against ``reference``; optional (H, W) bool ``mask`` of pixels to use."""
    a = np.asarray(image, dtype=np.float64)
    b = np.asarray(reference, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"psnr: shapes differ {a.shape} vs {b.shape}")
    diff = (a - b) ** 2
    if mask is not None:
        diff = diff[np.asarray(mask, dtype=bool)]
    if not np.isfinite(diff).all():
        return float("nan")  # a NaN/Inf pixel: say so (max(nan, 1e-10) was nan and min(100, nan) gave 100 dB)
    mse = max(float(diff.mean()) if diff.size else 0.0, 1e-10)
    return float(min(MAX_PSNR, -10.0 * np.log10(mse)))


def ssim(image: np.ndarray, reference: np.ndarray) -> float:
    """Mean SSIM of (H, W, 3) ``image`` against ``reference`` (11x11 Gaussian window, sigma 1.5)."""
    a = np.asarray(image, dtype=np.float64)
    b = np.asarray(reference, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"ssim: shapes differ {a.shape} vs {b.shape}")
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        return float("nan")  # a NaN/Inf pixel spreads through the Gaussian window: no score, not a warning
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    sigma, truncate = 1.5, 3.5  # radius 5 -> an 11x11 window

    def blur(x):
        return gaussian_filter(x, sigma=(sigma, sigma, 0), truncate=truncate, mode="reflect")

    mu_a, mu_b = blur(a), blur(b)
    var_a = blur(a * a) - mu_a ** 2
    var_b = blur(b * b) - mu_b ** 2
    cov = blur(a * b) - mu_a * mu_b
    num = (2 * mu_a * mu_b + c1) * (2 * cov + c2)
    den = (mu_a ** 2 + mu_b ** 2 + c1) * (var_a + var_b + c2)
    s = num / den
    r = 5
    if s.shape[0] > 2 * r and s.shape[1] > 2 * r:
        s = s[r:-r, r:-r]
    return float(s.mean())


def error_heatmap(image: np.ndarray, reference: np.ndarray, full_scale: float = 0.1) -> np.ndarray:
    """(H, W, 3) float32 colour map of the per-pixel mean absolute error; ``full_scale`` maps to the hottest
    colour (black -> red -> yellow -> white)."""
    err = np.abs(np.asarray(image, np.float32) - np.asarray(reference, np.float32)).mean(axis=-1)
    t = np.clip(err / full_scale, 0.0, 1.0)
    r = np.clip(3 * t, 0, 1)
    g = np.clip(3 * t - 1, 0, 1)
    b = np.clip(3 * t - 2, 0, 1)
    return np.stack([r, g, b], axis=-1).astype(np.float32)


def band_width(height: int, width: int) -> int:
    """Default silhouette band half-width in pixels: max(2, round(0.004 * diagonal)) (9 at 1920x1080)."""
    return max(2, int(round(0.004 * float(np.hypot(height, width)))))


def silhouette_band(opacity: np.ndarray, band: int | None = None) -> np.ndarray:
    """(H, W) bool: pixels within ``band`` px (Euclidean, default ``band_width``) of the boundary of the mask
    ``opacity > 0.5`` on either side, plus the soft fringe 0.02 < opacity < 0.98. ``opacity`` is (H, W)."""
    op = np.asarray(opacity, dtype=np.float32)
    if op.ndim != 2:
        raise ValueError(f"silhouette_band: expected an (H, W) opacity, got {op.shape}")
    band = band_width(*op.shape) if band is None else int(band)
    inside = op > OPAQUE
    near = np.zeros_like(inside)
    if inside.any() and not inside.all():
        # distance of an inside pixel to the nearest outside pixel (1 next to the boundary), and vice versa
        near = np.where(inside, distance_transform_edt(inside), distance_transform_edt(~inside)) <= band
    return near | ((op > FRINGE[0]) & (op < FRINGE[1]))


def interior_mask(opacity: np.ndarray, band_mask: np.ndarray | None = None) -> np.ndarray:
    """(H, W) bool: opacity > 0.98 and not in the silhouette band (``band_mask`` (H, W) bool, default
    ``silhouette_band(opacity)``)."""
    op = np.asarray(opacity, dtype=np.float32)
    band_mask = silhouette_band(op) if band_mask is None else band_mask
    return (op > FRINGE[1]) & ~band_mask


def smooth_mask(reference: np.ndarray, window: int = SMOOTH_WINDOW,
                threshold: float = SMOOTH_LUMA_STD) -> np.ndarray:
    """(H, W) bool: pixels of the (H, W, 3) ``reference`` (the field's image) whose ``window`` x ``window``
    neighbourhood (clipped at the frame's edge by reflection) has a luma standard deviation below ``threshold``."""
    ref = np.asarray(reference, dtype=np.float64)
    if ref.ndim != 3 or ref.shape[-1] != 3:
        raise ValueError(f"smooth_mask: expected an (H, W, 3) image, got {ref.shape}")
    luma = ref @ np.asarray(LUMA_WEIGHTS)
    mean = uniform_filter(luma, window, mode="reflect")
    var = uniform_filter(luma * luma, window, mode="reflect") - mean * mean
    return np.sqrt(np.maximum(var, 0.0)) < threshold


def hole_mask(opacity: np.ndarray, coverage: np.ndarray) -> np.ndarray:
    """(H, W) bool: the field is opaque (opacity > 0.5) and the bundle's mesh covers nothing (``coverage``
    (H, W) bool False)."""
    op = np.asarray(opacity, dtype=np.float32)
    cov = np.asarray(coverage, dtype=bool)
    if op.shape != cov.shape:
        raise ValueError(f"hole_mask: opacity {op.shape} and coverage {cov.shape} differ")
    return (op > OPAQUE) & ~cov


def hole_fraction(opacity: np.ndarray, coverage: np.ndarray) -> float:
    """Fraction of ALL pixels of the (H, W) view that are holes (``hole_mask``)."""
    return float(hole_mask(opacity, coverage).mean())


def region_psnr(image: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float | None:
    """PSNR over the (H, W) bool ``mask`` only; None when the mask is empty (no region, no score)."""
    return psnr(image, reference, mask) if np.asarray(mask, bool).any() else None
