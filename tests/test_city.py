"""The embedded city (scenes/city.py): extent, geometry by domain repetition, cameras, appearance."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import torch

from neuras_distill.errors import BadInputError
from neuras_distill.scenes.city import BLOCK, LOTS, CityField, make_city
from neuras_distill.scenes.synthetic import make_scene


@pytest.fixture(scope="module")
def city():
    return make_city()


def test_the_city_is_a_kilometre_across_and_the_small_one_half(city):
    extent = (city.aabb[1] - city.aabb[0]).tolist()
    assert extent[0] >= 1000.0 and extent[2] > 60.0, extent
    small = make_scene("city-small")
    assert abs(float(small.aabb[1, 0] - small.aabb[0, 0]) - 0.5 * extent[0]) < 1e-3
    assert city.kind == "sdf" and city.unbounded and city.preset == "city"
    with pytest.raises(BadInputError, match="even number of blocks"):
        CityField(blocks=3)


def test_signs_at_known_places(city):
    """Road surface, the air above the avenue, inside a building, inside a parked car, a park tree."""
    pts = torch.tensor([[5.0, -2.5, 0.5],        # air over the camera's lane
                        [5.0, -2.5, -0.3],       # under the road
                        [50.0, -40.0, 5.0],      # deep inside a building of block 0 (right side)
                        [150.0, 40.0, 1.0],      # the park: no building
                        [50.0, 0.0, 30.0]])      # high over the avenue
    d = city.geometry(pts)
    assert d[0] > 0.3 and d[1] < 0 and d[2] < -5 and d[3] > 0 and d[4] > 10, d
    assert abs(float(city.geometry(torch.tensor([[5.0, -2.5, 0.0]]))[0])) < 1e-4   # the road's top is z = 0


def test_buildings_by_domain_repetition_match_every_building_near_a_facade(city):
    """The lots of a point's own block give the min over every block (brute force over this one and the two
    beside it): an upper bound everywhere, exact within 7 m of a building (half a side street)."""
    from neuras_distill.scenes.city import BACK_Y, BUILDING_BOTTOM, BUILDING_ROUNDING, _rbox
    g = torch.Generator().manual_seed(0)
    n = 6000
    p = torch.stack([torch.rand(n, generator=g) * BLOCK * 3 - BLOCK, -(torch.rand(n, generator=g) * 50 + 12),
                     torch.rand(n, generator=g) * 70 - 1], dim=1)
    px, py, pz = p.T.contiguous().unbind(0)
    d, _ = city._buildings_city(px, py, pz)
    side = torch.where(py >= 0, 1.0, -1.0)
    best = torch.full_like(px, 1e4)
    for dk in (-1.0, 0.0, 1.0):
        k = city._block_of(px) + dk
        for lot in range(LOTS):
            x0, x1, yf, h = city._lot_box(k, torch.full_like(px, float(lot)), side)
            di = _rbox((px - 0.5 * (x0 + x1)).abs(), (py.abs() - 0.5 * (yf + BACK_Y)).abs(),
                       (pz - 0.5 * (h + BUILDING_BOTTOM)).abs(), 0.5 * (x1 - x0), 0.5 * (BACK_Y - yf),
                       0.5 * (h - BUILDING_BOTTOM), BUILDING_ROUNDING)
            best = torch.minimum(best, torch.where(h > 0, di, torch.full_like(di, 1e4)))
    assert bool((d >= best - 1e-4).all())
    near = d < 7.0
    assert int(near.sum()) > 500
    assert float((d[near] - best[near]).abs().max()) < 1e-4


def test_cameras_are_in_free_space_and_see_the_city(city):
    cams = city.default_cameras(24, 160, 90)
    centres = torch.stack([cams.c2w[i][:3, 3] for i in range(len(cams))])
    span = float(centres[:, 0].max() - centres[:, 0].min())
    assert span > 1000.0, span
    assert float(city.geometry(centres).min()) > 1.0
    for shift in city.lane_shifts:
        shifted = city.lane_shift_cameras(24, shift, 160, 90)
        c = torch.stack([shifted.c2w[i][:3, 3] for i in range(len(shifted))])
        assert float(city.geometry(c).min()) > 0.5, shift        # never inside a parked car


def test_radiance_colours_and_pickling(city):
    """Colours in [0, 1] that differ between materials; the field survives pickling (--nproc sends it)."""
    pts = torch.tensor([[5.0, -2.5, 0.02], [5.0, -14.0 - 1e-3, 8.0], [150.0, 40.0, 0.16]])
    surf = pts.clone()
    x0, x1, yf, _ = city._lot_box(torch.tensor([0.0]), torch.tensor([0.0]), torch.tensor([-1.0]))
    surf[1, 1] = -float(yf[0]) + 0.01                               # just in front of the first facade
    d = torch.tensor([[1.0, 0.0, -0.3], [0.0, -1.0, 0.0], [0.0, 1.0, -0.5]])
    d = d / d.norm(dim=1, keepdim=True)
    rgb = city.radiance(surf, d)
    assert torch.isfinite(rgb).all() and rgb.min() >= 0 and rgb.max() <= 1
    assert float((rgb[0] - rgb[2]).abs().max()) > 0.05              # asphalt is not grass
    assert rgb[2, 1] > rgb[2, 0] and rgb[2, 1] > rgb[2, 2]           # the park's grass is green
    again = pickle.loads(pickle.dumps(city))
    assert torch.equal(again.geometry(pts), city.geometry(pts))
    bg = city.background(torch.tensor([[1.0, 0.0, 0.3]]))
    assert np.all(np.isfinite(bg.numpy()))
