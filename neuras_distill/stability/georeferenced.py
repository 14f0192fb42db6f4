"""Constructed scenes in real-world coordinates (``neuras-distill check extreme:NAME``, the stability catalogue).

City and street captures come in georeferenced frames: UTM eastings about 5e5 m and northings about 4e6 m, or a
local frame offset by 1e5 m. Their fields compute positions in float64 (they subtract their own centre before
anything float32), so a run far from the origin is as precise as one at it when every float32 stage works
relative to the scene (``render.local_frame``). Both scenes here compute in float64 and are textured, so the
bundle's error shows any loss of precision:

* :class:`GeoSphere`: a NeuS sphere of radius 5 (10 units across) with colour bands, seen by cameras 30 units
  away (``geo-sphere`` at the origin, ``geo-sphere-1e5`` at (1e5, -1e5, 1e5), ``geo-sphere-utm`` at
  (5e5, 4.2e6, 50));
* :class:`KilometrePlaza`: a kilometre-wide square of ground with three towers whose box does not contain the
  origin (``km-plaza`` centred at the origin, ``km-plaza-offset`` at (2500, -1800, 30)).
"""

from __future__ import annotations

import math

import torch

#: UTM-like coordinates (easting, northing, height) in metres: float32 spaces them 0.031 and 0.5 apart.
UTM_LIKE = (5e5, 4.2e6, 50.0)


class _Float64Scene:
    """What both scenes share: an SDF computed in float64 relative to ``center``, colour bands, a white sky."""

    kind = "sdf"
    background_color = torch.ones(3)

    def __init__(self, center, half_extent, inv_s: float):
        self.center = torch.as_tensor(center, dtype=torch.float64).reshape(3)
        half = torch.as_tensor(half_extent, dtype=torch.float64).reshape(3)
        self.aabb = torch.stack([self.center - half, self.center + half])      # float64: exact far away
        self.inv_s = float(inv_s)

    def _local(self, x: torch.Tensor) -> torch.Tensor:
        """World points (N, 3), any float dtype -> (N, 3) float64 relative to ``center``."""
        return x.double() - self.center.to(x.device)

    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        """x (N, 3) world -> signed distance (N,) float32, negative inside."""
        return self.local_sdf(self._local(x)).float()

    def radiance(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """x (N, 3) world, d (N, 3) -> colour (N, 3) in [0.15, 0.85]: bands of ``band`` units along each axis."""
        p = self._local(x) / self.band
        rgb = torch.stack([torch.sin(2 * math.pi * p[:, 0]), torch.sin(2 * math.pi * p[:, 1]),
                           torch.sin(2 * math.pi * (p[:, 2] + 0.5 * p[:, 0]))], dim=-1)
        return (0.5 + 0.35 * rgb).float()


class GeoSphere(_Float64Scene):
    """A NeuS sphere of ``radius`` at ``center`` (sdf = |x - c| - r, float64), colour bands 2 units wide."""

    band = 2.0

    def __init__(self, center=(0.0, 0.0, 0.0), radius: float = 5.0, inv_s: float = 200.0):
        self.radius = float(radius)
        super().__init__(center, [1.1 * self.radius] * 3, inv_s)

    def local_sdf(self, p: torch.Tensor) -> torch.Tensor:
        return p.norm(dim=-1) - self.radius

    def default_cameras(self, n: int, width: int = 512, height: int = 512):
        """``n`` cameras 30 units from the centre, elevations 10-40 degrees."""
        from ..render.cameras import Cameras
        return Cameras.orbit(self.center, 6.0 * self.radius, n, width=width, height=height,
                             elevation_deg=(10.0, 40.0))

    def __repr__(self) -> str:
        return f"GeoSphere(center={self.center.tolist()}, radius={self.radius})"


class KilometrePlaza(_Float64Scene):
    """A 1000 x 1000 m square of ground 4 m thick (top at local z = 0) with three towers (60 m wide, 40-120 m
    tall), colour bands 25 m wide; the box spans 1000 x 1000 x 126 m around ``center``."""

    band = 25.0
    TOWERS = ((-200.0, 150.0, 40.0), (120.0, -100.0, 120.0), (300.0, 260.0, 70.0))  # (x, y, height)

    def __init__(self, center=(0.0, 0.0, 0.0), inv_s: float = 2.0):
        super().__init__(center, (510.0, 510.0, 65.0), inv_s)
        self.aabb[0, 2] = self.center[2] - 6.0
        self.aabb[1, 2] = self.center[2] + 124.0

    @staticmethod
    def _box(p: torch.Tensor, centre, half) -> torch.Tensor:
        q = (p - torch.as_tensor(centre, dtype=torch.float64)).abs() - torch.as_tensor(half, dtype=torch.float64)
        return q.clamp(min=0).norm(dim=-1) + q.amax(-1).clamp(max=0)

    def local_sdf(self, p: torch.Tensor) -> torch.Tensor:
        d = self._box(p, (0.0, 0.0, -2.0), (500.0, 500.0, 2.0))
        for x, y, h in self.TOWERS:
            d = torch.minimum(d, self._box(p, (x, y, 0.5 * h), (30.0, 30.0, 0.5 * h)))
        return d

    def default_cameras(self, n: int, width: int = 512, height: int = 512):
        """``n`` cameras 1300 m from the centre, elevations 20-45 degrees."""
        from ..render.cameras import Cameras
        return Cameras.orbit(self.center + torch.tensor([0.0, 0.0, 30.0], dtype=torch.float64), 1300.0, n,
                             width=width, height=height, elevation_deg=(20.0, 45.0))

    def __repr__(self) -> str:
        return f"KilometrePlaza(center={self.center.tolist()})"


GEOREFERENCED = {
    "geo-sphere": lambda: GeoSphere(),
    "geo-sphere-1e5": lambda: GeoSphere(center=(1e5, -1e5, 1e5)),
    "geo-sphere-utm": lambda: GeoSphere(center=UTM_LIKE),
    "km-plaza": lambda: KilometrePlaza(),
    "km-plaza-offset": lambda: KilometrePlaza(center=(2500.0, -1800.0, 30.0)),
}
