"""The fringe shell around a colour-level core as an offset of the core (``marching.offset_grid``,
``geometry.shell = "offset"``): its level sets are the core pushed out by a distance, smooth where the field's
own low-density levels are a trained NeRF's speckled fog."""

from __future__ import annotations

import numpy as np

from neuras_distill.geometry.marching import marching_cubes_grid, mesh_handles, offset_grid

N = 64
VOXEL = 1.0 / (N - 1)


def ball_grid(speckle: float = 0.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(N, N, N) density of a ball of radius 0.3 at the centre of the unit box, with a soft fringe and, when
    ``speckle`` > 0, multiplicative noise on the fringe's voxels (density < 10: a briefly trained hash grid's
    fringe; the dense core stays clean). Returns (grid, the radius of each lattice point)."""
    x = np.linspace(0.0, 1.0, N, dtype=np.float32)
    r = np.linalg.norm(np.stack(np.meshgrid(x, x, x, indexing="ij"), -1) - 0.5, axis=-1)
    grid = 100.0 / (1.0 + np.exp((r - 0.3) / 0.02))
    if speckle:
        noise = np.exp(speckle * np.random.default_rng(seed).standard_normal(grid.shape))
        grid = np.where(grid < 10.0, grid * noise, grid)
    return grid.astype(np.float32), r


def radii(mesh) -> np.ndarray:
    return np.linalg.norm(mesh.vertices - 0.5, axis=1)


def test_offset_levels_are_the_core_pushed_out_by_that_distance():
    grid, _ = ball_grid()
    core_level = 50.0                                        # the core: radius 0.3
    signed = offset_grid(grid, core_level, (VOXEL,) * 3)
    assert signed.shape == grid.shape and signed.dtype == np.float32
    assert signed[N // 2, N // 2, N // 2] < 0 < signed[0, 0, 0]       # negative inside, positive outside
    core = radii(marching_cubes_grid(grid, (0, 0, 0), (VOXEL,) * 3, "density", core_level))
    for voxels in (2, 5, 10):
        shell = radii(marching_cubes_grid(signed, (0, 0, 0), (VOXEL,) * 3, "sdf", voxels * VOXEL))
        # one sphere, its radius the core's plus the distance (within half a voxel), and round
        assert abs(np.median(shell) - np.median(core) - voxels * VOXEL) < 0.5 * VOXEL, (voxels, np.median(shell))
        assert shell.max() - shell.min() < 0.6 * VOXEL, voxels


def test_on_a_speckled_fringe_the_offset_shell_is_smooth_where_the_density_level_is_ragged():
    """The Instant-NGP ball's failure: its fringe is noise, so a low density level (where a shell enclosing the
    fringe sits) is a ragged, perforated blob; the offset of the (dense, so clean) core is a sphere."""
    grid, _ = ball_grid(speckle=1.5)
    core_level = 50.0
    level_shell = marching_cubes_grid(grid, (0, 0, 0), (VOXEL,) * 3, "density", 0.5)     # ~0.39 from the centre
    signed = offset_grid(grid, core_level, (VOXEL,) * 3)
    offset_shell = marching_cubes_grid(signed, (0, 0, 0), (VOXEL,) * 3, "sdf", 6 * VOXEL)
    spread_level = np.percentile(radii(level_shell), 99) - np.percentile(radii(level_shell), 1)
    spread_offset = np.percentile(radii(offset_shell), 99) - np.percentile(radii(offset_shell), 1)
    assert spread_offset < 1.0 * VOXEL < 3.0 * VOXEL < spread_level, (spread_offset, spread_level)
    assert mesh_handles(offset_shell) == 0
    assert offset_shell.num_faces < level_shell.num_faces / 2
