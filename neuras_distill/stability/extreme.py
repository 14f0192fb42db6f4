"""Constructed extreme fields for ``neuras-distill check extreme:NAME`` and the stability tests.

Each is a tiny analytic field (Field protocol) that stresses one numerical regime of the stability note:

* ``thin-shell``: density shell of radius 0.5, 0.002 thick, σ = 1e6 per unit (σδ ≈ 7e3 at 256 steps, and the
  shell is thinner than the 256-step teacher step of 0.0074);
* ``sharp-plate``: NeuS SDF of a 0.003-thick plate with inv_s = 1e5 (the opacity shell is 4.4e-5 wide);
* ``solid-1e8``: a cube of density 1e8 (stiff but solid: every step saturates, nothing is skipped);
* ``steep-sdf``: a sphere SDF scaled by 10 (|∇f| = 10: not a distance);
* ``km-sphere``: a 500 m sphere (a kilometre-scale scene);
* ``far-sphere``: a unit sphere 1e5 units from the origin (float32 positions quantised to 0.0078: refused);
* ``far-km-sphere``: a 500 m sphere 1e5 units from the origin (the same quantisation, 1e-5 of its size: fine);
* ``nan-corner``: a density sphere whose field returns NaN in one corner of the box;
* ``flipped-sign``: a sphere SDF that is positive inside;
* the scenes in real-world coordinates of :mod:`.georeferenced` (``geo-sphere``, ``geo-sphere-1e5``,
  ``geo-sphere-utm``, ``km-plaza``, ``km-plaza-offset``).
"""

from __future__ import annotations

import torch

from ..errors import BadInputError
from ..scenes.analytic import SphereSDF
from .georeferenced import GEOREFERENCED


class _Base:
    """Constant-ish colour, white background, default orbit cameras."""

    background_color = torch.ones(3)

    def radiance(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        x = x.float()
        lo, hi = self.aabb[0], self.aabb[1]
        u = ((x - lo) / (hi - lo)).clamp(0.0, 1.0)
        return 0.2 + 0.6 * u

    def default_cameras(self, n: int, width: int = 512, height: int = 512):
        from ..scenes.analytic import orbit_framing
        return orbit_framing(self.aabb, n, width, height)


class ThinShell(_Base):
    """Density σ inside a spherical shell |r - radius| < thickness / 2, 0 elsewhere."""

    kind = "density"

    def __init__(self, radius: float = 0.5, thickness: float = 0.002, sigma: float = 1e6, center=(0.0, 0.0, 0.0)):
        self.radius, self.thickness, self.sigma = float(radius), float(thickness), float(sigma)
        self.center = torch.as_tensor(center, dtype=torch.float32)
        h = self.radius + 0.1 * self.radius
        self.aabb = torch.stack([self.center - h, self.center + h])

    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        r = (x.float() - self.center).norm(dim=-1)
        return torch.where((r - self.radius).abs() < 0.5 * self.thickness, self.sigma, 0.0)


class SolidCube(_Base):
    """Density σ inside a cube of half-size ``half``."""

    kind = "density"

    def __init__(self, half: float = 0.4, sigma: float = 1e8):
        self.half, self.sigma = float(half), float(sigma)
        self.aabb = torch.tensor([[-0.5] * 3, [0.5] * 3])

    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        return torch.where(x.float().abs().amax(-1) < self.half, self.sigma, 0.0)


class Plate(_Base):
    """SDF of a plate |z| < thickness / 2 within |x|, |y| < 0.4 (box SDF), sharpness ``inv_s``."""

    kind = "sdf"

    def __init__(self, thickness: float = 0.003, inv_s: float = 1e5):
        self.half = torch.tensor([0.4, 0.4, 0.5 * float(thickness)])
        self.inv_s = float(inv_s)
        self.aabb = torch.tensor([[-0.5, -0.5, -0.1], [0.5, 0.5, 0.1]])

    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        q = x.float().abs() - self.half
        return q.clamp(min=0).norm(dim=-1) + q.amax(-1).clamp(max=0)


class ScaledSDF(_Base):
    """``scale * sdf`` of a wrapped SDF field (scale < 0 flips the sign)."""

    kind = "sdf"

    def __init__(self, inner, scale: float):
        self.inner, self.scale = inner, float(scale)
        self.aabb = inner.aabb
        self.inv_s = getattr(inner, "inv_s", None)

    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        return self.scale * self.inner.geometry(x)


class NaNCorner(ThinShell):
    """A solid density ball (σ = 50) whose field is NaN where x, y, z > 0.4."""

    def __init__(self):
        super().__init__(radius=0.25, thickness=0.5, sigma=50.0)
        self.aabb = torch.tensor([[-0.5] * 3, [0.5] * 3])

    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        g = super().geometry(x)
        return torch.where((x.float() > 0.4).all(-1), float("nan"), g)


def _sphere(center, radius: float, inv_s: float) -> SphereSDF:
    return SphereSDF(center=center, radius=radius, margin=0.1 * radius, inv_s=inv_s)


EXTREME = {
    "thin-shell": lambda: ThinShell(),
    "sharp-plate": lambda: Plate(),
    "solid-1e8": lambda: SolidCube(),
    "steep-sdf": lambda: ScaledSDF(_sphere((0.0, 0.0, 0.0), 0.5, 1000.0), 10.0),
    "km-sphere": lambda: _sphere((0.0, 0.0, 0.0), 500.0, 1.0),
    "far-sphere": lambda: _sphere((1e5, 0.0, 0.0), 0.5, 1000.0),
    "far-km-sphere": lambda: _sphere((1e5, 0.0, 0.0), 500.0, 1.0),
    "nan-corner": lambda: NaNCorner(),
    "flipped-sign": lambda: ScaledSDF(_sphere((0.0, 0.0, 0.0), 0.5, 1000.0), -1.0),
    **GEOREFERENCED,
}


def make_extreme(name: str):
    """The constructed field ``name`` (see the module docstring)."""
    if name not in EXTREME:
        raise BadInputError(f"unknown extreme field {name!r}; available: {', '.join(sorted(EXTREME))}")
    return EXTREME[name]()
