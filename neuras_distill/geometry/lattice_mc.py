"""Marching cubes on one lattice of values (the only scikit-image importer), the level nudged off exact ties,
and the signed volume that checks a closed mesh's orientation. Used by :mod:`.marching` (one lattice) and
:mod:`.blocks` (a lattice in blocks)."""

from __future__ import annotations

import numpy as np
from skimage import measure


def nudge_level(grid: np.ndarray, level: float) -> float:
    """``level`` raised by a negligible amount (1e-7 of the grid's range, doubling) until no grid value equals
    it exactly (exact ties make zero-area triangles and holes, scikit-image#8116)."""
    lv = np.float32(level)
    if not np.any(grid == lv):
        return float(lv)
    step = 1e-7 * max(abs(float(level)), float(grid.max()) - float(grid.min()), 1e-30)
    for i in range(64):
        if not np.any(grid == lv):
            return float(lv)
        lv = np.float32(float(level) + step * (2 ** i))
    return float(lv)


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume (float64) enclosed by a closed mesh; positive when faces are CCW seen from outside."""
    if faces.shape[0] == 0:
        return 0.0
    v = np.asarray(vertices, dtype=np.float64)
    total = 0.0
    for f0 in range(0, faces.shape[0], 1 << 20):            # bounded temporaries on multi-million-face meshes
        f = faces[f0:f0 + (1 << 20)]
        total += float(np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum())
    return total / 6.0


def lattice_marching_cubes(values: np.ndarray, level: float, gradient_direction: str,
                           spacing: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """scikit-image's marching cubes on ``values`` (R0, R1, R2) at ``level``, no degenerate triangles: (vertices
    (V, 3) float32 in lattice index units times ``spacing``, faces (F, 3) int). ``gradient_direction``:
    "descent" for an SDF."""
    verts, faces, _, _ = measure.marching_cubes(values, level=level, spacing=spacing,
                                                gradient_direction=gradient_direction,
                                                allow_degenerate=False)
    return verts, faces
