"""The core level of a soft density fringe: where the training rays terminate (geometry/colour_level.py)."""

import numpy as np
import pytest
import torch

from neuras_distill.geometry.colour_level import colour_level, termination_points
from neuras_distill.geometry.marching import marching_cubes_field
from neuras_distill.render.cameras import Cameras
from neuras_distill.render.volume import VolumeRenderer

CORE, FRINGE, PEAK = 0.25, 0.02, 200.0


def soft_ball_log_density(resolution=64):
    """log sigma of a ball with a sigmoid fringe on the lattice of [-0.5, 0.5]^3 (origin, spacing, grid)."""
    axis = np.linspace(-0.5, 0.5, resolution)
    x, y, z = np.meshgrid(axis, axis, axis, indexing="ij")
    r = np.sqrt(x * x + y * y + z * z)
    sigma = PEAK / (1.0 + np.exp((r - CORE) / FRINGE))
    return np.full(3, -0.5), np.full(3, axis[1] - axis[0]), np.log(sigma + 1e-6)


def log_sigma_at(r):
    return np.log(PEAK / (1.0 + np.exp((r - CORE) / FRINGE)))


def points_at(radius, tan, count=200, seed=0):
    """Points on the sphere of ``radius`` with rays meeting its normal at angle arctan(tan)."""
    rng = np.random.default_rng(seed)
    normal = rng.normal(size=(count, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    side = np.cross(normal, rng.normal(size=(count, 3)))
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    theta = np.arctan(tan)
    dirs = -np.cos(theta) * normal + np.sin(theta) * side             # travelling inwards
    return radius * normal, dirs


def test_the_level_is_the_log_density_where_oblique_rays_terminate():
    origin, spacing, grid = soft_ball_log_density()
    for radius in (0.26, 0.28):
        found = colour_level(grid, origin, spacing, *points_at(radius, tan=1.0))
        assert abs(found["log_level"] - log_sigma_at(radius)) < 0.15, (radius, found)
        assert abs(found["median_tan"] - 1.0) < 0.1
    # head-on rays weigh ~nothing against oblique ones: a sideways error is dr * tan(theta)
    p1, d1 = points_at(0.24, tan=0.0)
    p2, d2 = points_at(0.28, tan=2.0, seed=1)
    found = colour_level(grid, origin, spacing, np.concatenate([p1, p2]), np.concatenate([d1, d2]))
    assert abs(found["log_level"] - log_sigma_at(0.28)) < 0.15
    # nothing inside the lattice: no level
    assert colour_level(grid, origin, spacing, np.full((3, 3), 5.0), d1[:3]) is None


class SoftBall:
    kind = "density"
    aabb = torch.tensor([[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]])

    def geometry(self, x):
        return PEAK * torch.sigmoid((CORE - x.norm(dim=-1)) / FRINGE)

    def radiance(self, x, d):
        return torch.full_like(x, 0.5)


@pytest.mark.slow
def test_termination_points_lie_where_the_rays_reach_half_opacity_and_the_core_among_them():
    field = SoftBall()
    cams = Cameras.orbit((0, 0, 0), 1.5, 6, width=40, height=40, fov_deg=35.0, elevation_deg=(-30.0, 40.0))
    teacher = VolumeRenderer(field, num_steps=256)
    outs = [teacher.render(cams, i, crossings=True) for i in range(len(cams))]
    points, dirs = termination_points(cams, np.stack([o["surface_depth"] for o in outs]),
                                      np.stack([o["opacity"] for o in outs]))
    assert len(points) > 1000 and np.allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-6)
    radius = np.linalg.norm(points, axis=1)
    # head-on, opacity 0.5 is reached where 200 w softplus((CORE - r) / w) = ln 2: r = 0.283; grazing rays,
    # longer in the fringe, further out
    assert abs(radius.min() - 0.283) < 0.006 and np.percentile(radius, 95) < 0.31
    spec_origin, spacing = np.full(3, -0.5), np.full(3, 1.0 / 63)
    axis = np.linspace(-0.5, 0.5, 64)
    x, y, z = np.meshgrid(axis, axis, axis, indexing="ij")
    grid = field.geometry(torch.from_numpy(np.stack([x, y, z], -1).reshape(-1, 3)).float()).numpy().reshape(x.shape)
    found = colour_level(np.log(grid + 1e-6), spec_origin, spacing, points, dirs)
    level = np.exp(found["log_level"])
    core = marching_cubes_field(field, 64, level=level)
    r_core = np.linalg.norm(core.vertices, axis=1).mean()
    assert np.percentile(radius, 25) < r_core < np.percentile(radius, 95)    # towards the oblique rays' radius
