"""SDF -> opacity against 50-digit references: NeuS's discrete α (render.compositing.alpha_from_sdf) and
VolSDF's Laplace density (fields.wrappers.laplace_density), for sharpness 1 … 1e6 and SDF values deep inside,
far outside (±1e3) and near the surface.

Bounds (float32 inputs; the reference is evaluated at exactly those float32 values):

* relative error ≤ 2e-6 (+ 1e-30 absolute, for results in float32's subnormal range) — met by the log-space
  forms ``α = −expm1(−s·max(f_prev − f_next, 0))·σ(−s·f_next)`` and
  ``σ_L = (1/β)·(f > 0 ? ½e^{−|f|/β} : 1 − ½e^{−|f|/β})``;
* the package's implementations use exactly these forms; the weaker absolute bounds below are kept as a
  second, looser check.
"""

from __future__ import annotations

import math

import mpmath
import numpy as np
import pytest
import torch

from neuras_distill.fields.wrappers import laplace_density
from neuras_distill.render.compositing import alpha_from_sdf

mpmath.mp.dps = 50

EPS32 = float(np.finfo(np.float32).eps)
REL = 2e-6
TINY = 1e-30
SHARPNESS = [1.0, 10.0, 64.0, 1e3, 1e4, 1e6]
CENTRES = [-1e3, -10.0, -0.5, -1e-3, 0.0, 1e-3, 0.01, 0.5, 10.0, 1e3]
STEPS = [1e-4, 1e-2, 0.5, -1e-2]  # f_prev - f_next; negative: the SDF increases along the ray (α = 0)


def _cases():
    """(f_prev, f_next, s) as float32-exact Python floats."""
    out = []
    for s in SHARPNESS:
        for c in CENTRES:
            for step in STEPS:
                fp, fn = np.float32(c + step / 2), np.float32(c - step / 2)
                out.append((float(fp), float(fn), float(np.float32(s))))
    return out


CASES = _cases()


def _exact_alpha(fp: float, fn: float, s: float):
    sig = lambda z: 1 / (1 + mpmath.exp(-z))  # noqa: E731
    a = 1 - sig(mpmath.mpf(s) * mpmath.mpf(fn)) / sig(mpmath.mpf(s) * mpmath.mpf(fp))
    return float(max(a, mpmath.mpf(0)))


def _exact_laplace(f: float, beta: float):
    f, b = mpmath.mpf(f), mpmath.mpf(beta)
    return float((mpmath.mpf(0.5) * mpmath.exp(-f / b) if f > 0 else 1 - mpmath.mpf(0.5) * mpmath.exp(f / b)) / b)


def _alpha_errors(fn_alpha):
    fp = torch.tensor([c[0] for c in CASES])
    fn = torch.tensor([c[1] for c in CASES])
    got = []
    for s in SHARPNESS:  # one call per sharpness, as the renderer does
        sel = [i for i, c in enumerate(CASES) if c[2] == float(np.float32(s))]
        got.append((sel, fn_alpha(fp[sel], fn[sel], float(np.float32(s)))))
    values = torch.empty(len(CASES), dtype=torch.float64)
    for sel, v in got:
        values[sel] = v.double()
    ref = torch.tensor([_exact_alpha(*c) for c in CASES], dtype=torch.float64)
    return values, ref


def _worst(values, ref, bound):
    excess = (values - ref).abs() - bound
    i = int(torch.argmax(excess))
    fp, fn, s = CASES[i]
    return float(excess[i]), f"f_prev={fp:g} f_next={fn:g} s={s:g}: got {float(values[i]):.8g}, exact {float(ref[i]):.8g}"


def test_alpha_reference_cases_are_meaningful():
    _, ref = _alpha_errors(alpha_from_sdf)
    assert float(ref.max()) == pytest.approx(1.0, abs=1e-6)       # opaque steps exist
    assert 0 < float(ref[ref > 0].min()) < 1e-20                 # and vanishing ones
    assert int((ref == 0).sum()) >= len(SHARPNESS) * len(CENTRES)  # increasing SDF -> 0


def test_alpha_from_sdf_meets_absolute_bound():
    """The looser bound a log-sigmoid difference would meet: |Δα| ≤ 8 ε (1 + s·max(|f_prev|, |f_next|))."""
    values, ref = _alpha_errors(alpha_from_sdf)
    scale = torch.tensor([1.0 + c[2] * max(abs(c[0]), abs(c[1])) for c in CASES], dtype=torch.float64)
    excess, where = _worst(values, ref, REL * ref + 8 * EPS32 * scale + TINY)
    assert excess <= 0, where
    assert bool(((values >= 0) & (values <= 1)).all())


def test_alpha_from_sdf_meets_relative_bound():
    values, ref = _alpha_errors(alpha_from_sdf)
    excess, where = _worst(values, ref, REL * ref + TINY)
    assert excess <= 0, where


def test_alpha_from_sdf_sign_and_limits():
    s = 1e3
    inside = alpha_from_sdf(torch.tensor([-0.5]), torch.tensor([-0.502]), s)
    assert float(inside) == pytest.approx(1 - math.exp(-2.0), rel=1e-4)   # camera inside: not opaque at once
    crossing = alpha_from_sdf(torch.tensor([0.001]), torch.tensor([-0.001]), s)
    assert float(crossing) == pytest.approx(0.6321205588, rel=1e-5)
    assert float(alpha_from_sdf(torch.tensor([0.01]), torch.tensor([0.012]), s)) == 0.0  # moving away
    far = alpha_from_sdf(torch.tensor([1e3]), torch.tensor([1e3 - 1.0]), 1e6)
    assert float(far) == 0.0 and not torch.isnan(far).any()


# ---------------------------------------------------------------------------------------------- Laplace
BETAS = [1e-6, 1e-4, 3e-3, 0.1, 1.0]
SDFS = [-1e3, -1.0, -1e-2, -1e-4, 0.0, 1e-6, 1e-4, 1e-2, 0.05, 1.0, 1e3]


def _laplace_errors(fn):
    out = []
    for beta in BETAS:
        b = float(np.float32(beta))
        f = torch.tensor(SDFS, dtype=torch.float32)
        got = fn(f, b).double()
        ref = torch.tensor([_exact_laplace(float(v), b) for v in f], dtype=torch.float64)
        out.append((b, got, ref))
    return out


def test_laplace_density_meets_absolute_bound():
    """σ within 2e-6 relative or 1e-7/β absolute (the density's scale is 1/β), finite and non-negative."""
    for b, got, ref in _laplace_errors(laplace_density):
        bad = (got - ref).abs() > REL * ref + 1e-7 / b
        assert not bool(bad.any()), (b, got[bad], ref[bad])
        assert bool(torch.isfinite(got).all()) and bool((got >= 0).all())
        assert float(got[SDFS.index(0.0)]) == pytest.approx(0.5 / b, rel=1e-6)


def test_laplace_density_meets_relative_bound():
    for b, got, ref in _laplace_errors(laplace_density):
        bad = (got - ref).abs() > REL * ref + TINY
        assert not bool(bad.any()), (b, got[bad], ref[bad])
