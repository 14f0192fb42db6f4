"""The ``gradient-ball`` scene: a density ball with a soft fringe, a smooth colour gradient and its own orbit.

This module owns :class:`GradientBallField` (kind ``"density"``, no SDF), a test field with what trained NeRFs
have and the other synthetic scenes lack (issue "Fidelity you can see"):

* **A soft fringe.** σ(x) = σ_max · sigmoid((R_c − |x − c|) / w), σ_max = 200 per unit (a ray entering the
  core is opaque within ~0.02), w = 0.012. The core radius R_c is set so that a ray passing the centre at
  distance ``radius`` (0.5) collects opacity 0.5: ``radius`` is the radius one sees (the silhouette), and
  R_c = radius − 4.0 w. Against the passing distance p the opacity of a ray rises from 5 % to 95 % over
  ~4.4 w = 0.05 (10 % of the radius); a ray hitting the ball head-on reaches opacity 0.5 about 3 w inside
  the silhouette sphere (radius ~0.465) and 0.99 about 2 w inside the core radius.
* **A smooth, saturated colour gradient** over the ball: a cosine palette (hue-like, saturated) driven by a
  linear function of the direction from the centre, so the colour changes with longitude and latitude, is
  smooth everywhere (poles included) and constant along each radius (the fringe has the colour of the
  surface under it); times a smooth diffuse term (no clamps). No texture detail, no view dependence.
  White background.
* **Its own cameras** (:meth:`GradientBallField.default_cameras`): a closed helix around the ball (elevation
  from −1° up to 40° and back, lowest at view n/8) on which the views a default run holds out (every
  ``CameraConfig.test_every``-th from index test_every // 2, :meth:`Cameras.split`) bob 4° below the path. So
  held-out views see the lower part of the ball a little more than their training neighbours do (view 6 of
  48 sits at −5°, every training view at −0.8° or above).

World frame: z up, centre (0, 0, 0.5), radius 0.5 (like the ``sphere`` scene). ``surface_level`` is σ on
the silhouette sphere (≈ 3.5 per unit): the mesh is the sphere one sees, as instant-ngp's own export
threshold (ln σ_ngp = 2.5, ≈ 6.8 per world unit in the frame of ``tests/data/ngp/ball.ingp``) puts it on
the snapshot of this ball.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ..config import CameraConfig
from ..errors import require
from .analytic import orbit_framing

BALL_CENTER = (0.0, 0.0, 0.5)
BALL_RADIUS = 0.5          # the visible radius: a ray passing at this distance collects opacity 0.5
BALL_SIGMA_MAX = 200.0     # σ deep inside, per world unit
BALL_FRINGE = 0.012        # w, the width of the sigmoid ramp of σ (world units)
AABB_MARGIN = 0.1          # box = ball + this on every side (σ at the box faces ~1e-3, optical depth ~2e-4)

# colour: rgb = 0.5 + PALETTE_AMPLITUDE * cos(2π (t + (0, 1/3, 2/3))), t = n · PALETTE_AXIS (n: unit direction
# from the centre); |PALETTE_AXIS| = 0.56, so t spans 1.1 cycles of the palette over the ball
PALETTE_AXIS = (0.40, -0.25, 0.30)
PALETTE_AMPLITUDE = 0.42
LIGHT_DIR = (0.45, -0.35, 0.82)
DIFFUSE = 0.22             # shade = 1 - DIFFUSE + DIFFUSE * n · l  (0.56 .. 1, smooth)

# cameras
ORBIT_ELEVATION_DEG = (-1.0, 40.0)   # the helix: lowest at view n/8, highest at view 5n/8
HELD_OUT_DIP_DEG = 4.0               # held-out views sit this much below the helix
ORBIT_PADDING = 0.75                 # of orbit_framing (the box's bounding sphere is loose around the ball)


def _tangent_optical_depth(p: float, core: float, sigma_max: float, w: float, n: int = 40001) -> float:
    """∫ σ along a straight line passing the centre at distance ``p`` (trapezoid rule, float64)."""
    half = math.sqrt(max(core + 40.0 * w, p) ** 2 - p * p) + 40.0 * w
    t = torch.linspace(-half, half, n, dtype=torch.float64)
    r = torch.sqrt(p * p + t * t)
    return float(torch.trapezoid(sigma_max * torch.sigmoid((core - r) / w), t))


def core_radius(radius: float, sigma_max: float, w: float) -> float:
    """R_c such that a ray passing the centre at distance ``radius`` has optical depth ln 2 (opacity 0.5)."""
    lo, hi = radius - 30.0 * w, radius
    require(_tangent_optical_depth(radius, hi, sigma_max, w) > math.log(2.0),
            f"sigma_max {sigma_max} with fringe {w} is too thin for an opaque ball of radius {radius}")
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if _tangent_optical_depth(radius, mid, sigma_max, w) > math.log(2.0):
            hi = mid
        else:
            lo = mid
    return 0.5 * (lo + hi)


class GradientBallField:
    """A ball of density with a soft fringe and a smooth colour gradient (kind ``"density"``), z up.

    Members: ``kind``, ``aabb`` (2, 3), ``geometry(x)`` (N, 3) -> σ (N,) per world unit,
    ``radiance(x, d)`` (N, 3) -> (N, 3), ``albedo(x)``, ``background_color`` (white), ``surface_level``,
    ``default_cameras(n, width, height)``, and the shape: ``center`` (3,), ``radius`` (visible),
    ``core_radius`` (where σ = σ_max / 2), ``sigma_max``, ``fringe`` (w).
    """

    kind = "density"

    def __init__(self, center=BALL_CENTER, radius: float = BALL_RADIUS, *, sigma_max: float = BALL_SIGMA_MAX,
                 fringe: float = BALL_FRINGE, margin: float = AABB_MARGIN):
        require(radius > 0 and math.isfinite(radius), f"ball radius must be positive, got {radius}")
        require(fringe > 0 and sigma_max > 0,
                f"fringe and sigma_max must be positive, got {fringe}, {sigma_max}")
        self.center = torch.as_tensor(center, dtype=torch.float32).reshape(3)
        self.radius, self.sigma_max, self.fringe = float(radius), float(sigma_max), float(fringe)
        self.core_radius = core_radius(self.radius, self.sigma_max, self.fringe)
        require(self.core_radius > 0, f"fringe {fringe} is too wide for a ball of radius {radius}")
        half = self.radius + float(margin)
        self.aabb = torch.stack([self.center - half, self.center + half])
        self.background_color = torch.ones(3)
        self.surface_level = self.sigma_max / (1.0 + math.exp((self.radius - self.core_radius) / self.fringe))
        self._axis = torch.tensor(PALETTE_AXIS)
        self._light = F.normalize(torch.tensor(LIGHT_DIR), dim=0)

    def __repr__(self) -> str:
        return (f"GradientBallField(center={self.center.tolist()}, radius={self.radius}, "
                f"core_radius={self.core_radius:.4f}, sigma_max={self.sigma_max}, fringe={self.fringe})")

    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        """x (N, 3) -> σ (N,) >= 0 per world unit."""
        r = (x.float() - self.center).norm(dim=-1)
        return self.sigma_max * torch.sigmoid((self.core_radius - r) / self.fringe)

    def albedo(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 3) colour of the gradient from the direction of x from the centre (smooth, in [0.08, 0.92])."""
        n = F.normalize(x.float() - self.center, dim=-1, eps=1e-12)
        t = (n * self._axis).sum(-1, keepdim=True)
        phase = x.new_tensor([0.0, 1.0 / 3.0, 2.0 / 3.0])
        return 0.5 + PALETTE_AMPLITUDE * torch.cos(2.0 * math.pi * (t + phase))

    def radiance(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """x (N, 3), d (N, 3) unit directions of travel (unused: the ball is matte) -> (N, 3) in [0, 1]."""
        n = F.normalize(x.float() - self.center, dim=-1, eps=1e-12)
        shade = 1.0 - DIFFUSE + DIFFUSE * (n * self._light).sum(-1, keepdim=True)
        return (self.albedo(x) * shade).clamp(0.0, 1.0)

    def default_cameras(self, n: int, width: int = 512, height: int = 512, *,
                        held_out_every: int = CameraConfig.test_every):
        """``n`` cameras on a closed helix around the ball (z up, 40° horizontal fov, distance and intrinsics
        of :func:`orbit_framing`), azimuth 360° i / n. Elevation: from −1° (view n/8) to 40° (view 5n/8) and
        back, a cosine in i; the views ``Cameras.split(held_out_every)`` holds out (i % held_out_every ==
        held_out_every // 2) are 4° lower (0: no dip)."""
        from ..render.cameras import Cameras, look_at

        require(n > 0, "an orbit needs at least one camera")
        framing = orbit_framing(self.aabb, n, width, height, elevation_deg=0.0, padding=ORBIT_PADDING)
        target = (0.5 * (self.aabb[0] + self.aabb[1])).double()
        dist = float((framing.centers[0].double() - target).norm())
        lo, hi = ORBIT_ELEVATION_DEG
        up = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
        poses = []
        for i in range(n):
            el = lo + (hi - lo) * (0.5 - 0.5 * math.cos(2.0 * math.pi * (i / n - 0.125)))
            if held_out_every and i % held_out_every == held_out_every // 2:
                el -= HELD_OUT_DIP_DEG
            az, el = math.radians(360.0 * i / n), math.radians(el)
            eye = target + dist * torch.tensor([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az),
                                                math.sin(el)], dtype=torch.float64)
            poses.append(look_at(eye, target, up))
        return Cameras(torch.stack(poses).float(), framing.fx, framing.fy, framing.cx, framing.cy,
                       framing.width, framing.height)


def make_gradient_ball() -> GradientBallField:
    return GradientBallField()
