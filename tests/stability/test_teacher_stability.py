"""Teacher (volume rendering) on stiff and extreme densities: a constant-density slab against exp(-σL),
σ from 1e-8 to 1e8 per unit and steps from 1e-6 to more than the box, plus step functions, NaN/Inf samples
and many tiny steps, through the project's own compositing and VolumeRenderer."""

from __future__ import annotations

import math

import pytest
import torch

from neuras_distill.render.compositing import optical_depth, transmittance_from_density, weights_from_density
from neuras_distill.render.volume import VolumeRenderer

S = pytest.mark.stability


class Slab:
    """Constant density σ inside the unit cube [-0.5, 0.5]^3 (aabb a bit larger)."""

    kind = "density"

    def __init__(self, sigma: float, half: float = 0.5):
        self.sigma, self.half = float(sigma), half
        self.aabb = torch.tensor([[-half] * 3, [half] * 3])

    def geometry(self, x):
        return torch.full((x.shape[0],), self.sigma)

    def radiance(self, x, d):
        return torch.full((x.shape[0], 3), 0.5)


def _axis_ray():
    return torch.tensor([[-3.0, 0.1, 0.2]]), torch.tensor([[1.0, 0.0, 0.0]])


@S(case="slab opacity through VolumeRenderer", family="teacher",
   reference="1 - exp(-σL) (mpmath-free closed form, float64), L = 1",
   tolerance="relative 2e-5 on the opacity and 2e-5 on the transmittance")
@pytest.mark.parametrize("sigma", [1e-8, 1e-4, 1.0, 30.0, 1e4, 1e8])
@pytest.mark.parametrize("steps_per_box", [1, 16, 4096, 1_000_000])
def test_slab_opacity(sigma, steps_per_box):
    field = Slab(sigma)
    diag = math.sqrt(3.0)
    num_steps = max(1, round(steps_per_box * diag))   # steps per diagonal -> step = 1 / steps_per_box
    r = VolumeRenderer(field, num_steps=num_steps, occupancy=None, segment=min(65536, num_steps), early_stop=0.0)
    out = r.render_rays(*_axis_ray())
    exact_op = -math.expm1(-sigma * 1.0)
    got = float(out["opacity"][0])
    assert got == pytest.approx(exact_op, rel=2e-5, abs=1e-30)
    assert 1.0 - got == pytest.approx(math.exp(-sigma), rel=2e-5, abs=2e-5)


@S(case="step larger than the box", family="teacher", reference="one step of the whole chord: 1 - exp(-σL)",
   tolerance="relative 1e-6")
@pytest.mark.parametrize("sigma", [1e-3, 1.0, 1e3])
def test_step_above_box(sigma):
    # step = diagonal / num_steps with num_steps = 1 is 1.7x the chord; the chord is one interval
    r = VolumeRenderer(Slab(sigma), num_steps=1, occupancy=None, early_stop=0.0)
    got = float(r.render_rays(*_axis_ray())["opacity"][0])
    assert got == pytest.approx(-math.expm1(-sigma), rel=1e-6)


@S(case="stiff step σ=1e12 behind t*", family="teacher",
   reference="Σw = 1 (opaque), depth = t* + δ/2 (midpoint of the first occupied step)",
   tolerance="Σw within 1e-6 of 1; depth within δ; no NaN")
@pytest.mark.parametrize("delta", [1e-6, 1e-2, 10.0])
def test_step_function_density(delta):
    n = 64
    t = torch.arange(n, dtype=torch.float64) * delta
    t_star = t[n // 2]
    sigma = torch.where(t >= t_star, 1e12, 0.0).float()[None]
    w, _ = weights_from_density(sigma, torch.full((1, n), delta))
    assert not torch.isnan(w).any()
    assert float(w.sum()) == pytest.approx(1.0, abs=1e-6)
    depth = float((w.double() * (t + delta / 2)).sum() / w.double().sum())
    assert abs(depth - float(t_star) - delta / 2) <= delta



@S(case="NaN and Inf density samples", family="teacher",
   reference="NaN -> empty (τ = 0), +Inf -> τ = σδ clamped to 1e10 (opaque), Inf x zero-length interval -> τ = 0",
   tolerance="exact")
def test_nan_inf_zero_length():
    sigma = torch.tensor([[float("nan"), 1.0, float("inf"), float("inf")]])
    delta = torch.tensor([[0.1, 0.1, 0.0, 0.1]])
    tau = optical_depth(sigma, delta)
    assert tau.tolist() == [[0.0, pytest.approx(0.1), 0.0, 1e10]]
    w, trans = weights_from_density(sigma, delta)
    assert torch.isfinite(w).all() and torch.isfinite(trans).all()


@S(case="stiff sample behind a thin layer: weights", family="teacher",
   reference="Σw = 1 - exp(-Στ) <= 1 (telescoping); T before the wall = exp(-0.1)",
   tolerance="Σw within 1e-6 of 1, T within 1e-6")
def test_stiff_sample_keeps_prefix():
    sigma = torch.tensor([[1.0, 1e10]])
    delta = torch.tensor([[0.1, 0.1]])
    w, trans = weights_from_density(sigma, delta)
    assert float(trans[0, 1]) == pytest.approx(math.exp(-0.1), abs=1e-6)
    assert float(w.sum()) == pytest.approx(1.0, abs=1e-6)


@S(case="stiff sample behind a thin layer: proposed exclusive cumsum", family="teacher",
   reference="Σw = 1, T before the wall = exp(-0.1) (the fix proposed for compositing.py, checked here)",
   tolerance="1e-6")
def test_proposed_exclusive_cumsum():
    tau = optical_depth(torch.tensor([[1.0, 1e10]]), torch.tensor([[0.1, 0.1]]))
    excl = torch.cat([torch.zeros_like(tau[..., :1]), torch.cumsum(tau[..., :-1], dim=-1)], dim=-1)
    trans = torch.exp(-excl)
    w = -torch.expm1(-tau) * trans
    assert float(trans[0, 1]) == pytest.approx(math.exp(-0.1), abs=1e-6)
    assert float(w.sum()) == pytest.approx(1.0, abs=1e-6)


class LayerThenWall:
    """σ = 1 (red) for x in [-0.5, 0), σ = 1e12 (green) for x >= 0: a ray along +x sees 0.5 units of fog, then a wall."""

    kind = "density"
    aabb = torch.tensor([[-0.5] * 3, [0.5] * 3])

    def geometry(self, x):
        return torch.where(x[:, 0] < 0, 1.0, 1e12)

    def radiance(self, x, d):
        red = torch.tensor([1.0, 0.0, 0.0]).expand(x.shape[0], 3)
        green = torch.tensor([0.0, 1.0, 0.0]).expand(x.shape[0], 3)
        return torch.where((x[:, 0] < 0)[:, None], red, green)


@S(case="fog then σ=1e12 wall through VolumeRenderer", family="teacher",
   reference="rgb = (1 - e^-0.5, e^-0.5, 0) = (0.3935, 0.6065, 0)", tolerance="absolute 0.01 per channel")
def test_fog_then_wall_colour():
    r = VolumeRenderer(LayerThenWall(), num_steps=256, occupancy=None)
    rgb = r.render_rays(torch.tensor([[-3.0, 0.01, 0.02]]), torch.tensor([[1.0, 0.0, 0.0]]))["rgb"][0]
    assert rgb.tolist() == pytest.approx([1 - math.exp(-0.5), math.exp(-0.5), 0.0], abs=0.01)


@S(case="100000 tiny steps τ=1e-8", family="teacher", reference="T_end = exp(-1e-3) (float64)",
   tolerance="absolute 1e-7 (fails with cumprod(1 - α), which gives 1.0)")
def test_many_tiny_steps():
    n = 100_000
    trans = transmittance_from_density(torch.full((1, n + 1), 1e-8), torch.ones(1, n + 1))
    assert float(trans[0, -1]) == pytest.approx(math.exp(-1e-3), abs=1e-7)


@S(case="huge and tiny steps", family="teacher",
   reference="α = -expm1(-σδ): δ=1e-7, σ=1e-3 -> 1e-10; δ=1e4, σ=1e-2 -> 1 - e^-100",
   tolerance="relative 1e-6")
def test_huge_and_tiny_steps():
    from neuras_distill.render.compositing import alpha_from_density
    a = alpha_from_density(torch.tensor([1e-3, 1e-2]), torch.tensor([1e-7, 1e4]))
    assert float(a[0]) == pytest.approx(1e-10, rel=1e-6)
    assert float(a[1]) == pytest.approx(1.0, rel=1e-6)


@S(case="σ·δ clamped, not σ: tiny steps through huge densities", family="teacher",
   reference="α = -expm1(-σδ) in float64: δ = 1e-10 with σ = 1e12 -> 1 - e^-100 = 1, σ = 1e30 -> 1, σ = inf -> 1 "
             "(clamping σ to 1e10 before the product gave 1 - e^-1 = 0.632)",
   tolerance="absolute 1e-6; σ = inf with δ = 0 stays τ = 0")
@pytest.mark.parametrize("sigma", [1e12, 1e30, float("inf")])
def test_tau_clamped_not_sigma(sigma):
    from neuras_distill.render.compositing import alpha_from_density
    delta = torch.tensor([1e-10, 0.0])
    a = alpha_from_density(torch.tensor([sigma, sigma]), delta)
    exact = 1.0 if math.isinf(sigma) else -math.expm1(-min(sigma * 1e-10, 700.0))
    assert float(a[0]) == pytest.approx(exact, abs=1e-6)
    assert float(a[1]) == 0.0
    w, trans = weights_from_density(torch.tensor([[sigma]]), torch.tensor([[1e-10]]))
    assert float(w.sum()) == pytest.approx(exact, abs=1e-6) and torch.isfinite(trans).all()


@S(case="transmittance over 1e5-1e6 samples of tiny α", family="teacher",
   reference="T_end = (1 - α)^n in float64: α = 1e-7, n = 1e6 -> 0.904837 (exp(-0.1)); α = 1e-5, n = 2e5 -> "
             "0.135335 (float32 products of 1 - α gave 0.8876, 1.9% off, and 0.27% off)",
   tolerance="relative 1e-5 on T_end (compositing.transmittance_from_alpha and weights_from_alpha)")
@pytest.mark.parametrize("alpha,n", [(1e-7, 1_000_000), (1e-5, 200_000)])
def test_transmittance_drift(alpha, n):
    from neuras_distill.render.compositing import transmittance_from_alpha, weights_from_alpha
    a = torch.full((1, n + 1), alpha)
    exact = math.exp((n) * math.log1p(-float(a[0, 0])))       # the float32 α, exactly, n times
    assert float(transmittance_from_alpha(a)[0, -1]) == pytest.approx(exact, rel=1e-5)
    w, _ = weights_from_alpha(a[:, :-1])
    assert 1.0 - float(w.double().sum()) == pytest.approx(exact, rel=1e-5)


class _BallWithRegion:
    """A density ball (σ = 30, r = 0.5) whose field is ``value`` (NaN, Inf, or None: the ball as it is) in the
    box [0.25, 0.5]^3 that overlaps its edge."""

    kind = "density"
    aabb = torch.tensor([[-0.5] * 3, [0.5] * 3])
    region = torch.tensor([[0.25] * 3, [0.5] * 3])

    def __init__(self, value):
        self.value = value

    def geometry(self, x):
        g = torch.where(x.float().norm(dim=-1) < 0.5, 30.0, 0.0)
        if self.value is None:
            return g
        inside = ((x >= self.region[0]) & (x <= self.region[1])).all(-1)
        return torch.where(inside, self.value, g)

    def radiance(self, x, d):
        return (0.2 + 0.6 * (x.float() + 0.5)).clamp(0.0, 1.0)


@S(case="NaN / Inf density region leaves the other rays alone", family="teacher",
   reference="the same field without the region (VolumeRenderer, 1024 steps, 8 orbit views 48x48): every ray that "
             "misses the region's box (slab test) renders bit-identically (the rays through the region ended "
             "earlier or later and changed the chunk's round lengths: up to 9.8e-5 before)",
   tolerance="exact (0.0) on rgb, opacity, depth of the rays missing the region")
@pytest.mark.parametrize("value", [float("nan"), float("inf")], ids=["nan", "inf"])
def test_bad_region_isolated(value):
    from neuras_distill.render.rays import ray_aabb
    from neuras_distill.scenes.analytic import orbit_framing
    clean, bad = _BallWithRegion(None), _BallWithRegion(value)
    cams = orbit_framing(clean.aabb, 8, 48, 48)
    r_clean, r_bad = VolumeRenderer(clean, num_steps=1024), VolumeRenderer(bad, num_steps=1024)
    through = 0
    for i in range(len(cams)):
        o, d = (v.reshape(-1, 3) for v in cams.rays(i))
        miss = ~ray_aabb(o, d, _BallWithRegion.region)[2]
        through += int((~miss).sum())
        a, b = r_clean.render_rays(o, d), r_bad.render_rays(o, d)
        for key in ("rgb", "opacity", "depth"):
            assert torch.equal(a[key][miss], b[key][miss]), (i, key, float((a[key][miss] - b[key][miss]).abs().max()))
    assert through > 100         # the region is seen
