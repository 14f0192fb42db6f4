"""Image error metrics: PSNR and SSIM between a rendered and a reference image.

Both take (H, W, 3) float arrays in [0, 1] (data range 1). PSNR clamps the MSE at 1e-10 so identical images
give 100 dB instead of inf; averages over several images are means of per-image values, never pooled MSE.
SSIM uses an 11x11 Gaussian window (sigma 1.5), C1 = 0.01^2, C2 = 0.03^2, computed in float64 and averaged
over the valid (un-padded) region and the three channels, as in Wang et al. 2004.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

MAX_PSNR = 100.0


def psnr(image: np.ndarray, reference: np.ndarray, mask: np.ndarray | None = None) -> float:
    """PSNR in dB of (H, W, 3) ``image`` against ``reference``; optional (H, W) bool ``mask`` of pixels to use."""
    a = np.asarray(image, dtype=np.float64)
    b = np.asarray(reference, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"psnr: shapes differ {a.shape} vs {b.shape}")
    diff = (a - b) ** 2
    if mask is not None:
        diff = diff[np.asarray(mask, dtype=bool)]
    mse = max(float(diff.mean()) if diff.size else 0.0, 1e-10)
    return float(min(MAX_PSNR, -10.0 * np.log10(mse)))


def ssim(image: np.ndarray, reference: np.ndarray) -> float:
    """Mean SSIM of (H, W, 3) ``image`` against ``reference`` (11x11 Gaussian window, sigma 1.5)."""
    a = np.asarray(image, dtype=np.float64)
    b = np.asarray(reference, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"ssim: shapes differ {a.shape} vs {b.shape}")
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
