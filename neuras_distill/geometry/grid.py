"""Chunked sampling of a scalar field on one global lattice (no seams between chunks).

This module owns the lattice: where the grid points are (:class:`GridSpec`, :func:`grid_spec`) and how a
scalar function is evaluated on them in bounded memory (:func:`sample_grid`). Every chunk computes its points
from the same global formula ``origin + index * spacing`` (in float64, then cast to float32), so evaluating in
slabs gives bit-identical values to evaluating everything at once, whatever the chunk size.

Resolution:
* an ``int`` R is the number of lattice points along the *longest* box side; the other sides get as many
  points as keep the voxels cubic (spacing ``h = longest / (R - 1)`` on every axis). Where a side is not a
  whole number of voxels long, its lattice is grown symmetrically (by less than one voxel) so it still covers
  the whole box: the lattice box contains ``aabb``.
* a sequence (R0, R1, R2) is used as given: lattice points at ``aabb_min + i * (aabb_max - aabb_min) / (R - 1)``
  on each axis (voxels are then cubic only if the box's proportions match).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import torch

from ..errors import BadInputError, require

MAX_POINTS_PER_AXIS = 2048


@dataclass(frozen=True)
class GridSpec:
    """A regular lattice: point (i, j, k) sits at ``origin + (i, j, k) * spacing``.

    Attributes:
        origin: (3,) float64 world position of point (0, 0, 0).
        spacing: (3,) float64 distance between neighbouring points per axis (world units).
        shape: (R0, R1, R2) number of points per axis (x, y, z).
    """

    origin: np.ndarray
    spacing: np.ndarray
    shape: tuple[int, int, int]

    @property
    def num_points(self) -> int:
        return int(np.prod(self.shape))

    @property
    def box(self) -> np.ndarray:
        """(2, 3) float64 world box spanned by the lattice (first and last point)."""
        return np.stack([self.origin, self.origin + (np.asarray(self.shape) - 1) * self.spacing])

    def points(self, i0: int = 0, i1: int | None = None) -> np.ndarray:
        """(n, 3) float32 world positions of the slab of x indices [i0, i1), x slowest, z fastest."""
        i1 = self.shape[0] if i1 is None else i1
        ix = np.arange(i0, i1, dtype=np.float64)
        iy = np.arange(self.shape[1], dtype=np.float64)
        iz = np.arange(self.shape[2], dtype=np.float64)
        xs = self.origin[0] + ix * self.spacing[0]
        ys = self.origin[1] + iy * self.spacing[1]
        zs = self.origin[2] + iz * self.spacing[2]
        gx, gy, gz = np.meshgrid(xs, ys, zs, indexing="ij")
        return np.stack([gx, gy, gz], axis=-1).reshape(-1, 3).astype(np.float32)


def _aabb_numpy(aabb) -> np.ndarray:
    if isinstance(aabb, torch.Tensor):
        aabb = aabb.detach().to("cpu", torch.float64).numpy()
    box = np.asarray(aabb, dtype=np.float64)
    require(box.shape == (2, 3), f"the field's aabb must be a (2, 3) box [min, max], got shape {box.shape}")
    require(bool(np.isfinite(box).all()), "the field's aabb contains NaN or Inf; give a finite bounding box")
    require(bool((box[1] > box[0]).all()),
            f"the field's aabb must have max > min on every axis, got min {box[0].tolist()} max {box[1].tolist()}")
    return box


def grid_spec(aabb, resolution: int | Sequence[int]) -> GridSpec:
    """The lattice used for ``aabb`` ((2, 3) tensor/array) at ``resolution`` (see the module docstring)."""
    box = _aabb_numpy(aabb)
    extent = box[1] - box[0]
    if isinstance(resolution, (int, np.integer)) and not isinstance(resolution, bool):
        r = int(resolution)
        require(2 <= r <= MAX_POINTS_PER_AXIS,
                f"grid resolution must be between 2 and {MAX_POINTS_PER_AXIS} points per axis, got {r}")
        h = float(extent.max()) / (r - 1)
        counts = np.maximum(2, np.ceil(extent / h - 1e-6).astype(np.int64) + 1)
        grown = (counts - 1) * h - extent  # >= 0 (up to rounding), < one voxel
        origin = box[0] - 0.5 * grown
        spacing = np.full(3, h)
        shape = tuple(int(c) for c in counts)
    else:
        try:
            res = [int(v) for v in resolution]
        except TypeError:
            raise BadInputError(f"grid resolution must be an int or three ints, got {resolution!r}") from None
        require(len(res) == 3, f"grid resolution must be an int or three ints, got {resolution!r}")
        require(all(2 <= v <= MAX_POINTS_PER_AXIS for v in res),
                f"grid resolution must be between 2 and {MAX_POINTS_PER_AXIS} points per axis, got {res}")
        origin = box[0].copy()
        spacing = extent / (np.asarray(res, dtype=np.float64) - 1)
        shape = tuple(res)
    return GridSpec(origin=origin, spacing=spacing, shape=shape)


def _to_numpy(values, n: int) -> np.ndarray:
    if isinstance(values, torch.Tensor):
        values = values.detach().to("cpu", torch.float32).numpy()
    out = np.asarray(values, dtype=np.float32).reshape(-1)
    if out.shape[0] != n:
        raise BadInputError(f"the field's geometry() returned {out.shape[0]} values for {n} points; "
                            "it must return one value per point, shape (N,)")
    return out


def sample_grid(fn: Callable[[torch.Tensor], torch.Tensor], aabb, resolution: int | Sequence[int], *,
                outside: float = 0.0, chunk_points: int = 1 << 20, device: torch.device | str | None = None,
                stats: dict | None = None) -> np.ndarray:
    """Evaluate ``fn`` on the lattice :func:`grid_spec` (``aabb``, ``resolution``) in slabs along x.

    Args:
        fn: maps x (N, 3) float32 tensor -> (N,) values (tensor or array).
        aabb: (2, 3) box [min, max].
        resolution: int (points along the longest side, cubic voxels) or (R0, R1, R2).
        outside: the value written where ``fn`` returns NaN/Inf ("outside": large positive SDF, 0 density).
        chunk_points: about how many points are evaluated per call (memory bound); slabs hold whole x slices,
            split further into rows when one slice is larger than this.
        device: where the points are sent (default: the device of ``aabb`` when it is a tensor, else CPU).
        stats: if given, receives ``grid_shape``, ``grid_spacing``, ``grid_origin``, ``grid_nonfinite``
            (number of values replaced) and ``grid_seconds``.

    Returns:
        (R0, R1, R2) float32 array, ``grid[i, j, k] = fn(origin + (i, j, k) * spacing)``.
    """
    t0 = time.perf_counter()
    spec = grid_spec(aabb, resolution)
    if device is None:
        device = aabb.device if isinstance(aabb, torch.Tensor) else "cpu"
    r0, r1, r2 = spec.shape
    slices_per_chunk = max(1, max(1, int(chunk_points)) // (r1 * r2))
    grid = np.empty(spec.shape, dtype=np.float32)
    nonfinite = 0
    for i0 in range(0, r0, slices_per_chunk):
        i1 = min(r0, i0 + slices_per_chunk)
        grid[i0:i1], bad = sample_slab(fn, spec, i0, i1, outside=outside, chunk_points=chunk_points, device=device)
        nonfinite += bad
    if stats is not None:
        stats.update(grid_shape=list(spec.shape), grid_spacing=spec.spacing.tolist(),
                     grid_origin=spec.origin.tolist(), grid_nonfinite=nonfinite,
                     grid_seconds=time.perf_counter() - t0)
    return grid


def sample_slab(fn: Callable[[torch.Tensor], torch.Tensor], spec: GridSpec, i0: int, i1: int, *,
                outside: float = 0.0, chunk_points: int = 1 << 20,
                device: torch.device | str = "cpu") -> tuple[np.ndarray, int]:
    """``fn`` on the x slices [i0, i1) of the lattice ``spec``: ((i1 - i0, R1, R2) float32 values, how many
    NaN/Inf values were replaced by ``outside``), ``chunk_points`` points per call. The same values as those
    slices of :func:`sample_grid`: every point comes from the lattice's global formula."""
    per_slice = spec.shape[1] * spec.shape[2]
    chunk_points = max(1, int(chunk_points))
    step = max(1, chunk_points // per_slice)             # the points of a few slices at a time (float64 meshgrids)
    out = np.empty((i1 - i0) * per_slice, dtype=np.float32)
    with torch.no_grad():
        for s0 in range(i0, i1, step):
            s1 = min(i1, s0 + step)
            pts = spec.points(s0, s1)
            base = (s0 - i0) * per_slice
            for p0 in range(0, pts.shape[0], chunk_points):
                p1 = min(pts.shape[0], p0 + chunk_points)
                out[base + p0:base + p1] = _to_numpy(fn(torch.from_numpy(pts[p0:p1]).to(device)), p1 - p0)
    bad = ~np.isfinite(out)
    out[bad] = outside
    return out.reshape(i1 - i0, spec.shape[1], spec.shape[2]), int(bad.sum())


def field_outside_value(kind: str, aabb) -> float:
    """The "outside" value for a field kind: 0 density, or an SDF larger than any distance in the box."""
    if kind == "density":
        return 0.0
    box = _aabb_numpy(aabb)
    return float(2.0 * np.linalg.norm(box[1] - box[0]) + 1.0)


__all__ = ["GridSpec", "grid_spec", "sample_grid", "field_outside_value"]
