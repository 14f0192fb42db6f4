"""Analytic SDF fields with exact surfaces (sphere, torus, rounded box).

This module owns:

* :class:`AnalyticSDFField` and its shapes :class:`SphereSDF`, :class:`TorusSDF`, :class:`BoxSDF`: fields of
  kind ``"sdf"`` whose ``exact_sdf(x)`` is the true Euclidean signed distance (negative inside), with a
  simple position-dependent colour and a mild view-dependent term. Used by tests and as synthetic scenes.

The SDF -> density view (:func:`~neuras_distill.fields.wrappers.laplace_density`,
:class:`~neuras_distill.fields.wrappers.SDFToDensityField`) is in :mod:`neuras_distill.fields.wrappers`.

All points are world points (N, 3); directions are unit directions of travel (N, 3).
"""

from __future__ import annotations

import math

import torch

from ..errors import require
from ..fields.wrappers import DEFAULT_BETA, SDFToDensityField


def smoothstep(e0: float, e1: float, x: torch.Tensor) -> torch.Tensor:
    """Hermite step of ``x`` (any shape) from 0 at ``e0`` to 1 at ``e1`` (GLSL's smoothstep; e0 > e1 falls)."""
    t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


class AnalyticSDFField:
    """Base of the analytic SDF fields: kind ``"sdf"``, exact signed distance, simple colour.

    Subclasses implement :meth:`exact_sdf` (N, 3) -> (N,) and set ``aabb``. Radiance is a smooth colour
    from the position (in [0.15, 0.9]) times a soft diffuse term, plus a small view-dependent lobe when
    ``gloss > 0``; always in [0, 1].
    """

    kind = "sdf"

    def __init__(self, aabb: torch.Tensor, *, inv_s: float = 1000.0, gloss: float = 0.0,
                 background_color=(1.0, 1.0, 1.0)):
        self.aabb = torch.as_tensor(aabb, dtype=torch.float32).reshape(2, 3)
        self.inv_s = float(inv_s)
        self.gloss = float(gloss)
        self.background_color = torch.as_tensor(background_color, dtype=torch.float32).reshape(3)

    # -- geometry
    def exact_sdf(self, x: torch.Tensor) -> torch.Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        """x (N, 3) -> signed distance (N,), negative inside."""
        return self.exact_sdf(x.float())

    def normal(self, x: torch.Tensor, eps: float = 1e-4) -> torch.Tensor:
        """(N, 3) unit outward normals from central differences of :meth:`exact_sdf`."""
        x = x.float()
        offs = torch.eye(3, dtype=x.dtype) * eps
        pts = torch.cat([x[:, None, :] + offs, x[:, None, :] - offs], dim=1).reshape(-1, 3)
        f = self.exact_sdf(pts).reshape(-1, 2, 3)
        g = f[:, 0] - f[:, 1]
        return torch.nn.functional.normalize(g, dim=-1, eps=1e-12)

    def radiance(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """x (N, 3), d (N, 3) -> (N, 3) colour in [0, 1]."""
        x, d = x.float(), d.float()
        lo, hi = self.aabb[0].to(x.device), self.aabb[1].to(x.device)     # aabb: host metadata
        u = ((x - lo) / (hi - lo)).clamp(0.0, 1.0)
        albedo = 0.15 + 0.75 * (0.5 + 0.5 * torch.sin(2.0 * math.pi * u + x.new_tensor([0.0, 2.1, 4.2])))
        n = self.normal(x)
        light = torch.nn.functional.normalize(x.new_tensor([0.4, -0.3, 0.85]), dim=0)
        ndl = (n * light).sum(-1, keepdim=True)
        shade = 0.45 + 0.55 * ((ndl + 0.3) / 1.3).clamp(min=0.0)
        rgb = albedo * shade
        if self.gloss > 0:
            h = torch.nn.functional.normalize(light - d, dim=-1)
            rgb = rgb + self.gloss * (n * h).sum(-1, keepdim=True).clamp(min=0.0) ** 12
        return rgb.clamp(0.0, 1.0)

    def density(self, beta: float = DEFAULT_BETA) -> SDFToDensityField:
        """The VolSDF density version of this field (kind ``"density"``)."""
        return SDFToDensityField(self, beta)

    def default_cameras(self, n: int, width: int = 512, height: int = 512):
        """An orbit (z up, elevations 15..50 degrees) framing the aabb (see :func:`orbit_framing`)."""
        return orbit_framing(self.aabb, n, width, height)


ORBIT_FOV_DEG = 40.0
ORBIT_ELEVATION_DEG = (15.0, 50.0)
ORBIT_PADDING = 1.0


def orbit_framing(aabb: torch.Tensor, n: int, width: int = 512, height: int = 512, *,
                  fov_deg: float = ORBIT_FOV_DEG, elevation_deg=ORBIT_ELEVATION_DEG, padding: float = ORBIT_PADDING):
    """``n`` cameras on a helix orbit (z up) around the aabb centre that keep the whole box in view.

    The distance is ``padding * r / sin(fov / 2)`` with r the radius of the sphere around the aabb (so the
    sphere fits the narrower field of view), elevations vary between ``elevation_deg`` over the orbit.
    """
    from ..render.cameras import Cameras

    aabb = torch.as_tensor(aabb, dtype=torch.float32).reshape(2, 3)
    center = 0.5 * (aabb[0] + aabb[1])
    radius = 0.5 * float((aabb[1] - aabb[0]).norm())
    half_h = math.radians(fov_deg) / 2  # Cameras.orbit's fov is horizontal
    fov_min = 2 * min(half_h, math.atan(math.tan(half_h) * height / width))
    dist = padding * radius / math.sin(0.5 * fov_min)
    return Cameras.orbit(center.tolist(), dist, n, width=width, height=height, fov_deg=fov_deg,
                         elevation_deg=elevation_deg)


def _box_around(center: torch.Tensor, half: torch.Tensor, margin: float) -> torch.Tensor:
    return torch.stack([center - half - margin, center + half + margin])


class SphereSDF(AnalyticSDFField):
    """Sphere of ``radius`` at ``center``: sdf = |x − c| − r."""

    def __init__(self, center=(0.0, 0.0, 0.0), radius: float = 0.5, *, margin: float = 0.05, **kw):
        require(radius > 0, f"sphere radius must be positive, got {radius}")
        self.center = torch.as_tensor(center, dtype=torch.float32).reshape(3)
        self.radius = float(radius)
        super().__init__(_box_around(self.center, torch.full((3,), self.radius), margin), **kw)

    def exact_sdf(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.center).norm(dim=-1) - self.radius

    def __repr__(self) -> str:
        return f"SphereSDF(center={self.center.tolist()}, radius={self.radius})"


class TorusSDF(AnalyticSDFField):
    """Torus around the z axis through ``center``: major radius R (ring), minor radius r (tube)."""

    def __init__(self, center=(0.0, 0.0, 0.0), major: float = 0.4, minor: float = 0.15, *,
                 margin: float = 0.05, **kw):
        require(0 < minor < major, f"torus needs 0 < minor < major, got minor={minor}, major={major}")
        self.center = torch.as_tensor(center, dtype=torch.float32).reshape(3)
        self.major, self.minor = float(major), float(minor)
        half = torch.tensor([major + minor, major + minor, minor])
        super().__init__(_box_around(self.center, half, margin), **kw)

    def exact_sdf(self, x: torch.Tensor) -> torch.Tensor:
        p = x - self.center
        q = torch.stack([p[:, :2].norm(dim=-1) - self.major, p[:, 2]], dim=-1)
        return q.norm(dim=-1) - self.minor

    def __repr__(self) -> str:
        return f"TorusSDF(center={self.center.tolist()}, major={self.major}, minor={self.minor})"


class BoxSDF(AnalyticSDFField):
    """Axis-aligned box of half extents ``half_size`` at ``center``, edges rounded by ``rounding``
    (the rounded box's outer extent is ``half_size``)."""

    def __init__(self, center=(0.0, 0.0, 0.0), half_size=(0.4, 0.3, 0.2), rounding: float = 0.0, *,
                 margin: float = 0.05, **kw):
        self.center = torch.as_tensor(center, dtype=torch.float32).reshape(3)
        self.half_size = torch.as_tensor(half_size, dtype=torch.float32).reshape(3)
        self.rounding = float(rounding)
        require(bool((self.half_size > self.rounding).all()) and self.rounding >= 0,
                f"box half sizes {self.half_size.tolist()} must exceed rounding {rounding} >= 0")
        super().__init__(_box_around(self.center, self.half_size, margin), **kw)

    def exact_sdf(self, x: torch.Tensor) -> torch.Tensor:
        q = (x - self.center).abs() - (self.half_size - self.rounding)
        outside = q.clamp(min=0.0).norm(dim=-1)
        inside = q.max(dim=-1).values.clamp(max=0.0)
        return outside + inside - self.rounding

    def __repr__(self) -> str:
        return f"BoxSDF(center={self.center.tolist()}, half_size={self.half_size.tolist()}, r={self.rounding})"


class BlocksSDF(AnalyticSDFField):
    """A small town for tiling: a ground slab 3 x 2 units (top at z = 0, 0.1 thick) with six rounded blocks of
    different heights on a 3 x 2 grid, z up; sdf = min(slab, blocks). Every block stands inside one cell of a
    1-unit grid, the ground runs under all of them: a tile boundary at x = -0.5 or 0.5 or y = 0 cuts the ground
    and no block."""

    HEIGHTS = (0.55, 0.3, 0.8, 0.4, 0.65, 0.25)

    def __init__(self, *, margin: float = 0.05, **kw):
        self.centres = torch.tensor([[x, y] for y in (-0.5, 0.5) for x in (-1.0, 0.0, 1.0)], dtype=torch.float32)
        self.heights = torch.tensor(self.HEIGHTS, dtype=torch.float32)
        aabb = torch.tensor([[-1.5 - margin, -1.0 - margin, -0.1 - margin],
                             [1.5 + margin, 1.0 + margin, float(self.heights.max()) + margin]])
        super().__init__(aabb, **kw)

    def exact_sdf(self, x: torch.Tensor) -> torch.Tensor:
        slab_half = x.new_tensor([1.5, 1.0, 0.05])
        q = (x - x.new_tensor([0.0, 0.0, -0.05])).abs() - slab_half
        d = q.clamp(min=0.0).norm(dim=-1) + q.max(dim=-1).values.clamp(max=0.0)
        r = 0.03
        for (cx, cy), h in zip(self.centres.tolist(), self.heights.tolist()):
            half = x.new_tensor([0.3 - r, 0.3 - r, h / 2 - r])
            q = (x - x.new_tensor([cx, cy, h / 2])).abs() - half
            d = torch.minimum(d, q.clamp(min=0.0).norm(dim=-1) + q.max(dim=-1).values.clamp(max=0.0) - r)
        return d

    def __repr__(self) -> str:
        return "BlocksSDF()"

