"""The embedded street scene: an analytic SDF field in metres, seen from a driving trajectory.

This module owns :class:`StreetField` (scene name ``"street"``) and its layout tables. World frame: z up,
units metres, the street runs along +x. In the scene's local frame (before ``origin`` is added):

* ground: a 0.6 m slab with its top at z = 0; a two-lane road (asphalt, |y| < 3.5) with a dashed centre
  line, solid edge lines and a zebra crossing painted in the albedo; raised sidewalks (top z = 0.15, curb
  at |y| = 3.5, ~3 m wide before the facades, grass where no building stands);
* ten box buildings (five a side), 8 to 20 m tall, with different widths along x, setbacks and gaps, each
  with its own facade colour and window grid (frames, dark glass that mirrors the sky) in the albedo;
  the +x end is open (a plaza and a park), so a driver looking along the street sees sky and hills;
* street furniture: four parked cars (rounded boxes on cylinder wheels), three street lamps, four trees
  (cylinder trunk, two-sphere crown) and a bus shelter with a bench. Nothing is thinner than ~0.3 m:
  finer parts would be finer than the teacher's ray step (aabb diagonal / 256 = 0.34 m) and would not
  converge at 256 steps.

Distant content (sky, sun, a range of hills 1 to 6 degrees above the horizon, a city skyline band ahead,
hazy ground below the horizon) lives in :meth:`StreetField.background`, modelled at infinity: the
teacher's background takes only a direction, so it stands for hills and a skyline hundreds of metres away
(no parallax between the cameras of the trajectory, which is what such far content would show anyway).

Geometry is one analytic SDF: min/max of exact primitive SDFs (rounded boxes, capped cylinders, capsules,
spheres, half-spaces), vectorised on (N, 3) float32 (CPU). The min is exact outside the union and a bound
inside it (|grad| = 1 wherever one primitive is nearest, < 1 on the kinks where two meet). Terrain and the
ten buildings (a fixed loop with scalar parameters) are evaluated at every point; each small object only
at the points where a cheap lower bound of its distance (distance to a slab around it) is below the
running minimum, which gives exactly the same min (tests/test_street.py checks it against the plain min).
About 5-7 M points/s on one CPU thread.

Radiance: albedo per material x (hemisphere sky light + sun diffuse with analytic box/sphere sun shadows)
+ view-dependent sky reflection (Fresnel) and sun highlight on glass and car paint; normals from a
4-point tetrahedral difference of the SDF; textures are looked up where the sample's ray meets the
locally planar surface, so that every sample of a ray sees the same texel. The sun direction is the one
the sky draws. ``inv_s`` = 24 /m: renders at 256 and 512 steps agree to > 36 dB PSNR (160x90 views of the
default trajectory).

``origin`` translates the whole scene (aabb, geometry, radiance, cameras): inputs are converted to the
local frame by subtracting ``origin`` in float32 before anything else, so a street kilometres from the
world origin behaves like one at (0, 0, 0) up to float32 rounding of the inputs (half an ulp, 1.2e-4 m, at 3 km).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ..errors import require
from .analytic import smoothstep

# ---------------------------------------------------------------------------------------------- layout
ROAD_HALF = 3.5            # asphalt |y| < 3.5 (two 3.5 m lanes)
CURB_H = 0.15              # sidewalk top
CURB_R = 0.04              # rounding of the curb edge
SLAB_BOTTOM = -0.6         # ground slab bottom
BACK_Y = 14.0              # buildings reach back to |y| = 14 (past the aabb)
BUILDING_BOTTOM = -0.5
BUILDING_ROUNDING = 0.1    # edges of the building boxes
AABB = ((-40.0, -13.0, -1.0), (40.0, 13.0, 21.0))  # the street is 80 m long (x), 26 m wide (y)

# buildings: (side (+1: y > 0 / left when driving +x, -1: right), x0, x1, facade |y|, height,
#             wall rgb, frame rgb, glass rgb, window cell width, floor height, window half w, half h)
BUILDINGS = (
    (-1, -40.0, -24.0, 6.5, 14.0, (0.62, 0.33, 0.26), (0.90, 0.88, 0.84), (0.10, 0.12, 0.15),
     2.6, 3.2, 0.60, 0.85),
    (-1, -22.5, -10.0, 7.5, 19.0, (0.80, 0.72, 0.58), (0.35, 0.30, 0.26), (0.08, 0.10, 0.14),
     2.2, 3.0, 0.55, 0.95),
    (-1, -9.0, 4.0, 6.5, 9.0, (0.55, 0.62, 0.70), (0.92, 0.92, 0.92), (0.09, 0.12, 0.16),
     3.0, 3.4, 0.95, 0.80),
    (-1, 5.5, 20.0, 8.0, 16.0, (0.88, 0.82, 0.62), (0.55, 0.42, 0.30), (0.10, 0.11, 0.13),
     2.4, 3.1, 0.50, 0.90),
    (-1, 22.0, 30.0, 6.5, 11.0, (0.52, 0.58, 0.42), (0.88, 0.86, 0.78), (0.09, 0.11, 0.12),
     2.0, 3.3, 0.55, 0.90),
    (+1, -40.0, -28.0, 6.5, 10.0, (0.64, 0.74, 0.82), (0.95, 0.95, 0.95), (0.09, 0.11, 0.14),
     2.5, 3.3, 0.70, 0.85),
    (+1, -26.5, -12.0, 6.5, 17.0, (0.86, 0.85, 0.82), (0.30, 0.32, 0.36), (0.07, 0.09, 0.12),
     2.3, 3.1, 0.65, 1.00),
    (+1, -10.5, -2.0, 8.5, 12.0, (0.80, 0.58, 0.30), (0.93, 0.90, 0.82), (0.10, 0.10, 0.12),
     2.8, 3.2, 0.60, 0.90),
    (+1, 0.0, 14.0, 6.5, 20.0, (0.42, 0.45, 0.50), (0.70, 0.72, 0.75), (0.12, 0.16, 0.22),
     1.6, 3.5, 0.72, 1.30),
    (+1, 16.0, 25.0, 7.0, 8.0, (0.82, 0.55, 0.52), (0.95, 0.93, 0.90), (0.10, 0.11, 0.13),
     2.6, 3.2, 0.60, 0.85),
)
GROUND_FLOOR = 3.6         # shop-front storey height (big windows)

# cars: (x centre, y centre, heading +1/-1 along x, paint rgb)
CARS = (
    (-17.0, 2.55, -1.0, (0.70, 0.08, 0.07)),
    (-8.0, 2.55, -1.0, (0.12, 0.22, 0.45)),
    (9.5, 2.55, -1.0, (0.85, 0.85, 0.83)),
    (35.0, -2.55, 1.0, (0.15, 0.16, 0.17)),
)
CAR_BODY = ((0.0, 0.0, 0.62), (2.15, 0.87, 0.33), 0.18)     # centre, half size, rounding (car frame)
CAR_CABIN = ((-0.25, 0.0, 1.17), (1.25, 0.78, 0.30), 0.22)
CAR_WHEEL = (1.35, 0.33, 0.33, 0.90)                       # axle |x|, axle z, radius, half width

# street lamps: one row on the left sidewalk at x = first + spacing * k (k = 0..count-1), y = row y, arms
# reaching over the road (-y). Stout (0.22 m poles): thinner ones are finer than the teacher's 0.34 m ray
# step and would not converge at 256 steps. None on the right, where the lane-shifted trajectories run.
LAMP_ROW = (-20.0, 20.0, 3, 4.3)  # first x, spacing, count, y
LAMP_POLE = (0.22, 6.8)                                   # radius, top z
LAMP_ARM = ((0.0, 0.0, 6.6), (0.0, -2.0, 6.9), 0.20)      # from, to (y toward the road), radius
LAMP_HEAD = ((0.0, -2.3, 6.85), (0.30, 0.60, 0.25), 0.15)  # centre, half size, rounding

# trees: (x, y, trunk top z, crown centre z, crown radius)
TREES = (
    (-17.0, -5.7, 3.6, 4.9, 1.9),
    (-5.0, 6.2, 3.4, 4.7, 1.8),
    (30.0, 9.0, 3.8, 5.3, 2.3),
    (36.0, -9.5, 3.8, 5.2, 2.2),
)
TRUNK_R = 0.2

# bus shelter on the right sidewalk (y < 0), parts as boxes: (centre, half size, rounding)
SHELTER = (
    ((-3.0, -6.05, 1.35), (2.00, 0.16, 1.20), 0.05),   # back panel (glass)
    ((-3.0, -5.55, 2.55), (2.20, 0.70, 0.15), 0.08),   # roof
    ((-4.85, -5.85, 1.35), (0.15, 0.35, 1.20), 0.05),  # side panel
    ((-1.15, -5.85, 1.35), (0.15, 0.35, 1.20), 0.05),  # side panel
    ((-3.0, -5.65, 0.38), (1.30, 0.25, 0.23), 0.06),   # bench block
)

# cameras (the driving trajectory)
LANE_Y = -1.75             # right-hand lane centre when driving +x (right of +x is -y)
EYE_HEIGHT = 1.6
TRAJ_X = (-34.0, 27.0)
FOV_DEG = 70.0             # horizontal
YAW_WOBBLE_DEG = (2.5, 1.0)
PITCH_DEG = 1.5

# lighting and sky
SUN_AZ_DEG, SUN_EL_DEG = 40.0, 45.0
SUN_RGB = (1.00, 0.94, 0.82)
SKY_AMBIENT = (0.36, 0.42, 0.52)
GROUND_AMBIENT = (0.22, 0.21, 0.19)
HORIZON_RGB = (0.80, 0.86, 0.92)
ZENITH_RGB = (0.24, 0.45, 0.80)
GROUND_FAR_RGB = (0.43, 0.46, 0.41)
GROUND_NEAR_RGB = (0.22, 0.22, 0.21)
HILL_FAR_RGB = (0.56, 0.64, 0.74)
HILL_NEAR_RGB = (0.36, 0.46, 0.44)
CITY_RGB = (0.44, 0.49, 0.58)
SUN_RADIUS_DEG = 0.8
SKYLINE_AZ_DEG = (-28.0, 22.0)

STREET_INV_S = 24.0        # NeuS sharpness, 1/m (opacity ramp ~ 10 / inv_s = 0.4 m; converges at 256 steps)
STREET_BETA = 0.05         # VolSDF Laplace scale of the density variant, m

_MAT_TERRAIN, _MAT_BUILDING, _MAT_CAR, _MAT_LAMP, _MAT_TREE, _MAT_SHELTER = range(6)
_SUB = 64                  # material code = material * _SUB + sub index


# ---------------------------------------------------------------------------------------------- primitives
def _rbox(ax, ay, az, hx, hy, hz, r=0.0):
    """Rounded box SDF from |local coordinates| ax, ay, az (any broadcastable shapes), half sizes and rounding
    (the outer extent is the half size)."""
    qx, qy, qz = ax - (hx - r), ay - (hy - r), az - (hz - r)
    out = torch.sqrt(qx.clamp(min=0.0).square() + qy.clamp(min=0.0).square() + qz.clamp(min=0.0).square())
    return out + torch.maximum(torch.maximum(qx, qy), qz).clamp(max=0.0) - r


def _cyl(radial, axial, radius, half):
    """Capped cylinder SDF from the distance to the axis and |coordinate along the axis| (centred)."""
    qx, qy = radial - radius, axial - half
    return torch.hypot(qx.clamp(min=0.0), qy.clamp(min=0.0)) + torch.maximum(qx, qy).clamp(max=0.0)


def _lower_bound_mask(d: torch.Tensor, bound: torch.Tensor) -> torch.Tensor:
    """Indices (M,) of points whose lower bound is below the current distance (only they can change)."""
    return torch.nonzero(bound < d).squeeze(1)


def facade_albedo(ps, n, wall, frame, glass, win, x0, x1, yf, h, back_y):
    """Facade albedo (M, 3) with a window grid (frames, glass), ground-floor shop fronts and a roof, and the gloss
    weight (M,) (the glass), for box buildings whose street facades face ±y.

    Args: local surface points ps (M, 3) and normals n (M, 3); per point, the building's wall, frame and glass
    colours (M, 3), window grid (M, 4) (cell width, floor height, window half width, half height), x extent
    x0, x1 (M,), facade |y| yf (M,), height h (M,), and the |y| of its back wall back_y (M,) or a float."""
    px, py, pz = ps.unbind(-1)
    cw, fh, hw, hh = win.unbind(-1)
    front = n[:, 1].abs() >= n[:, 0].abs()
    # coordinate along the wall: x on street facades, |y| on the side walls
    u = torch.where(front, px - x0, py.abs() - yf)
    width = torch.where(front, x1 - x0, back_y - yf)
    ncol = torch.floor((width - 0.6) / cw).clamp(min=0.0)
    off = 0.5 * (width - ncol * cw)
    uu = (u - off) / cw
    col = torch.floor(uu)
    du = (uu - col - 0.5) * cw  # metres from the window centre
    in_cols = (col >= 0) & (col < ncol)
    # storeys: a shop front below GROUND_FLOOR, a grid of floors above, a parapet band on top
    zz = pz - CURB_H
    nrow = torch.floor((h - GROUND_FLOOR - 1.0) / fh).clamp(min=0.0)
    vv = (zz - GROUND_FLOOR) / fh
    row = torch.floor(vv)
    dv = (vv - row - 0.5) * fh
    upper = (row >= 0) & (row < nrow) & in_cols
    ground = zz < GROUND_FLOOR
    shop_dv = zz - 1.6
    hw_g, hh_g = (0.5 * cw - 0.15), torch.full_like(hh, 1.1)
    dvv = torch.where(ground, shop_dv, dv)
    hw2 = torch.where(ground, hw_g, hw)
    hh2 = torch.where(ground, hh_g, hh)
    box = torch.maximum(du.abs() - hw2, dvv.abs() - hh2)  # signed 2D distance to the window rectangle
    e = 0.025
    has_window = (upper | (ground & in_cols & front)).float()
    frame_m = smoothstep(e, -e, box) * has_window
    glass_m = smoothstep(e, -e, box + 0.09) * has_window
    c = wall * (0.93 + 0.07 * torch.sin(0.5 * pz + 0.3 * px)[:, None])
    band = smoothstep(-0.05, 0.05, zz - GROUND_FLOOR + 0.25) * \
        smoothstep(0.05, -0.05, zz - GROUND_FLOOR)  # cornice over the shop fronts
    c = c * (1.0 - 0.25 * band[:, None])
    parapet = smoothstep(h - 0.65, h - 0.55, pz)
    c = c * (1.0 - 0.2 * parapet[:, None])
    c = c + (frame - c) * frame_m[:, None]
    c = c + (glass - c) * glass_m[:, None]
    roof = smoothstep(0.6, 0.8, n[:, 2])[:, None]
    c = c + (torch.tensor([0.30, 0.29, 0.28]) - c) * roof
    return c, glass_m * (1.0 - roof[:, 0])


def shade_materials(code: torch.Tensor, sub_range: int, shaders: dict) -> tuple[torch.Tensor, torch.Tensor]:
    """Albedo (M, 3) and gloss (M,) of M surface points from their material codes (M,) long
    (``material * sub_range + sub index``): ``shaders`` maps a material to ``fn(sel, sub)`` of the points'
    indices (K,) and sub indices (K,), returning their albedo (K, 3) or (albedo, gloss (K,)); gloss defaults
    to 0."""
    alb = torch.empty(code.shape[0], 3)
    gloss = torch.zeros(code.shape[0])
    mat = torch.div(code, sub_range, rounding_mode="floor")
    sub = code - mat * sub_range
    for material, shade in shaders.items():
        sel = torch.nonzero(mat == material).squeeze(1)
        if sel.numel():
            out = shade(sel, sub[sel])
            if isinstance(out, tuple):
                alb[sel], gloss[sel] = out
            else:
                alb[sel] = out
    return alb, gloss


def car_albedo(paint: torch.Tensor, part: torch.Tensor, z: torch.Tensor):
    """Albedo (M, 3) and gloss (M,) of car surface points: paint (M, 3), part (M,) (0 body, 1 cabin, 2 wheels),
    height above the road z (M,): a window band round the cabin, rubber wheels."""
    is_window = ((part == 1) & (z > 1.02) & (z < 1.36)).float()[:, None]
    c = paint + (torch.tensor([0.06, 0.07, 0.09]) - paint) * is_window
    c = torch.where((part == 2)[:, None], torch.tensor([0.05, 0.05, 0.05]), c)
    return c, torch.where(part == 2, 0.0, 0.55 + 0.45 * is_window[:, 0])


# ---------------------------------------------------------------------------------------------- the field
class StreetField:
    """A street with buildings, cars, lamps and trees under a sky with hills (kind ``"sdf"``, metres, z up).

    Args:
        origin: (3,) where the scene's local origin sits in the world (everything is translated by it).
        inv_s: NeuS sharpness in 1/m.

    Members: ``kind``, ``aabb`` (2, 3) world, ``geometry(x)`` (N, 3) -> (N,) metres, ``radiance(x, d)``
    -> (N, 3), ``background(d)`` -> (N, 3), ``normal(x)`` (N, 3), ``material(x)`` (N,) int codes,
    ``inv_s``, ``unbounded = True``, ``origin`` (3,), ``sun_dir`` (3,), ``default_cameras(n, width, height)``,
    ``lane_shift_cameras(n, shift_m, width, height)``.
    """

    kind = "sdf"
    unbounded = True
    #: Sideways camera shifts (metres) the pipeline evaluates for extrapolation, as the paper does.
    lane_shifts = (-3.0, -2.0, 2.0, 3.0)
    #: the configuration preset that fits this scene to a laptop (configs/street.toml); the command line uses
    #: it when no --preset is given (a --config file then changes settings on top of it)
    preset = "street"

    def __init__(self, origin=(0.0, 0.0, 0.0), inv_s: float = STREET_INV_S):
        origin_t = torch.as_tensor(origin, dtype=torch.float32).reshape(-1)
        require(origin_t.numel() == 3 and bool(torch.isfinite(origin_t).all()),
                f"street origin must be 3 finite numbers, got {origin}")
        require(inv_s > 0 and math.isfinite(inv_s), f"inv_s must be positive and finite, got {inv_s}")
        self.origin = origin_t
        self.inv_s = float(inv_s)
        self.aabb = torch.tensor(AABB, dtype=torch.float32) + origin_t
        az, el = math.radians(SUN_AZ_DEG), math.radians(SUN_EL_DEG)
        self.sun_dir = torch.tensor([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        self._build_tables()

    def __repr__(self) -> str:
        return f"StreetField(origin={self.origin.tolist()}, aabb={self.aabb.tolist()}, inv_s={self.inv_s})"

    # ------------------------------------------------------------------ tables
    def _build_tables(self) -> None:
        # building boxes as scalars (cx, hx, cy, hy, cz, hz), y signed, indexed like BUILDINGS
        self._bparams = []
        for side, x0, x1, yf, h in (b[:5] for b in BUILDINGS):
            cy = side * 0.5 * (yf + BACK_Y)
            self._bparams.append((0.5 * (x0 + x1), 0.5 * (x1 - x0), cy, 0.5 * (BACK_Y - yf),
                                  0.5 * (h + BUILDING_BOTTOM), 0.5 * (h - BUILDING_BOTTOM)))
        self._object_list = self._objects()
        # building appearance, indexed like BUILDINGS
        self._bx0 = torch.tensor([b[1] for b in BUILDINGS])
        self._bx1 = torch.tensor([b[2] for b in BUILDINGS])
        self._byf = torch.tensor([b[3] for b in BUILDINGS])
        self._bh = torch.tensor([b[4] for b in BUILDINGS])
        self._bwall = torch.tensor([b[5] for b in BUILDINGS])
        self._bframe = torch.tensor([b[6] for b in BUILDINGS])
        self._bglass = torch.tensor([b[7] for b in BUILDINGS])
        self._bwin = torch.tensor([b[8:12] for b in BUILDINGS])              # cell w, floor h, half w, half h
        self._car_paint = torch.tensor([c[3] for c in CARS])
        # sun-shadow casters (local frame): buildings, car bodies, the shelter roof as boxes; tree crowns
        lo, hi = [], []
        for b in BUILDINGS:
            s, x0, x1, yf, h = b[:5]
            y0, y1 = (yf, BACK_Y) if s > 0 else (-BACK_Y, -yf)
            lo.append([x0, y0, BUILDING_BOTTOM])
            hi.append([x1, y1, h])
        for cx, cy, _, _ in CARS:
            lo.append([cx - 2.1, cy - 0.85, 0.15])
            hi.append([cx + 2.1, cy + 0.85, 1.0])
            lo.append([cx - 1.3, cy - 0.75, 1.0])
            hi.append([cx + 1.3, cy + 0.75, 1.42])
        (c, h, _) = SHELTER[1]
        lo.append([c[0] - h[0], c[1] - h[1], c[2] - h[2]])
        hi.append([c[0] + h[0], c[1] + h[1], c[2] + h[2]])
        # per caster, the ray parameters t = plane / l_a - p_a / l_a of the entering and leaving planes
        sun = self.sun_dir.tolist()
        require(min(abs(v) for v in sun) > 1e-6, "the sun direction needs non-zero x, y and z components")
        self._shadow_slabs = [
            (tuple((a if la > 0 else b) / la for a, b, la in zip(bl, bh, sun)),
             tuple((b if la > 0 else a) / la for a, b, la in zip(bl, bh, sun)))
            for bl, bh in zip(lo, hi)]

    # ------------------------------------------------------------------ geometry (local frame)
    def _local(self, x: torch.Tensor) -> torch.Tensor:
        """World points (N, 3) -> local points (N, 3) float32 (origin subtracted in float32)."""
        return x.float() - self.origin.to(x.device)

    @staticmethod
    def _terrain(ay: torch.Tensor, pz: torch.Tensor) -> torch.Tensor:
        """Road half-space z <= 0 united with the sidewalks (|y| >= 3.5, z <= 0.15, rounded curb), cut at
        the slab bottom. ay = |y| (N,), pz (N,) -> (N,)."""
        qy = (ROAD_HALF + CURB_R) - ay
        qz = pz - (CURB_H - CURB_R)
        walk = torch.hypot(qy.clamp(min=0.0), qz.clamp(min=0.0)) + torch.maximum(qy, qz).clamp(max=0.0)
        walk = walk - CURB_R
        return torch.maximum(torch.minimum(pz, walk), SLAB_BOTTOM - pz)

    def _buildings(self, px, py, pz, with_ids: bool):
        """Distance (N,) to the buildings (a fixed loop over the ten rounded boxes, scalar parameters) and,
        when ``with_ids``, the index (N,) into BUILDINGS of the nearest one (else None)."""
        d = ids = None
        r = BUILDING_ROUNDING
        differentiable = torch.is_grad_enabled() and px.requires_grad
        for i, (cx, hx, cy, hy, cz, hz) in enumerate(self._bparams):
            if differentiable:
                di = _rbox((px - cx).abs(), (py - cy).abs(), (pz - cz).abs(), hx, hy, hz, r)
            else:  # the same in place: a third faster
                qx = (px - cx).abs_().sub_(hx - r)
                qy = (py - cy).abs_().sub_(hy - r)
                qz = (pz - cz).abs_().sub_(hz - r)
                di = qx.clamp(min=0.0).square_().add_(qy.clamp(min=0.0).square_())
                di = di.add_(qz.clamp(min=0.0).square_()).sqrt_()
                di = di.add_(torch.maximum(torch.maximum(qx, qy), qz).clamp_(max=0.0)).sub_(r)
            if d is None:
                d = di
                ids = torch.zeros(px.shape, dtype=torch.long) if with_ids else None
            else:
                if with_ids:
                    ids = torch.where(di < d, i, ids)
                d = torch.minimum(d, di)
        return d, ids

    @staticmethod
    def _lamps(px, py, pz):
        """Street lamps by domain repetition along x: distance (M,) and part (M,) (0 pole, 1 arm, 2 head).
        Lamp frame: lx along the street, ly = y - row y (negative toward the road)."""
        first, spacing, count, row_y = LAMP_ROW
        kk = torch.round((px - first) / spacing).clamp(0.0, float(count - 1))
        lx = px - first - spacing * kk
        ly = py - row_y
        pole = _cyl(torch.hypot(lx, ly), (pz - 0.5 * LAMP_POLE[1]).abs(), LAMP_POLE[0], 0.5 * LAMP_POLE[1])
        (a, b, r) = LAMP_ARM
        ab = (b[1] - a[1], b[2] - a[2])
        ab2 = ab[0] ** 2 + ab[1] ** 2
        t = (((ly - a[1]) * ab[0] + (pz - a[2]) * ab[1]) / ab2).clamp(0.0, 1.0)
        arm = torch.sqrt(lx.square() + (ly - a[1] - t * ab[0]).square() + (pz - a[2] - t * ab[1]).square())
        arm = arm - r
        (c, h, rr) = LAMP_HEAD
        head = _rbox(lx.abs(), (ly - c[1]).abs(), (pz - c[2]).abs(), h[0], h[1], h[2], rr)
        d = torch.stack([pole, arm, head], dim=1)
        return d.min(dim=1)

    @staticmethod
    def _lamp_bound(px, py, pz):
        """Lower bound (N,) of the lamps' distance: the slab y - row y in [-3, 0.3], z <= 7.3, and the x
        range of the row widened by 3 m."""
        first, spacing, count, row_y = LAMP_ROW
        mid, half = first + 0.5 * spacing * (count - 1), 0.5 * spacing * (count - 1) + 3.0
        slab = torch.maximum((py - row_y + 1.35).abs() - 1.65, pz - 7.3)
        return torch.maximum(slab, (px - mid).abs() - half)

    @staticmethod
    def _car(i: int):
        """(bound, sdf) of car ``i``: sdf returns distance (M,) and sub code (M,) = car * 4 + part
        (0 body, 1 cabin, 2 wheels)."""
        cx, cy, heading, _ = CARS[i]
        (bc, bh, br), (cc, ch, cr) = CAR_BODY, CAR_CABIN
        ax, az, wr, ww = CAR_WHEEL

        def bound(px, py, pz):
            return torch.maximum(torch.maximum((px - cx).abs() - 2.2, (py - cy).abs() - 0.95), pz - 1.5)

        def sdf(px, py, pz):
            lx = (px - cx) * heading
            ly = (py - cy).abs()
            body = _rbox(lx.abs(), ly, (pz - bc[2]).abs(), bh[0], bh[1], bh[2], br)
            cabin = _rbox((lx - cc[0]).abs(), ly, (pz - cc[2]).abs(), ch[0], ch[1], ch[2], cr)
            wheel = _cyl(torch.hypot(lx.abs() - ax, pz - az), ly, wr, ww)
            d, part = torch.stack([body, cabin, wheel], dim=1).min(dim=1)
            return d, i * 4 + part

        return bound, sdf

    @staticmethod
    def _tree(i: int):
        """(bound, sdf) of tree ``i``: sdf returns distance (M,) and sub code (M,) = tree * 2 + part
        (0 trunk, 1 crown of two spheres)."""
        tx, ty, top, cz, r = TREES[i]
        reach = 1.5 * r

        def bound(px, py, pz):
            slab = torch.maximum((px - tx).abs() - reach, (py - ty).abs() - reach)
            return torch.maximum(slab, pz - (cz + 1.2 * r))

        def sdf(px, py, pz):
            dx, dy = px - tx, py - ty
            trunk = _cyl(torch.hypot(dx, dy), (pz - 0.5 * top).abs(), TRUNK_R, 0.5 * top)
            crown1 = torch.sqrt(dx.square() + dy.square() + (pz - cz).square()) - r
            crown2 = torch.sqrt((dx - 0.45 * r).square() + (dy + 0.3 * r).square()
                                + (pz - cz - 0.45 * r).square()) - 0.7 * r
            crown = torch.minimum(crown1, crown2)
            return torch.minimum(trunk, crown), i * 2 + (crown < trunk).long()

        return bound, sdf

    @staticmethod
    def _shelter_bound(px, py, pz):
        return torch.maximum(torch.maximum((px + 3.0).abs() - 2.25, (py + 5.55).abs() - 0.75), pz - 2.75)

    @staticmethod
    def _shelter(px, py, pz):
        """Distance (M,) to the bus shelter and its part (M,) (0 back glass, 1 roof, 2/3 sides, 4 bench)."""
        ds = [_rbox((px - c[0]).abs(), (py - c[1]).abs(), (pz - c[2]).abs(), h[0], h[1], h[2], r)
              for c, h, r in SHELTER]
        return torch.stack(ds, dim=1).min(dim=1)

    def __getstate__(self) -> dict:
        """Pickled without the objects' closures (``--nproc`` sends the field to worker processes); they are
        rebuilt from the scene tables on unpickling."""
        state = dict(self.__dict__)
        state.pop("_object_list", None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._object_list = self._objects()

    def _objects(self):
        """The small objects as (bound, sdf, material): bound (N,) is a lower bound of the object's SDF."""
        objs = [(self._lamp_bound, self._lamps, _MAT_LAMP),
                (self._shelter_bound, self._shelter, _MAT_SHELTER)]
        objs += [(*self._car(i), _MAT_CAR) for i in range(len(CARS))]
        objs += [(*self._tree(i), _MAT_TREE) for i in range(len(TREES))]
        return objs

    def _scene(self, p: torch.Tensor, with_ids: bool = False):
        """Local points (N, 3) -> distance (N,) [and material codes (N,) long when ``with_ids``].

        Terrain and buildings are evaluated everywhere; each small object only where its lower bound is
        below the running minimum (the only points where it can change the min)."""
        px, py, pz = p.T.contiguous().unbind(0)
        d = self._terrain(py.abs(), pz)
        db, bid = self._buildings(px, py, pz, with_ids)
        code = None
        if with_ids:
            code = torch.where(db < d, _MAT_BUILDING * _SUB + bid, torch.full_like(bid, _MAT_TERRAIN * _SUB))
        d = torch.minimum(d, db)
        for bound_fn, sdf_fn, mat in self._object_list:
            sel = _lower_bound_mask(d, bound_fn(px, py, pz))
            if sel.numel() == 0:
                continue
            ds, sub = sdf_fn(px[sel], py[sel], pz[sel])
            cur = d[sel]
            better = ds < cur
            d[sel] = torch.where(better, ds, cur)
            if with_ids:
                code[sel] = torch.where(better, mat * _SUB + sub, code[sel])
        return (d, code) if with_ids else d

    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        """World points x (N, 3) -> signed distance (N,) in metres, negative inside."""
        return self._scene(self._local(x))

    def exact_sdf(self, x: torch.Tensor) -> torch.Tensor:
        """Same as :meth:`geometry` (the analytic SDF; a bound inside the union, see the module doc)."""
        return self.geometry(x)

    def material(self, x: torch.Tensor) -> torch.Tensor:
        """World points (N, 3) -> material code (N,) long of the nearest part (material * 64 + sub index)."""
        return self._scene(self._local(x), with_ids=True)[1]

    _TETRA = torch.tensor([[1.0, -1.0, -1.0], [-1.0, -1.0, 1.0], [-1.0, 1.0, -1.0], [1.0, 1.0, 1.0]])

    def _normal_local(self, p: torch.Tensor, h: float = 0.01) -> torch.Tensor:
        """(N, 3) unit normals at local points from a 4-point tetrahedral difference of the SDF."""
        k = self._TETRA.to(p.device)   # a class constant: on the host until moved here
        f = self._scene((p[:, None, :] + h * k).reshape(-1, 3)).reshape(-1, 4, 1)
        return F.normalize((f * k).sum(1), dim=-1, eps=1e-12)

    def normal(self, x: torch.Tensor) -> torch.Tensor:
        """World points (N, 3) -> unit outward normals (N, 3)."""
        return self._normal_local(self._local(x))

    # ------------------------------------------------------------------ background
    def background(self, d: torch.Tensor) -> torch.Tensor:
        """Unit directions of travel (N, 3), world frame -> (N, 3) colour in [0, 1] arriving from infinity:
        sky gradient, sun disc and glow, two ranges of hills (1-6 degrees), a city skyline band ahead (+x),
        hazy ground below the horizon."""
        d = F.normalize(d.float(), dim=-1, eps=1e-12)
        dx, dy, dz = d.unbind(-1)
        el = torch.rad2deg(torch.asin(dz.clamp(-1.0, 1.0)))  # elevation, degrees
        az = torch.atan2(dy, dx)  # radians
        hor, zen = torch.tensor(HORIZON_RGB), torch.tensor(ZENITH_RGB)
        t = (1.0 - torch.exp(-el.clamp(min=0.0) / 18.0))[:, None]
        sky = hor + (zen - hor) * t
        # sun glow and disc
        cos_sun = (d * self.sun_dir).sum(-1).clamp(-1.0, 1.0)
        ang = torch.rad2deg(torch.acos(cos_sun))
        glow = (0.45 * torch.exp(-ang / 4.0) + 0.18 * torch.exp(-ang / 25.0))[:, None]
        sky = sky + glow * torch.tensor([1.0, 0.85, 0.6])
        disc = smoothstep(SUN_RADIUS_DEG + 0.25, SUN_RADIUS_DEG, ang)[:, None]
        sky = sky + (torch.tensor([1.0, 0.98, 0.92]) - sky).clamp(min=0.0) * disc
        # distant hills (elevation profile in degrees vs azimuth)
        far = (3.6 + 1.3 * torch.sin(2.0 * az + 0.4) + 0.8 * torch.sin(5.0 * az + 1.7)
               + 0.3 * torch.sin(13.0 * az + 0.2)).clamp(1.0, 6.0)
        near = (1.9 + 0.6 * torch.sin(3.0 * az + 2.1) + 0.4 * torch.sin(7.0 * az + 0.5)
                + 0.15 * torch.sin(19.0 * az + 1.0)).clamp(1.0, 3.5)
        hill_rgb = torch.tensor(HILL_FAR_RGB)
        hill_far = hill_rgb + (hor - hill_rgb) * (0.35 * (el / far).clamp(0, 1))[:, None]  # hazier higher up
        col = sky + (hill_far - sky) * smoothstep(0.06, -0.06, el - far)[:, None]
        # city skyline: blocks of hashed heights in an azimuth band ahead, in a dip of the near hills
        azd = torch.rad2deg(az)
        lo_az, hi_az = SKYLINE_AZ_DEG
        block = torch.floor(azd / 1.3)
        hsh = torch.frac(torch.sin(block * 12.9898 + 4.1) * 43758.5453).abs()
        centre = (block + 0.5) * 1.3
        taper = smoothstep(lo_az, lo_az + 10.0, centre) * smoothstep(hi_az, hi_az - 10.0, centre)
        city_h = (1.2 + 3.6 * hsh.square()) * (0.45 + 0.55 * taper) * (taper > 0.05).float()
        city = torch.tensor(CITY_RGB) * (0.88 + 0.12 * hsh)[:, None]
        city_m = smoothstep(0.04, -0.04, el - city_h)[:, None]
        col = col + (city - col) * city_m
        band = smoothstep(lo_az - 5.0, lo_az + 8.0, azd) * smoothstep(hi_az + 5.0, hi_az - 8.0, azd)
        near = near * (1.0 - 0.55 * band) + 0.3 * band
        near_col = torch.tensor(HILL_NEAR_RGB) * (0.9 + 0.1 * torch.sin(11.0 * az))[:, None]
        col = col + (near_col - col) * smoothstep(0.05, -0.05, el - near)[:, None]
        # below the horizon: hazy ground, darker looking down
        g_far, g_near = torch.tensor(GROUND_FAR_RGB), torch.tensor(GROUND_NEAR_RGB)
        gnd = g_far + (g_near - g_far) * smoothstep(0.0, -25.0, el)[:, None]
        col = col + (gnd - col) * smoothstep(0.15, -0.35, el)[:, None]
        return col.clamp(0.0, 1.0)

    # ------------------------------------------------------------------ appearance
    def _albedo(self, ps: torch.Tensor, n: torch.Tensor, code: torch.Tensor):
        """Albedo (M, 3) at surface points ps (local, (M, 3)) with normals n, and a gloss weight (M,)
        (1 on glass, ~0.6 on car paint, 0 elsewhere)."""
        px, py, pz = ps.unbind(-1)

        def car(sel, sub):
            return car_albedo(self._car_paint[torch.div(sub, 4, rounding_mode="floor")], sub % 4, pz[sel])

        def lamp(sel, sub):
            return torch.where((sub == 2)[:, None], torch.tensor([0.95, 0.93, 0.85]), torch.tensor([0.20, 0.24, 0.22]))

        def tree(sel, sub):
            q = ps[sel]
            v = torch.sin(2.1 * q[:, 0] + 1.3 * q[:, 2]) * torch.sin(1.7 * q[:, 1] - 2.3 * q[:, 2])
            v = 0.5 + 0.5 * v
            leaf = torch.tensor([0.16, 0.30, 0.10]) + torch.tensor([0.10, 0.12, 0.03]) * v[:, None]
            return torch.where((sub % 2 == 1)[:, None], leaf, torch.tensor([0.30, 0.21, 0.13]))

        def shelter(sel, sub):
            c = torch.tensor([[0.55, 0.66, 0.70], [0.30, 0.32, 0.34], [0.55, 0.66, 0.70], [0.55, 0.66, 0.70],
                              [0.52, 0.34, 0.18]])[sub]
            return c, torch.where((sub == 0) | (sub == 2) | (sub == 3), 0.6, 0.0)

        return shade_materials(code, _SUB, {
            _MAT_TERRAIN: lambda sel, sub: self._terrain_albedo(px[sel], py[sel], pz[sel]),
            _MAT_BUILDING: lambda sel, sub: self._building_albedo(ps[sel], n[sel], sub),
            _MAT_CAR: car, _MAT_LAMP: lamp, _MAT_TREE: tree, _MAT_SHELTER: shelter})

    @staticmethod
    def _terrain_albedo(px, py, pz):
        """Road (asphalt, lane markings, zebra crossing), curb, sidewalk paving and grass: (M, 3)."""
        ay = py.abs()
        stain = 0.5 + 0.5 * torch.sin(0.37 * px + 1.1 * torch.sin(0.9 * py)) * torch.sin(0.23 * px - 0.8 * py)
        asphalt = torch.tensor([0.25, 0.25, 0.26]) + 0.05 * stain[:, None]
        w = 0.03  # soft edge of painted lines (m)
        centre = smoothstep(0.075 + w, 0.075 - w, py.abs())
        dash = smoothstep(-w, w, 1.5 - (torch.remainder(px, 9.0) - 1.5).abs())
        edge = smoothstep(0.075 + w, 0.075 - w, (ay - 3.2).abs())
        zx = smoothstep(w, -w, (px + 3.0).abs() - 1.5)  # crossing at x in [-4.5, -1.5]
        stripes = smoothstep(0.25 + w, 0.25 - w, (torch.remainder(py + 0.5, 1.0) - 0.5).abs()) * \
            smoothstep(w, -w, ay - 3.0)
        paint = torch.maximum(torch.maximum(centre * dash * (1 - zx), edge * (1 - zx)), zx * stripes)
        road = asphalt + (torch.tensor([0.86, 0.86, 0.82]) - asphalt) * paint[:, None]
        # sidewalk: paving slabs 1.2 m with dark joints; curb stones
        jx = (torch.remainder(px, 1.2) - 0.6).abs()
        jy = (torch.remainder(ay - 3.75, 1.2) - 0.6).abs()
        joint = torch.maximum(smoothstep(0.56, 0.59, jx), smoothstep(0.56, 0.59, jy))
        walk = torch.tensor([0.62, 0.60, 0.56]) * (1.0 - 0.25 * joint)[:, None]
        curb = torch.tensor([0.70, 0.70, 0.68])
        grass = torch.tensor([0.24, 0.38, 0.14]) * (0.9 + 0.1 * stain)[:, None]
        on_walk = smoothstep(0.03, 0.1, pz)[:, None]  # raised part (sidewalk or curb face)
        is_curb = smoothstep(3.78, 3.72, ay)[:, None]
        open_ground = (((py > 0) & (px > 25.5)) | ((py < 0) & (px > 30.5))).float()
        is_grass = (smoothstep(6.6, 6.9, ay) * open_ground)[:, None]
        side = walk + (curb - walk) * is_curb
        side = side + (grass - side) * is_grass
        return road + (side - road) * on_walk

    def _building_albedo(self, ps, n, bid):
        """Facade albedo (M, 3) and gloss (M,) of the buildings ``bid`` (M,) (:func:`facade_albedo`)."""
        return facade_albedo(ps, n, self._bwall[bid], self._bframe[bid], self._bglass[bid], self._bwin[bid],
                             self._bx0[bid], self._bx1[bid], self._byf[bid], self._bh[bid], BACK_Y)

    def _sun_visibility(self, p: torch.Tensor) -> torch.Tensor:
        """(M,) in [0, 1]: 1 where the sun is visible from local points p (M, 3) (already offset from the
        surface). Soft shadows of boxes (chord length of the sun ray through the box) and tree crowns
        (chord through the sphere, partly transparent). A fixed loop over the casters, scalar parameters."""
        q = (p / self.sun_dir).T.contiguous()  # (3, M): p_a / l_a (the sun has no zero component)
        occ = torch.zeros(p.shape[0])
        for enter, leave in self._shadow_slabs:
            t_in = torch.maximum(torch.maximum(enter[0] - q[0], enter[1] - q[1]), enter[2] - q[2])
            t_in = t_in.clamp_(min=0.0)
            t_out = torch.minimum(torch.minimum(leave[0] - q[0], leave[1] - q[1]), leave[2] - q[2])
            occ = torch.maximum(occ, t_out.sub_(t_in))
        occ = smoothstep(0.0, 0.5, occ)
        sun = self.sun_dir.tolist()
        px, py, pz = p.T.unbind(0)
        for tx, ty, _, cz, r in TREES:
            ox, oy, oz = tx - px, ty - py, cz - pz
            tc = ox * sun[0] + oy * sun[1] + oz * sun[2]
            dist2 = ox.square() + oy.square() + oz.square() - tc.square()
            chord = (r * r - dist2).clamp_(min=0.0).sqrt_() * (tc > 0)
            occ = torch.maximum(occ, 0.8 * smoothstep(0.0, 1.2, chord))
        return 1.0 - occ

    @staticmethod
    def _surface_point(p, d, n, dist):
        """Where the texture is looked up for samples p (M, 3) near a surface: the point where the sample's
        ray (direction d) meets the locally planar surface (normal n, signed distance dist), so that all the
        samples of one ray see the same texel whatever the step count. The step along the ray,
        ``-dist * cos / (cos^2 + 0.02^2)`` with ``cos = n . d``, is regularised for grazing rays (which
        then fall back to the foot of the normal) and limited to 3 m; what is left of the distance is
        removed along the normal."""
        ndd = (n * d).sum(-1)
        along = (-dist * ndd / (ndd.square() + 0.02 ** 2)).clamp(-3.0, 3.0)
        rest = dist + ndd * along
        return p + d * along[:, None] - n * rest[:, None]

    def radiance(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """World points x (N, 3), unit directions of travel d (N, 3) -> colour (N, 3) in [0, 1].

        albedo x (sky/ground hemisphere light + sun diffuse x sun visibility) + gloss x (Fresnel sky
        reflection + sun highlight)."""
        p = self._local(x)
        d = F.normalize(d.float(), dim=-1, eps=1e-12)
        dist, code = self._scene(p, with_ids=True)
        n = self._normal_local(p)
        ps = self._surface_point(p, d, n, dist)
        alb, gloss = self._albedo(ps, n, code)
        sun = self.sun_dir
        ndl = (n * sun).sum(-1).clamp(min=0.0)
        vis = self._sun_visibility(ps + 0.15 * n)
        up = (0.5 + 0.5 * n[:, 2])[:, None]
        light = torch.tensor(SKY_AMBIENT) * up + torch.tensor(GROUND_AMBIENT) * (1.0 - up) + \
            torch.tensor(SUN_RGB) * (ndl * vis)[:, None]
        rgb = alb * light
        gsel = torch.nonzero(gloss > 0.01).squeeze(1)
        if gsel.numel():
            ng, dg = n[gsel], d[gsel]
            cos_i = (-(dg * ng).sum(-1)).clamp(0.0, 1.0)
            r = dg + 2.0 * cos_i[:, None] * ng
            fres = 0.06 + 0.94 * (1.0 - cos_i) ** 5
            env = self.background(r)
            hl = (r * sun).sum(-1).clamp(min=0.0) ** 300 * vis[gsel]
            spec = (0.5 * fres)[:, None] * env + 0.8 * hl[:, None]
            rgb[gsel] = rgb[gsel] + gloss[gsel][:, None] * spec
        return rgb.clamp(0.0, 1.0)

    # ------------------------------------------------------------------ cameras
    def default_cameras(self, n: int, width: int = 320, height: int = 180):
        """``n`` cameras driving along the right-hand lane (y = -1.75, 1.6 m above the road) from x = -34 to
        x = 27, looking forward (+x) with a smooth yaw wobble of a few degrees and a slight upward pitch;
        horizontal field of view 70 degrees (square pixels; 16:9 frames by default)."""
        from ..render.cameras import Cameras, look_at

        require(n >= 1, f"need at least one camera, got {n}")
        origin = self.origin.double()
        poses = []
        for i in range(n):
            u = i / max(n - 1, 1)
            x = TRAJ_X[0] + (TRAJ_X[1] - TRAJ_X[0]) * u
            yaw = math.radians(YAW_WOBBLE_DEG[0] * math.sin(2 * math.pi * 1.3 * u + 0.5)
                               + YAW_WOBBLE_DEG[1] * math.sin(2 * math.pi * 3.1 * u + 1.3))
            pitch = math.radians(PITCH_DEG + 0.6 * math.sin(2 * math.pi * 2.0 * u))
            fwd = torch.tensor([math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw),
                                math.sin(pitch)], dtype=torch.float64)
            eye = torch.tensor([x, LANE_Y, EYE_HEIGHT], dtype=torch.float64) + origin
            poses.append(look_at(eye, eye + fwd, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)))
        f = 0.5 * width / math.tan(0.5 * math.radians(FOV_DEG))
        return Cameras(torch.stack(poses).float(), f, f, width / 2.0, height / 2.0, width, height)

    def lane_shift_cameras(self, n: int, shift_m: float, width: int = 320, height: int = 180):
        """The default trajectory moved sideways by ``shift_m`` metres (positive: to the driver's right)."""
        return self.default_cameras(n, width, height).lane_shifted(shift_m)


def make_street(origin=(0.0, 0.0, 0.0)) -> StreetField:
    """The street scene (the ``SCENES["street"]`` factory)."""
    return StreetField(origin=origin)
