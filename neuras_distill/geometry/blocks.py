"""Marching cubes of a large SDF field in blocks along x: memory bounded by one block, not the whole lattice.

A 0.6 km city at 0.29 m voxels is a 2048 x 478 x 230 lattice: 225 M points, 900 MB as float32, and meshing it
in one piece held the grid, its cavity fill, its padded copy and scikit-image's own arrays at once (4172 MB
peak). Here the lattice is sampled one block of x slices at a time (plus the next block's first
slice), each block is padded on the sides the lattice's box closes (y and z always, x at the first and last
block) and meshed alone, and the blocks' vertices on their shared slices are welded. Every cube of the lattice is
meshed by exactly one block and a vertex on a shared slice is interpolated from the same two lattice values in
both, in lattice index coordinates where the slice's x is an exact integer, so welding by exact position gives
the mesh of the whole lattice (``tests/test_geometry_blocks.py``).

Differences from :func:`~neuras_distill.geometry.marching.marching_cubes_grid`: SDF fields only (level 0 or as
given; density fields keep the whole-grid path with its log space, fringe shells and fused depths) and no cavity
filling: it exists for a NeRF's hollow density shells; an SDF's enclosed cavity (none in our fields) would keep its
inner surface, which no view sees.
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import BadInputError
from .grid import GridSpec, sample_slab
from .lattice_mc import lattice_marching_cubes, nudge_level, signed_volume
from .mesh import MeshData

#: Lattices with more points than this are meshed in blocks (an SDF field without a fringe shell): 2^25 points
#: are 128 MB as float32.
BLOCK_MIN_POINTS = 1 << 25
#: Points per block (about; whole x slices): 2^24 points, 64 MB as float32.
BLOCK_POINTS = 1 << 24


def marching_cubes_blocks(fn, spec: GridSpec, level: float, *, outside: float, block_points: int = BLOCK_POINTS,
                          chunk_points: int = 1 << 20, device="cpu") -> MeshData:
    """Mesh the level set ``level`` of the SDF ``fn`` (x (N, 3) -> (N,), evaluated on ``device``) on the lattice
    ``spec``, one block of about ``block_points`` points at a time; ``outside`` replaces NaN/Inf values and pads
    the lattice's box (the same value in every block, so the caps weld too).

    Returns MeshData (vertices (V, 3) float32 world, faces (F, 3) int32 counter-clockwise from outside) with
    stats ``mc_blocks``, ``mc_block_slices``, ``grid_nonfinite``, ``grid_seconds`` (sampling) and
    ``mc_cavity_voxels`` = None (not filled). Raises BadInputError when the lattice holds no surface at ``level``.
    """

    r0, r1, r2 = spec.shape
    per_block = max(1, int(block_points) // (r1 * r2))
    starts = list(range(0, r0 - 1, per_block))
    pad = np.float32(level + 1e4 * (abs(float(outside)) + abs(level) + 1.0))
    for _ in range(4):
        verts, faces, count, lo, hi, nonfinite, sampling = [], [], 0, np.inf, -np.inf, 0, 0.0
        nudged = level
        for b, i0 in enumerate(starts):
            i1 = min(r0, i0 + per_block + 1)                  # one shared slice with the next block
            t0 = time.perf_counter()
            values, bad = sample_slab(fn, spec, i0, i1, outside=outside, chunk_points=chunk_points, device=device)
            sampling += time.perf_counter() - t0
            nonfinite += bad
            lo, hi = min(lo, float(values.min())), max(hi, float(values.max()))
            nudged = nudge_level(values, nudged)
            if nudged != level:
                break
            first, last = b == 0, i1 == r0
            padded = np.pad(values, ((1 if first else 0, 1 if last else 0), (1, 1), (1, 1)), mode="constant",
                            constant_values=pad)
            del values
            if not (float(padded.min()) < level < float(padded.max())):
                continue                                      # no surface in this block
            v, f = lattice_marching_cubes(padded, level, "descent")
            v = v.astype(np.float64) - np.array([1.0 if first else 0.0, 1.0, 1.0]) + np.array([i0, 0.0, 0.0])
            verts.append(v)
            faces.append(f.astype(np.int64) + count)
            count += v.shape[0]
        else:
            break
        level = nudged                                        # a tie in a later block: mesh again at its level
    else:
        raise BadInputError(f"the field's SDF takes the iso-level's value exactly at lattice points for every "
                            f"nudge tried (last {level!r}); pass another grid resolution")
    if not verts:
        raise BadInputError(f"the field has no surface inside its box at level {level:.4g} (its SDF spans "
                            f"{lo:.4g} .. {hi:.4g}); check the aabb and the field kind")
    index_coords = np.concatenate(verts)
    unique, inverse = np.unique(index_coords, axis=0, return_inverse=True)
    tri = inverse.reshape(-1)[np.concatenate(faces)]
    world = spec.origin + unique * spec.spacing
    if signed_volume(world, tri) < 0:
        tri = tri[:, ::-1]
    stats = {"mc_cavity_voxels": None, "mc_blocks": len(starts), "mc_block_slices": per_block,
             "grid_nonfinite": nonfinite, "grid_seconds": sampling}
    return MeshData(world.astype(np.float32), tri.astype(np.int32), None, stats)
