"""The space beyond the foreground box of an unbounded field, as its trainer renders it.

This module owns :class:`FarRegion` (what an unbounded field declares: its near and far planes and the distance
at which its sampling turns from linear to disparity) and :func:`march_interval`, which composites a field's
density and colour over per-ray intervals of that space. A field trained with scene contraction (nerfstudio's
nerfacto, mip-NeRF 360) holds content out to its far plane: ground, buildings and sky that a renderer clipped
to the foreground box never draws.

Sampling: the distance t along each (unit) ray from its origin is spaced uniformly in
``s(t) = t / pivot`` for ``t < pivot`` and ``s(t) = 2 - pivot / t`` beyond (linear near the camera, uniform in
disparity far away: nerfstudio's ``UniformLinDispPiecewiseSampler``, which is about uniform in the contracted
space it trains). ``steps`` samples span ``s(near) .. s(far)``; an interval [a, b] gets
``ceil((s(b) - s(a)) / step_s)`` samples of equal length in s, so the density of samples does not depend on how
the ray is cut into intervals. Density is taken at each interval's midpoint (in s), alpha = 1 - exp(-sigma dt).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..errors import require
from .compositing import exclusive_cumsum, optical_depth

#: The far plane may be at most this many pivots away: float32 has 24 bits, so beyond 2^24 pivots a contracted
#: coordinate (2 - pivot / t) rounds to the edge of contracted space and a float32 distance along the ray no
#: longer resolves one pivot: the near scene and the far plane cannot share one ray's arithmetic.
MAX_FAR_RATIO = float(2**24)


def far_steps_at(steps: int, far_ratio: float) -> int:
    """The far-region samples that go with a march of ``steps`` box steps: as many per box step as the run's
    teacher took (``far_ratio`` = its ``teacher.far_steps / teacher.num_steps``; 0 keeps the box only). The
    error-against-run-time curve and the bench scale the far region by it."""
    return max(1, round(far_ratio * steps)) if far_ratio > 0 else 0


@dataclass(frozen=True)
class FarRegion:
    """The far region of an unbounded field, world units along unit rays from the camera.

    near: where rays start (the trainer's near plane). far: where they end (its far plane). pivot: the
    distance at which sampling turns from linear to uniform in disparity (the trainer's unit of contraction).
    """

    near: float
    far: float
    pivot: float

    def __post_init__(self):
        require(all(math.isfinite(v) for v in (self.near, self.far, self.pivot)),
                f"the far region's near, far and pivot must be finite, got {self.near}, {self.far}, {self.pivot}")
        require(0.0 <= self.near < self.far and self.pivot > 0,
                f"the far region needs 0 <= near < far and pivot > 0, got near {self.near}, far {self.far}, "
                f"pivot {self.pivot}")
        require(self.far / self.pivot <= MAX_FAR_RATIO,
                f"the far plane ({self.far:g}) is {self.far / self.pivot:.3g} times the scene's unit "
                f"({self.pivot:g}): float32 cannot resolve the near scene along such rays (at most 2^24 = "
                f"{MAX_FAR_RATIO:.4g}x); lower the run's far plane (nerfstudio: pipeline.model.far_plane)")

    def spacing(self, t: torch.Tensor) -> torch.Tensor:
        """s(t) for distances t (any shape)."""
        p = self.pivot
        return torch.where(t < p, t / p, 2.0 - p / t.clamp(min=p))

    def inverse(self, s: torch.Tensor) -> torch.Tensor:
        """t(s), the inverse of :meth:`spacing`."""
        p = self.pivot
        return torch.where(s < 1.0, s * p, p / (2.0 - s).clamp(min=1e-12))

    def step(self, steps: int) -> float:
        """The length in s of one of ``steps`` samples spanning near .. far."""
        far, near = torch.tensor([self.far, self.near], dtype=torch.float64).split(1)
        return float((self.spacing(far) - self.spacing(near)) / steps)


@torch.no_grad()
def march_interval(field, region: FarRegion, step_s: float, o: torch.Tensor, d: torch.Tensor, t_a: torch.Tensor,
                   t_b: torch.Tensor, trans: torch.Tensor, acc_rgb: torch.Tensor, *, early_stop: float,
                   min_weight: float, segment: int = 32, stats: dict | None = None) -> torch.Tensor:
    """Composite ``field`` (kind "density") over [t_a, t_b] of each ray, front to back, behind transmittance
    ``trans``.

    Args:
        o, d: (N, 3) ray origins and unit directions of travel, world frame.
        t_a, t_b: (N,) interval ends (t_b <= t_a: an empty interval).
        trans: (N,) transmittance in front of the interval.
        acc_rgb: (N, 3) accumulated colour, updated in place (weights times radiance).
    Returns the (N,) transmittance behind the interval; a ray stops early once it falls below ``early_stop``.
    """
    s_a, s_b = region.spacing(t_a.double()), region.spacing(t_b.double())
    n_steps = torch.ceil(((s_b - s_a) / step_s).clamp(min=0)).to(torch.int64)
    ds = torch.where(n_steps > 0, (s_b - s_a) / n_steps.clamp(min=1), torch.zeros_like(s_a))
    trans = trans.clone()
    live = torch.nonzero((n_steps > 0) & (trans > early_stop)).flatten()
    k0 = 0
    while live.numel():
        k = torch.arange(k0, k0 + segment, device=o.device, dtype=torch.float64)
        valid = k[None, :] < n_steps[live, None]                                   # (A, K)
        s0 = s_a[live, None] + k[None, :] * ds[live, None]
        t_lo, t_hi = region.inverse(s0), region.inverse(s0 + ds[live, None])
        t_mid = region.inverse(s0 + 0.5 * ds[live, None])
        dt = ((t_hi - t_lo) * valid).float()
        flat = torch.nonzero(valid.reshape(-1)).flatten()
        rows = flat // segment
        pts = torch.addcmul(o[live][rows].double(), t_mid.reshape(-1)[flat][:, None], d[live][rows].double())
        sigma = torch.zeros(valid.numel(), device=o.device)
        sigma[flat] = field.geometry(pts.float()).reshape(-1).float()   # optical_depth: NaN -> 0, Inf -> opaque
        if stats is not None:
            stats["geometry_points"] = stats.get("geometry_points", 0) + int(flat.numel())
            stats["far_points"] = stats.get("far_points", 0) + int(flat.numel())
        tau = optical_depth(sigma.reshape(valid.shape), dt)
        w = trans[live, None] * torch.exp(-exclusive_cumsum(tau)) * -torch.expm1(-tau)
        sflat = torch.nonzero((w > min_weight).reshape(-1)).flatten()
        if sflat.numel():
            srows = sflat // segment
            dirs = d[live][srows]
            x = torch.addcmul(o[live][srows].double(), t_mid.reshape(-1)[sflat][:, None], dirs.double()).float()
            c = torch.nan_to_num(field.radiance(x, dirs).float().reshape(-1, 3), nan=0.0, posinf=1.0, neginf=0.0)
            acc_rgb.index_add_(0, live[srows], w.reshape(-1)[sflat][:, None] * c)
            if stats is not None:
                stats["radiance_points"] = stats.get("radiance_points", 0) + int(sflat.numel())
        trans[live] = trans[live] * torch.exp(-tau.sum(-1))
        k0 += segment
        live = live[(n_steps[live] > k0) & (trans[live] > early_stop)]
    return trans


@torch.no_grad()
def opaque_depths(field, region: FarRegion, o: torch.Tensor, d: torch.Tensor, *, steps: int = 256,
                  level: float = 0.5, chunk: int = 2048) -> torch.Tensor:
    """Where each whole ray (near .. far) first reaches opacity ``level``: the depth the field's picture shows
    along it, foreground box and far region alike.

    Args:
        o, d: (N, 3) ray origins and unit directions of travel, world frame (float64 keeps far origins exact).
        steps: samples spanning near .. far, uniform in ``region.spacing``.
    Returns:
        (N,) float64 distances along the rays; ``inf`` where a ray stays below ``level`` up to the far plane.
    """
    s = torch.linspace(float(region.spacing(torch.tensor(region.near, dtype=torch.float64))),
                       float(region.spacing(torch.tensor(region.far, dtype=torch.float64))), steps + 1,
                       dtype=torch.float64)
    t = region.inverse(s)
    t_mid, dt = 0.5 * (t[1:] + t[:-1]), (t[1:] - t[:-1]).float()
    out = torch.full((o.shape[0],), math.inf, dtype=torch.float64)
    for i in range(0, o.shape[0], chunk):
        oc, dc = o[i:i + chunk].double(), d[i:i + chunk].double()
        pts = oc[:, None, :] + t_mid[None, :, None] * dc[:, None, :]                 # (n, steps, 3)
        sigma = field.geometry(pts.reshape(-1, 3).float()).reshape(pts.shape[:2]).float()
        opacity = -torch.expm1(-torch.cumsum(optical_depth(sigma, dt[None, :]), dim=1))
        reached = opacity >= level
        first = reached.float().argmax(dim=1)
        out[i:i + chunk] = torch.where(reached.any(dim=1), t_mid[first], torch.full_like(t_mid[first], math.inf))
    return out
