"""Marching cubes in blocks (geometry/blocks.py): the whole lattice's mesh, in bounded memory."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuras_distill.errors import BadInputError
from neuras_distill.geometry.blocks import marching_cubes_blocks
from neuras_distill.geometry.grid import field_outside_value, grid_spec, sample_grid
from neuras_distill.geometry.marching import marching_cubes_field, marching_cubes_grid
from neuras_distill.scenes.analytic import SphereSDF


def _two_spheres_and_a_cut(x: torch.Tensor) -> torch.Tensor:
    """Two spheres, one cut by the box (its cap closes the mesh), one whole."""
    a = (x - torch.tensor([0.0, 0.0, 0.0])).norm(dim=-1) - 0.45
    b = (x - torch.tensor([0.9, 0.2, 0.1])).norm(dim=-1) - 0.3
    return torch.minimum(a, b)


BOX = torch.tensor([[-0.3, -0.6, -0.5], [1.3, 0.6, 0.5]])


def _same_triangles(a, b, tol: float) -> None:
    """Every face of ``a`` has a face of ``b`` with the same corners (as a set) within ``tol``, and back."""
    from scipy.spatial import cKDTree

    def keys(m):
        c = m.vertices[m.faces].astype(np.float64)                  # (F, 3, 3)
        return np.concatenate([c.mean(1), np.sort(c.reshape(-1, 9), axis=1)], axis=1)

    ka, kb = keys(a), keys(b)
    for x, y in ((ka, kb), (kb, ka)):
        dist, _ = cKDTree(y).query(x)
        assert dist.max() < tol, dist.max()


@pytest.mark.parametrize("slices", [9, 3, 1, 1000])
def test_blocks_give_the_whole_lattice_mesh(slices):
    spec = grid_spec(BOX, 65)
    block_points = slices * spec.shape[1] * spec.shape[2]
    outside = field_outside_value("sdf", BOX)
    whole = marching_cubes_grid(sample_grid(_two_spheres_and_a_cut, BOX, 65, outside=outside), spec.origin,
                                spec.spacing, "sdf", 0.0, fill=False)
    blocks = marching_cubes_blocks(_two_spheres_and_a_cut, spec, 0.0, outside=outside, block_points=block_points)
    assert blocks.num_faces == whole.num_faces and blocks.num_vertices == whole.num_vertices
    _same_triangles(blocks, whole, 1e-4 * spec.spacing.max())
    assert blocks.stats["mc_blocks"] == -(-(spec.shape[0] - 1) // slices)
    edges = np.sort(np.concatenate([blocks.faces[:, [0, 1]], blocks.faces[:, [1, 2]], blocks.faces[:, [2, 0]]]), 1)
    _, uses = np.unique(edges, axis=0, return_counts=True)
    assert (uses == 2).all()                          # welded: closed, every edge shared by exactly two faces


def test_a_field_meshed_in_blocks_when_its_lattice_is_large(monkeypatch):
    from neuras_distill.geometry import blocks

    sphere = SphereSDF(radius=0.5)
    whole = marching_cubes_field(sphere, 48)
    monkeypatch.setattr(blocks, "BLOCK_MIN_POINTS", 1000)
    monkeypatch.setattr(blocks, "BLOCK_POINTS", 48 * 48 * 5)
    split = marching_cubes_field(sphere, 48)
    assert split.stats["mc_blocks"] >= 9 and "mc_blocks" not in whole.stats
    assert split.num_faces == whole.num_faces
    _same_triangles(split, whole, 1e-5)


def test_a_lattice_without_surface_is_refused():
    spec = grid_spec(BOX, 17)
    with pytest.raises(BadInputError, match="no surface"):
        marching_cubes_blocks(lambda x: x.norm(dim=-1) + 5.0, spec, 0.0, outside=10.0, block_points=17 * 17 * 4)


@pytest.mark.slow
def test_decimation_in_blocks_gives_a_closed_mesh_on_the_surface_within_budget():
    """Two spheres meshed at 160 (about 180k faces) decimated to 4000 faces whole and in 4 blocks: both closed,
    within the budget, and as close to the true surface (the SDF at the vertices)."""
    from neuras_distill.geometry.cleanup import clean_mesh, decimate, decimate_in_blocks, is_watertight

    spec = grid_spec(BOX, 160)
    grid = sample_grid(_two_spheres_and_a_cut, BOX, 160, outside=field_outside_value("sdf", BOX))
    mesh = clean_mesh(marching_cubes_grid(grid, spec.origin, spec.spacing, "sdf", 0.0))
    whole = decimate(mesh, 4000)
    blocks = decimate_in_blocks(mesh, 4000, min_faces=0, block_faces=mesh.num_faces // 4 + 1)
    assert blocks.stats["decimate_blocks"] == 4 and blocks.stats["decimate_faces_in"] == mesh.num_faces
    assert 6000 < blocks.stats["decimate_faces_joined"] <= 8100        # each block to twice its share first
    for m in (whole, blocks):
        assert 3000 < m.num_faces <= 4000 and is_watertight(m.faces)
    voxel = float(spec.spacing.max())

    def surface_error(m):         # |SDF| at the vertices away from the box's cut (its caps are not on the SDF's zero)
        v = torch.as_tensor(m.vertices)
        away = ((v > BOX[0] + 2 * voxel) & (v < BOX[1] - 2 * voxel)).all(dim=1)
        return float(_two_spheres_and_a_cut(v[away]).abs().max())

    error = {"whole": surface_error(whole), "blocks": surface_error(blocks)}
    assert error["blocks"] < 0.5 * voxel and error["blocks"] < 2.0 * error["whole"] + 0.05 * voxel, error
    small = decimate_in_blocks(mesh, 4000)          # under the size threshold: the plain decimation, no blocks
    assert "decimate_blocks" not in small.stats and small.num_faces == whole.num_faces
