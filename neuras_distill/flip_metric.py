"""NVIDIA's FLIP perceptual error (Andersson et al. 2020) through the ``flip-evaluator`` package; the only
module that imports it.

LDR-FLIP on (H, W, 3) sRGB-encoded images in [0, 1], at FLIP's default viewing conditions (67 pixels per
degree: a 0.7 m wide 3840-pixel monitor seen from 0.7 m). The error map is in [0, 1] per pixel (0: no visible
difference); the mean is its plain mean. A NaN or Inf pixel in either image makes the mean NaN and marks that
pixel NaN in the map (FLIP itself would silently score it as a small error).
"""

from __future__ import annotations

import numpy as np

_HINT = "FLIP needs the flip-evaluator package: pip install flip-evaluator"


def flip(image: np.ndarray, reference: np.ndarray) -> tuple[float, np.ndarray]:
    """LDR-FLIP of ``image`` against ``reference``, both (H, W, 3) sRGB values in [0, 1] (finite values
    outside are clipped). Returns (mean error, (H, W) float32 error map); the mean is NaN when either image
    has a non-finite pixel.

    Examples:
        >>> a = np.zeros((8, 8, 3), np.float32)
        >>> flip(a, a)[0]
        0.0
    """
    try:
        import flip_evaluator
    except ImportError as e:  # pragma: no cover - a declared dependency
        raise ImportError(_HINT) from e
    a = np.asarray(image, dtype=np.float32)
    b = np.asarray(reference, dtype=np.float32)
    if a.shape != b.shape or a.ndim != 3 or a.shape[-1] != 3:
        raise ValueError(f"flip: expected two (H, W, 3) images of one shape, got {a.shape} and {b.shape}")
    bad = ~(np.isfinite(a).all(axis=-1) & np.isfinite(b).all(axis=-1))

    def clean(x):
        return np.ascontiguousarray(np.clip(np.nan_to_num(x, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0))

    error_map, mean, _ = flip_evaluator.evaluate(clean(b), clean(a), "LDR", applyMagma=False)
    error_map = np.asarray(error_map, dtype=np.float32).reshape(a.shape[:2])
    if bad.any():
        error_map[bad] = np.nan
        return float("nan"), error_map
    return float(mean), error_map
