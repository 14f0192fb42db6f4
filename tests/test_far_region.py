"""The far region of unbounded fields: sampling, seamless compositing across the foreground box, validation."""

from __future__ import annotations

import math

import pytest
import torch

from neuras_distill.errors import BadInputError
from neuras_distill.render.far_region import FarRegion
from neuras_distill.render.rays import ray_aabb
from neuras_distill.render.volume import VolumeRenderer


class Medium:
    """A uniform medium of density ``sigma`` everywhere (colour red), or only on a spherical shell of radius
    ``shell`` (thickness 4, colour green) when given; foreground box [-1, 1]^3."""

    kind = "density"
    unbounded = True
    background_color = torch.tensor([0.0, 0.0, 1.0])

    def __init__(self, sigma: float, region: FarRegion, shell: float | None = None):
        self.aabb = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
        self.sigma, self.far_region, self.shell = sigma, region, shell

    def geometry(self, x):
        if self.shell is None:
            return torch.full((x.shape[0],), self.sigma)
        r = x.double().norm(dim=-1)
        return torch.where((r - self.shell).abs() < 2.0, self.sigma, 0.0).float()

    def radiance(self, x, d):
        colour = [1.0, 0.0, 0.0] if self.shell is None else [0.0, 1.0, 0.0]
        return torch.tensor(colour).expand(x.shape[0], 3)


def _rays(origins, targets):
    o = torch.tensor(origins, dtype=torch.float32)
    d = torch.nn.functional.normalize(torch.tensor(targets, dtype=torch.float32) - o, dim=-1)
    return o, d


def test_spacing_is_linear_then_disparity_and_inverts():
    region = FarRegion(near=0.05, far=1000.0, pivot=2.0)
    t = torch.tensor([0.0, 1.0, 2.0, 4.0, 1000.0], dtype=torch.float64)
    s = region.spacing(t)
    assert torch.allclose(s, torch.tensor([0.0, 0.5, 1.0, 1.5, 2.0 - 2.0 / 1000.0], dtype=torch.float64))
    back = region.inverse(region.spacing(torch.linspace(0.05, 1000.0, 101, dtype=torch.float64)))
    assert torch.allclose(back, torch.linspace(0.05, 1000.0, 101, dtype=torch.float64), rtol=1e-9)


@pytest.mark.parametrize("origin", [[-5.0, 0.3, 0.2], [0.2, 0.1, -0.3]])
def test_a_uniform_medium_composites_seamlessly_across_the_box(origin):
    """Front, box and back intervals together give the analytic opacity of the whole ray [near, far], whether the
    camera is outside the box or inside it; the box's own share is its opacity output."""
    near, far, sigma = 0.1, 12.0, 0.3
    field = Medium(sigma, FarRegion(near=near, far=far, pivot=1.0))
    o, d = _rays([origin, origin], [[0.0, 0.0, 0.0], [origin[0], origin[1] + 10.0, origin[2]]])
    out = VolumeRenderer(field, num_steps=256, far_steps=512, occupancy=None, early_stop=0.0).render_rays(o, d)
    whole = 1.0 - math.exp(-sigma * (far - near))
    expected = torch.tensor([[whole, 0.0, 1.0 - whole]] * 2)
    assert torch.allclose(out["rgb"], expected, atol=2e-4), out["rgb"]
    # the box's share: in front of it transmittance exp(-sigma (t_in - near)), across it 1 - exp(-sigma L)
    t_in, t_out, _ = ray_aabb(o[:1], d[:1], field.aabb, near=near)
    t_in, t_out = float(t_in), float(t_out)
    box = math.exp(-sigma * (t_in - near)) * (1.0 - math.exp(-sigma * (t_out - t_in)))
    assert out["opacity"][0].item() == pytest.approx(box, abs=2e-4)


def test_a_distant_shell_is_drawn_and_without_far_steps_the_background_is():
    field = Medium(50.0, FarRegion(near=0.05, far=1000.0, pivot=1.0), shell=20.0)
    o, d = _rays([[0.0, 0.0, 0.0]], [[1.0, 0.3, 0.2]])
    with_far = VolumeRenderer(field, num_steps=64, far_steps=512, occupancy=None).render_rays(o, d)
    assert torch.allclose(with_far["rgb"], torch.tensor([[0.0, 1.0, 0.0]]), atol=1e-3), with_far["rgb"]
    assert with_far["opacity"].item() == 0.0               # the box is empty: nothing in the foreground
    box_only = VolumeRenderer(field, num_steps=64, far_steps=0, occupancy=None).render_rays(o, d)
    assert torch.allclose(box_only["rgb"], torch.tensor([[0.0, 0.0, 1.0]]), atol=1e-6)


def test_a_far_plane_float32_cannot_resolve_is_refused():
    with pytest.raises(BadInputError, match="far plane"):
        FarRegion(near=0.05, far=1e9, pivot=1.0)
    with pytest.raises(BadInputError, match="near < far"):
        FarRegion(near=5.0, far=1.0, pivot=1.0)
    with pytest.raises(BadInputError, match="finite"):
        FarRegion(near=0.0, far=float("nan"), pivot=1.0)


def test_nan_and_inf_densities_in_the_far_region_are_empty_and_opaque():
    """As inside the box (render/compositing.py): a NaN sample is empty, an Inf one opaque."""
    for value, colour in ((float("nan"), [0.0, 0.0, 1.0]), (float("inf"), [1.0, 0.0, 0.0])):
        field = Medium(value, FarRegion(near=0.05, far=100.0, pivot=1.0))
        field.aabb = torch.tensor([[10.0, 10.0, 10.0], [11.0, 11.0, 11.0]])    # the rays miss the box
        o, d = _rays([[0.0, 0.0, 0.0]], [[-1.0, 0.2, 0.1]])
        out = VolumeRenderer(field, num_steps=16, far_steps=64, occupancy=None).render_rays(o, d)
        assert torch.allclose(out["rgb"], torch.tensor([colour]), atol=1e-6), (value, out["rgb"])


def test_opaque_depths_find_where_the_whole_ray_reaches_half_opacity():
    """A uniform medium reaches 0.5 at near + ln 2 / sigma (to one sample's length); a distant shell (radius 18 to
    22, sigma 50) at its inner surface; an empty ray never does (inf)."""
    from neuras_distill.render.far_region import opaque_depths

    region = FarRegion(near=0.1, far=1000.0, pivot=1.0)
    o, d = _rays([[0.0, 0.0, 0.0]], [[1.0, 0.3, 0.2]])
    t = opaque_depths(Medium(0.3, region), region, o, d, steps=512)
    assert float(t[0]) == pytest.approx(0.1 + math.log(2.0) / 0.3, abs=0.05)
    t = opaque_depths(Medium(50.0, region, shell=20.0), region, o.repeat(3, 1), d.repeat(3, 1), steps=512)
    assert torch.allclose(t, torch.full((3,), 18.0, dtype=torch.float64), atol=0.6), t
    assert torch.isinf(opaque_depths(Medium(0.0, region), region, o, d, steps=64)).all()
