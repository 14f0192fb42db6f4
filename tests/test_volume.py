"""Tests for neuras_distill.render: stable compositing (A1, A2), ray-box (A6), occupancy, VolumeRenderer."""

from __future__ import annotations

import math

import mpmath
import numpy as np
import pytest
import torch

from neuras_distill.render.cameras import Cameras, look_at
from neuras_distill.render.compositing import (alpha_from_density, alpha_from_sdf, sdf_weight_centre,
                                               transmittance_from_alpha, transmittance_from_density,
                                               weights_from_density)
from neuras_distill.render.occupancy import OccupancyGrid
from neuras_distill.render.rays import ray_aabb
from neuras_distill.render.volume import VolumeRenderer
from neuras_distill.scenes.analytic import SphereSDF


# ---------------------------------------------------------------------------------------------- A1
@pytest.mark.parametrize("tau", [1e-10, 1e-8, 1e-6])
def test_alpha_tiny_tau(tau):
    a = alpha_from_density(torch.tensor([tau]), torch.tensor([1.0]))
    assert a.item() == pytest.approx(tau, rel=1e-6)


def test_transmittance_many_tiny_steps():
    n = 100_000
    t = transmittance_from_density(torch.full((n + 1,), 1e-8), torch.ones(n + 1))
    assert abs(t[-1].item() - math.exp(-1e-3)) < 1e-7


@pytest.mark.parametrize("delta", [1e-6, 1e-2, 10.0])
def test_step_function_density(delta):
    n = 64
    t = torch.arange(n) * delta
    sigma = torch.where(torch.arange(n) >= 20, 1e12, 0.0).requires_grad_(True)
    w, _ = weights_from_density(sigma, torch.full((n,), delta))
    assert torch.isfinite(w).all()
    assert 1 - 1e-6 <= w.sum().item() <= 1 + 1e-6
    depth = (w * t).sum().item()
    assert abs(depth - 20 * delta) <= delta
    (w * torch.linspace(0, 1, n)).sum().backward()
    assert torch.isfinite(sigma.grad).all()


def test_zero_length_interval_no_nan():
    sigma = torch.tensor([0.0, float("inf"), 1e38, 5.0], requires_grad=True)
    deltas = torch.tensor([0.1, 0.0, 0.0, 0.1])
    w, tr = weights_from_density(sigma, deltas)
    assert torch.isfinite(w).all() and torch.isfinite(tr).all()
    w.sum().backward()
    assert torch.isfinite(sigma.grad).all()


def test_transmittance_from_alpha_cumprod_exact_zero():
    alpha = torch.tensor([0.5, 1.0, 0.3], requires_grad=True)
    tr = transmittance_from_alpha(alpha)
    assert torch.allclose(tr, torch.tensor([1.0, 0.5, 0.0]))
    (tr * alpha).sum().backward()
    assert torch.isfinite(alpha.grad).all()


# ---------------------------------------------------------------------------------------------- A2
def _exact_neus(s, f_prev, f_next):
    mpmath.mp.dps = 50
    sig = lambda z: 1 / (1 + mpmath.exp(-z))  # noqa: E731
    return float(max(1 - sig(mpmath.mpf(s) * mpmath.mpf(f_next)) / sig(mpmath.mpf(s) * mpmath.mpf(f_prev)), 0))


@pytest.mark.parametrize("s", [1.0, 64.0, 1e3, 1e4, 1e6])
def test_alpha_from_sdf_matches_exact(s):
    cases = [(-0.5, -0.502), (0.010, 0.008), (0.001, -0.001), (0.0001, -0.0001), (-0.002, 0.002), (2.0, 1.998)]
    fp = torch.tensor([c[0] for c in cases], dtype=torch.float32)
    fn = torch.tensor([c[1] for c in cases], dtype=torch.float32)
    got = alpha_from_sdf(fp, fn, s)
    for i in range(len(cases)):
        exact = _exact_neus(s, float(fp[i]), float(fn[i]))  # exact for the fp32-rounded inputs
        assert abs(got[i].item() - exact) <= 2e-6 + 1e-5 * exact, (s, cases[i], got[i].item(), exact)


def test_alpha_from_sdf_gradients_finite_and_signs():
    fp = torch.tensor([-0.5, 0.01, 0.001], requires_grad=True)
    fn = torch.tensor([-0.502, 0.008, -0.001], requires_grad=True)
    a = alpha_from_sdf(fp, fn, 1e3)
    a.sum().backward()
    assert torch.isfinite(fp.grad).all() and torch.isfinite(fn.grad).all()
    # correct sign: a ray through a sphere is opaque at the entry side
    sphere = SphereSDF(radius=0.5)
    r = VolumeRenderer(sphere, 256, occupancy=None)
    out = r.render_rays(torch.tensor([[0.0, 0.0, -2.0]]), torch.tensor([[0.0, 0.0, 1.0]]))
    assert out["opacity"].item() == pytest.approx(1.0, abs=1e-3)
    assert out["depth"].item() == pytest.approx(1.5, abs=r.step)


def _exact_weight_centre(s, f_prev, f_next):
    """The mean position (fraction of the interval) of -d/dt sigmoid(s f(t)) with f linear from f_prev to
    f_next, by 50-digit quadrature."""
    mpmath.mp.dps = 50
    f = lambda u: mpmath.mpf(f_prev) + (mpmath.mpf(f_next) - mpmath.mpf(f_prev)) * u  # noqa: E731
    pdf = lambda u: mpmath.exp(-abs(s * f(u))) / (1 + mpmath.exp(-abs(s * f(u)))) ** 2  # noqa: E731  (logistic)
    return float(mpmath.quad(lambda u: u * pdf(u), [0, 1]) / mpmath.quad(pdf, [0, 1]))


@pytest.mark.parametrize("s", [64.0, 1e3, 1e4])
def test_sdf_weight_centre_is_where_the_interval_holds_its_opacity(s):
    """Colour is sampled where an interval's opacity lies: at the mean of its weight within the interval."""
    cases = [(0.001, -0.005), (0.004, -0.002), (0.02, 0.014), (-0.01, -0.02), (0.003, -0.003), (0.04, 0.03)]
    fp = torch.tensor([c[0] for c in cases])
    fn = torch.tensor([c[1] for c in cases])
    got = sdf_weight_centre(fp, fn, s)
    for i in range(len(cases)):
        exact = _exact_weight_centre(s, float(fp[i]), float(fn[i]))
        assert got[i].item() == pytest.approx(exact, abs=1e-4), (s, cases[i])
    # a surface crossed at a sixth of a sharp interval has its colour near there, not at the midpoint
    assert sdf_weight_centre(torch.tensor([0.001]), torch.tensor([-0.005]), 1e4).item() == pytest.approx(1 / 6,
                                                                                                          abs=0.02)
    # no opacity to place (rising, flat, NaN, or so far outside that its mass is below float64): the midpoint
    rest = sdf_weight_centre(torch.tensor([-0.01, 0.2, float("nan"), 5.0]), torch.tensor([0.01, 0.2, 0.0, 4.9]), 1e3)
    assert rest.tolist() == [0.5, 0.5, 0.5, 0.5]


class _LayeredPlane:
    """An SDF plane z = 0.0137 (normal +z) whose colour changes with depth: red above z = 0.0137 - 0.004,
    blue below; a march that samples colour away from the surface sees blue."""

    kind = "sdf"
    inv_s = 1e4
    aabb = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])

    def geometry(self, x):
        return 0.0137 - x[:, 2]

    def radiance(self, x, d):
        red = (x[:, 2] < 0.0137 + 0.004).float()[:, None]
        return red * torch.tensor([1.0, 0.0, 0.0]) + (1 - red) * torch.tensor([0.0, 0.0, 1.0])


@pytest.mark.parametrize("steps", [16, 24, 37])
def test_sdf_colour_is_taken_where_a_coarse_march_crosses_the_surface(steps):
    """At any step count the rays' colour is the surface's (red), wherever the crossing falls in its interval:
    the interval midpoint could lie up to half a step (here up to 0.11) beyond the thin red skin."""
    rays = torch.linspace(-0.3, 0.3, 41)
    o = torch.stack([rays, torch.zeros_like(rays), torch.full_like(rays, -0.9)], dim=-1)
    d = torch.nn.functional.normalize(torch.stack([0.1 * rays, torch.zeros_like(rays), torch.ones_like(rays)], -1),
                                      dim=-1)
    out = VolumeRenderer(_LayeredPlane(), steps, occupancy=None).render_rays(o, d)
    assert out["opacity"].min().item() > 0.999
    assert out["rgb"][:, 0].min().item() > 0.95 and out["rgb"][:, 2].max().item() < 0.05


# ---------------------------------------------------------------------------------------------- A6
def test_ray_aabb_cases():
    box = torch.tensor([[-1.0, -1, -1], [1, 1, 1]])
    o = torch.tensor([[-3.0, 0, 0],   # axis aligned, zero y/z components
                      [-3.0, 1, 0],   # origin on the slab plane y = 1, d_y = 0
                      [-3.0, 2, 0],   # parallel, outside the slab
                      [0.0, 0, 0],    # camera inside
                      [3.0, 0, 0],    # pointing away
                      [1.0, 0.5, 0],  # origin on a face, going in
                      [1.0, 1.0, 1.0],  # corner, going out
                      [-3.0, -3, -3]])  # diagonal through the corners
    d = torch.tensor([[1.0, 0, 0], [1, 0, 0], [1, 0, 0], [1, 0, 0], [1, 0, 0], [-1, 0, 0], [1, 1, 1],
                      [1, 1, 1]])
    tn, tf, hit = ray_aabb(o, d, box)
    assert hit.tolist() == [True, True, False, True, False, True, False, True]
    assert torch.isfinite(tn).all() and torch.isfinite(tf).all()
    assert tn[:2].tolist() == [2.0, 2.0] and tf[:2].tolist() == [4.0, 4.0]
    assert (tn[3].item(), tf[3].item()) == (0.0, 1.0)
    assert (tn[5].item(), tf[5].item()) == (0.0, 2.0)
    assert tn[7].item() == pytest.approx(2.0) and tf[7].item() == pytest.approx(4.0)
    tn, tf, hit = ray_aabb(o[3:4], d[3:4], box, near=0.25)
    assert tn.item() == 0.25 and hit.item()


# ---------------------------------------------------------------------------------------------- occupancy
def test_occupancy_grid_sdf_and_density():
    s = SphereSDF(radius=0.5)
    g = OccupancyGrid.from_field(s, 32)
    c = g.cell_centers().reshape(-1, 3)
    dist = (c.norm(dim=-1) - 0.5).abs()
    occ = g.occupied.reshape(-1)
    assert bool(occ[dist < 0.01].all()) and not bool(occ[dist > 0.2].any())
    assert torch.equal(g.query(c).reshape(-1), occ)
    assert not g.query(torch.tensor([[5.0, 0, 0]])).item()
    gd = OccupancyGrid.from_field(s.density(0.01), 32)
    assert bool(gd.occupied.reshape(-1)[c.norm(dim=-1) < 0.45].all())  # inside is occupied for density
    assert not bool(gd.occupied.reshape(-1)[c.norm(dim=-1) > 0.75].any())


# ---------------------------------------------------------------------------------------------- renderer
def _front_camera(size=48, dist=2.5, fov=40.0):
    pose = look_at(torch.tensor([0.0, -dist, 0.0]), torch.zeros(3), torch.tensor([0.0, 0.0, 1.0]))
    f = 0.5 * size / math.tan(math.radians(fov) / 2)
    return Cameras(pose[None].float(), f, f, size / 2, size / 2, size, size)


@pytest.fixture(scope="module")
def sphere_renders():
    s = SphereSDF(radius=0.5, gloss=0.25)
    cams = _front_camera()
    out = {}
    for kind, field in (("sdf", s), ("density", s.density(0.003))):
        for occ in ("auto", None):
            r = VolumeRenderer(field, 256, occupancy=occ, occupancy_resolution=48)
            out[kind, occ] = (r.render(cams, 0), dict(r.stats), r)
    return s, cams, out


def test_sphere_depth_and_opacity(sphere_renders):
    s, cams, out = sphere_renders
    size = cams.width
    for kind in ("sdf", "density"):
        img, _, r = out[kind, "auto"]
        assert img["rgb"].dtype == np.float32 and img["rgb"].shape == (size, size, 3)
        assert 0.0 <= img["rgb"].min() and img["rgb"].max() <= 1.0
        # the centre ray (between the 4 centre pixels) hits at distance 2.0
        o, d = cams.rays(0)
        px = size // 2
        t_exact = float((o[px, px] * d[px, px]).sum().neg() - torch.sqrt(
            (o[px, px] * d[px, px]).sum() ** 2 - (o[px, px].norm() ** 2 - 0.25)))
        assert abs(img["depth"][px, px] - t_exact) <= r.step, kind
        # opacity: 1 well inside the silhouette, 0 well outside (angular radius asin(0.5/2.5) = 11.5 deg)
        v, u = np.mgrid[0:size, 0:size]
        rad = np.hypot(u + 0.5 - size / 2, v + 0.5 - size / 2) / cams.fx[0].item()
        edge = math.tan(math.asin(0.5 / 2.5))
        inside, outside = rad < 0.8 * edge, rad > 1.2 * edge
        assert np.abs(img["opacity"][inside] - 1).max() < 1e-3, kind
        assert np.abs(img["opacity"][outside]).max() < 1e-4, kind
        assert np.abs(img["rgb"][outside] - 1.0).max() < 1e-4  # white background composited
        assert img["depth"][outside].max() == 0.0


def test_density_and_sdf_variants_agree(sphere_renders):
    _, _, out = sphere_renders
    a, b = out["sdf", "auto"][0]["rgb"], out["density", "auto"][0]["rgb"]
    diff = np.abs(a - b)
    assert diff.mean() < 0.02  # silhouette pixels differ most (opacity ramps of different shape)
    assert np.median(diff) < 0.005
    both = (out["sdf", "auto"][0]["opacity"] > 0.999) & (out["density", "auto"][0]["opacity"] > 0.999)
    assert diff[both].mean() < 0.02


def test_occupancy_skipping_is_exact_and_cheaper(sphere_renders):
    _, _, out = sphere_renders
    for kind in ("sdf", "density"):
        (with_occ, st_occ, _), (without, st_all, _) = out[kind, "auto"], out[kind, None]
        for key in ("rgb", "opacity"):
            assert np.abs(with_occ[key] - without[key]).max() < 1e-3, (kind, key)
        assert st_occ["geometry_points"] < 0.5 * st_all["geometry_points"], kind


def test_chunk_size_does_not_change_result(sphere_renders):
    s, cams, out = sphere_renders
    occ = out["sdf", "auto"][2].occupancy
    ref = out["sdf", "auto"][0]
    img = VolumeRenderer(s, 256, chunk=77, occupancy=occ).render(cams, 0)
    for key in ("rgb", "depth", "opacity"):     # rounds grow per chunk: early termination may cut elsewhere
        assert np.abs(img[key] - ref[key]).max() < 2e-4, key
    # the segment length only moves where early termination (T < 1e-4) cuts a ray
    img = VolumeRenderer(s, 256, segment=5, occupancy=occ).render(cams, 0)
    for key in ("rgb", "opacity"):
        assert np.abs(img[key] - ref[key]).max() < 2e-4, key


@pytest.mark.slow
def test_rounds_grow_as_rays_finish(sphere_renders):
    """Most rays stop at the sphere after a few segments; the few that pass beside it march the whole box in
    longer rounds (same samples per round), not in ``segment``-step rounds: the picture is unchanged."""
    s, cams, out = sphere_renders
    occ = out["sdf", "auto"][2].occupancy
    rounds = {}
    images = {}
    for mode in ("fixed", "growing"):
        r = VolumeRenderer(s, 4096, segment=8, occupancy=occ)
        if mode == "fixed":
            r._steps_this_round = lambda started, live, remaining, r=r: r.segment
        calls = []
        march = r._march_segment
        r._march_segment = lambda *a, **k: calls.append(1) or march(*a, **k)
        images[mode], rounds[mode] = r.render(cams, 0), len(calls)
    for key in ("rgb", "opacity"):
        assert np.abs(images["fixed"][key] - images["growing"][key]).max() < 2e-4, key
    assert rounds["growing"] <= rounds["fixed"] / 2, rounds           # 305 -> 120 rounds here
    r = VolumeRenderer(s, 256, segment=32)
    assert [r._steps_this_round(1000, live, 10_000) for live in (1000, 400, 10, 0)] == [32, 64, 512, 512]
    assert r._steps_this_round(1000, 10, 40) == 64 and r._steps_this_round(1000, 1000, 1) == 32   # not past the end


def test_render_rays_background_and_misses():
    s = SphereSDF(radius=0.5)
    s.background = lambda d: (0.5 + 0.5 * d).clamp(0, 1)
    r = VolumeRenderer(s, 64)
    o = torch.tensor([[0.0, -3.0, 0.0], [0.0, -3.0, 5.0]])
    d = torch.tensor([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    out = r.render_rays(o, d)
    assert out["opacity"].tolist()[1] == 0.0
    assert torch.allclose(out["rgb"][1], torch.tensor([0.5, 1.0, 0.5]))
    assert out["opacity"][0].item() == pytest.approx(1.0, abs=1e-3)
