"""Robust ray / axis-aligned box intersection (slab test), safe for every corner case.

This module owns :func:`ray_aabb`. Cases handled (see the stability note, A6): direction components that
are zero or tiny (treated as parallel to that slab: the ray is inside the slab for all t or for none, never
NaN), origins exactly on a face, edge or corner, cameras inside the box (``t_near`` clamped to ``near``),
rays pointing away (miss).
"""

from __future__ import annotations

import torch

PARALLEL_EPS = 1e-12


def ray_aabb(origins: torch.Tensor, dirs: torch.Tensor, aabb: torch.Tensor, near: float = 0.0
             ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Intersect rays with a box.

    Args:
        origins: (N, 3) ray origins, world frame.
        dirs: (N, 3) ray directions (need not be unit; t is in units of ``|dirs|``).
        aabb: (2, 3) box ``[min, max]``.
        near: smallest admissible t (a camera inside the box starts at ``near``).

    Returns:
        t_near (N,), t_far (N,) float32, and hit (N,) bool where ``t_far > t_near``. For misses both t are 0.
        Points ``origins + t * dirs`` for t in [t_near, t_far] lie in the (closed) box.
    """
    o = origins.float()
    d = dirs.float()
    lo = aabb[0].to(o)
    hi = aabb[1].to(o)
    parallel = d.abs() < PARALLEL_EPS
    safe_d = torch.where(parallel, torch.ones_like(d), d)
    t0 = (lo - o) / safe_d
    t1 = (hi - o) / safe_d
    tmin = torch.minimum(t0, t1)
    tmax = torch.maximum(t0, t1)
    inside_slab = (o >= lo) & (o <= hi)
    inf = torch.full_like(tmin, float("inf"))
    # parallel axis: unconstrained if the origin is within the slab, empty otherwise
    tmin = torch.where(parallel, torch.where(inside_slab, -inf, inf), tmin)
    tmax = torch.where(parallel, torch.where(inside_slab, inf, -inf), tmax)
    t_near = tmin.amax(dim=-1).clamp(min=near)
    t_far = tmax.amin(dim=-1)
    hit = t_far > t_near
    zero = torch.zeros_like(t_near)
    return torch.where(hit, t_near, zero), torch.where(hit, t_far, zero), hit
