"""SDF -> opacity on whole rays: NeuS inv_s up to 1e6 against mpmath along a ray, the sign convention, SDFs
with non-unit gradients, NaN SDF samples. (Single-interval α against mpmath for s 1..1e6 and |f| up to 1e3 is
tests/test_sdf_opacity.py; not repeated here.)"""

from __future__ import annotations


import mpmath
import numpy as np
import pytest
import torch

from neuras_distill.render.compositing import alpha_from_sdf, weights_from_alpha
from neuras_distill.render.volume import VolumeRenderer
from neuras_distill.scenes.analytic import SphereSDF
from neuras_distill.stability.extreme import ScaledSDF
from neuras_distill.stability.probe import probe_field

S = pytest.mark.stability
mpmath.mp.dps = 50


def _ray_through_sphere(n=256):
    """SDF of a radius-0.5 sphere along the z axis from z = -2, t in [0.5, 3.5] (true entry depth 1.5)."""
    t = torch.linspace(0.5, 3.5, n + 1, dtype=torch.float64)
    f = (t - 2.0).abs() - 0.5
    return t, f.float()


@S(case="NeuS ray transmittance vs mpmath", family="sdf",
   reference="T_end = Π Φ(s f_{i+1})/Φ(s f_i) over the ray, 50-digit mpmath",
   tolerance="absolute 1e-6 on the ray opacity")
@pytest.mark.parametrize("inv_s", [1.0, 64.0, 1e3, 1e5, 1e6])
def test_ray_opacity_vs_mpmath(inv_s):
    t, f = _ray_through_sphere()
    alpha = alpha_from_sdf(f[:-1], f[1:], inv_s)
    w, _ = weights_from_alpha(alpha[None])
    got = float(w.sum())
    sig = lambda z: 1 / (1 + mpmath.exp(-z))  # noqa: E731
    trans = mpmath.mpf(1)
    for a, b in zip(f[:-1].tolist(), f[1:].tolist()):
        alpha_ex = max(mpmath.mpf(0), 1 - sig(mpmath.mpf(inv_s) * mpmath.mpf(b)) / sig(mpmath.mpf(inv_s) * mpmath.mpf(a)))
        trans *= 1 - alpha_ex
    assert got == pytest.approx(float(1 - trans), abs=1e-6)


@S(case="sign convention: depth of a sphere", family="sdf",
   reference="depth 1.5 for the correct sign (stability note A2); flipped sign refused by check",
   tolerance="depth within one step (3/256); exact refusal message")
def test_sign_convention():
    t, f = _ray_through_sphere()
    alpha = alpha_from_sdf(f[:-1], f[1:], 64.0)
    w, _ = weights_from_alpha(alpha[None])
    mid = 0.5 * (t[:-1] + t[1:])
    depth = float((w[0].double() * mid).sum() / w.sum())
    assert abs(depth - 1.5) <= 3.0 / 256
    flipped = ScaledSDF(SphereSDF(radius=0.5, inv_s=1000.0), -1.0)
    report = probe_field(flipped)
    assert report.verdict == "refused"
    assert report.reason().startswith("sdf.sign: the SDF is negative outside (8/8 box corners and 8/8 camera centres); "
                                      "it must be negative inside")


@S(case="gradient scale k equals inv_s scale k", family="sdf",
   reference="α(k f, s) = α(f, k s) exactly (NeuS depends on s·Δf)", tolerance="relative 1e-6")
@pytest.mark.parametrize("k", [1e-3, 0.1, 10.0, 1e3])
def test_gradient_scale_equivalence(k):
    t, f = _ray_through_sphere()
    a1 = alpha_from_sdf(k * f[:-1], k * f[1:], 64.0)
    a2 = alpha_from_sdf(f[:-1], f[1:], 64.0 * k)
    assert torch.allclose(a1, a2, rtol=1e-5, atol=1e-7)


@S(case="eikonal probe measures |∇f|", family="sdf", reference="|∇(k·sdf)| = k for a sphere",
   tolerance="relative 2% on the median")
@pytest.mark.parametrize("k", [0.1, 1.0, 10.0])
def test_eikonal_probe(k):
    field = ScaledSDF(SphereSDF(radius=0.5, inv_s=1000.0), k)
    item = probe_field(field, samples=32, rays=64).item("sdf.eikonal")
    assert item.values["grad_p50"] == pytest.approx(k, rel=0.02)


PROPOSED_OCC = ("proposed fix: render/occupancy.py OccupancyGrid.from_field (SDF branch): scale the cell test by the "
                "field's Lipschitz bound L (max |Δf|/Δx between neighbouring cell centres, >= 1): "
                "limit = L * 0.5 * |cell| + margin; today |f(centre)| < 0.5|cell| + margin assumes |∇f| <= 1")


@S(case="SDF with |∇f| = 10: occupancy skipping", family="sdf",
   reference="same opacity with and without the occupancy grid (the grid must only skip empty cells)",
   tolerance="max |Δopacity| <= 1e-3 over a 24x24 view")
def test_steep_sdf_occupancy():
    field = ScaledSDF(SphereSDF(radius=0.5, inv_s=1000.0), 10.0)
    cams = field.inner.default_cameras(2, 24, 24)
    a = VolumeRenderer(field, num_steps=256, occupancy=None).render(cams, 0)["opacity"]
    b = VolumeRenderer(field, num_steps=256).render(cams, 0)["opacity"]
    assert float(np.abs(a - b).max()) <= 1e-3


class NaNCap:
    """Sphere SDF that returns NaN above z = 0.3."""

    kind = "sdf"

    def __init__(self):
        self.s = SphereSDF(radius=0.5, inv_s=1000.0)
        self.aabb, self.inv_s = self.s.aabb, 1000.0

    def geometry(self, x):
        return torch.where(x[:, 2] > 0.3, float("nan"), self.s.geometry(x))

    def radiance(self, x, d):
        return self.s.radiance(x, d)


@S(case="NaN SDF region: teacher", family="sdf",
   reference="no NaN pixel (NaN samples treated as empty, as for densities)", tolerance="exact: 0 NaN")
def test_nan_sdf_teacher():
    field = NaNCap()
    cams = field.s.default_cameras(2, 24, 24)
    out = VolumeRenderer(field, num_steps=128, occupancy=None).render(cams, 0)
    assert not np.isnan(out["rgb"]).any() and not np.isnan(out["opacity"]).any()


@S(case="NaN SDF region (22% of the box): check refuses", family="sdf",
   reference="exact message naming the fraction and the box of the NaN region", tolerance="exact prefix")
def test_nan_sdf_refused_by_check():
    report = probe_field(NaNCap(), samples=32, rays=64)
    item = report.item("finite.geometry")
    assert item.verdict == "refused"
    assert item.explanation.startswith("the SDF is NaN/Inf at ") and "(more than 5%)" in item.explanation
    lo, hi = item.values["bbox"]
    assert lo[2] > 0.3 and hi[2] <= float(field_max_z()) + 1e-6


def field_max_z():
    return SphereSDF(radius=0.5, inv_s=1000.0).aabb[1, 2]


@S(case="NeuS inv_s 1e5 sphere end to end (teacher)", family="sdf",
   reference="opacity 1 inside the silhouette, 0 outside; depth = distance to the sphere",
   tolerance="opacity within 1e-4 away from a 1-pixel silhouette band; depth within one step")
def test_sharp_neus_teacher():
    field = SphereSDF(radius=0.5, inv_s=1e5)
    cams = field.default_cameras(2, 16, 16)
    out = VolumeRenderer(field, num_steps=256).render(cams, 0)
    o, d = cams.rays(0)
    o, d = o.reshape(-1, 3).double(), d.reshape(-1, 3).double()
    b = (o * d).sum(-1)
    disc = b * b - ((o * o).sum(-1) - 0.25)
    hit = disc > 0
    depth = -b - disc.clamp(min=0).sqrt()
    miss_dist = ((o + (-b)[:, None] * d).norm(dim=-1) - 0.5).abs()
    clear = miss_dist.numpy() > 2 * float(cams.width and 1.0 / cams.fx[0]) * float(o[0].norm())
    op = out["opacity"].reshape(-1)
    assert np.abs(op[clear] - hit.numpy()[clear].astype(np.float32)).max() <= 1e-4
    step = float((field.aabb[1] - field.aabb[0]).norm()) / 256
    dd = np.abs(out["depth"].reshape(-1) - depth.numpy())[clear & hit.numpy()]
    assert dd.max() <= step
