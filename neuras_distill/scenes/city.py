"""The embedded city: an analytic SDF field 1.2 km across (metres, z up), seen from a drive down its avenue.

This module owns :class:`CityField` (scene names ``"city"``, 12 blocks, 1.2 km, and ``"city-small"``, 6 blocks,
0.6 km: the same city cut shorter, for how run time and memory grow with the scene). Local frame (before
``origin`` is added): the avenue runs along +x.

* ground: a 0.6 m slab with its top at z = 0; a four-lane avenue (|y| < 10, dashed lane lines at |y| = 5, a
  double centre line, edge lines) crossed every 100 m by a side street (|x - 100 j| < 7, zebra crossings where
  it meets the avenue); raised pavements (top z = 0.15) on the blocks between;
* blocks: on each side of the avenue, between two side streets, three adjoining buildings (lots of 28.7 m),
  10 to 60 m tall, facades 14 to 18 m from the avenue's axis, each with its own wall colour and window grid
  (frames, dark glass that mirrors the sky, shop fronts; :func:`~neuras_distill.scenes.street.facade_albedo`);
* a park (the block between x = 100 and 200 on the +y side): grass and a grid of trees;
* vehicles (the street scene's car) parked in the outer right lane and driving the other way in the two
  left lanes, at hashed places, none in the camera's lane;
* distant hills, a skyline and the sky at infinity: the street's :meth:`StreetField.background`.

Geometry is one SDF, evaluated by domain repetition: a point looks only at the three lots of its own block and
side, at the vehicle slot of its lane and the tree cell of the park, each object only where a cheap lower bound
says it can change the minimum (as in the street). That is exact wherever the nearest building stands on the
point's own block (always within 7 m of one, half a side street); elsewhere it is an upper bound of the true
distance, where the opacity is zero either way. No part is thinner than ~0.6 m, the
teacher's ray step at 2048 steps across the 1.2 km diagonal (``configs/city.toml``). ``inv_s`` = 40 /m: at 14
(the street's product of step and sharpness) the cars near the camera rendered as a translucent smear; at 40 they
are crisp, the frames render faster (rays stop sooner), and 2048 and 4096 steps agree to 32 dB (a 320x180 view).
Hashed numbers (heights, colours, which slots hold a car) come
from the block, lot and slot indices, so the city is the same on every run and every device.

Radiance: as in the street (albedo x hemisphere and sun light, Fresnel sky reflection on glass and paint), but
sun shadows are traced through the SDF (24 sphere-tracing steps toward the sun, out to 150 m, soft), since the
city has too many casters for the street's loop over boxes.
"""

from __future__ import annotations

import math

import torch

from ..errors import require
from .analytic import smoothstep
from .street import (
    CAR_BODY,
    CAR_CABIN,
    CAR_WHEEL,
    CURB_H,
    EYE_HEIGHT,
    FOV_DEG,
    PITCH_DEG,
    SLAB_BOTTOM,
    StreetField,
    _cyl,
    _lower_bound_mask,
    _rbox,
    car_albedo,
    facade_albedo,
    shade_materials,
)

BLOCK = 100.0              # side streets at x = 100 j
CROSS_HALF = 7.0           # side-street road |x - 100 j| < 7
AVENUE_HALF = 10.0         # avenue road |y| < 10
LOTS = 3                   # buildings per block and side
LOT_START = CROSS_HALF     # lots fill x in [100 k + 7, 100 k + 93]
LOT = (BLOCK - 2 * CROSS_HALF) / LOTS
BACK_Y = 85.0              # buildings reach back to |y| = 85 (past the aabb)
FACADE_Y = (14.0, 18.0)    # facade |y| range
HEIGHT = (10.0, 60.0)      # building heights, m
BUILDING_BOTTOM = -0.5
BUILDING_ROUNDING = 0.15
HALF_Y = 70.0              # aabb |y|
TOP_Z = 66.0               # aabb top
PARK = (1, +1)             # (block index k, side): the block x in [100, 200] on the +y side is a park
TREE_PITCH = 12.0          # park trees on a 12 m grid
TREE = (0.35, 5.0, 6.6, 3.2)   # trunk radius, trunk top z, crown centre z, crown radius
# vehicle lanes: (y centre, heading, slot pitch m, probability a slot holds a car)
LANES = ((-7.5, 1.0, 11.0, 0.55), (2.5, -1.0, 23.0, 0.45), (7.5, -1.0, 19.0, 0.45))
CAMERA_LANE_Y = -2.5       # the inner right lane (driving +x)
TRAJ_MARGIN = 40.0         # the drive starts and ends this far inside the aabb's x faces
CITY_INV_S = 40.0          # NeuS sharpness, 1/m
CITY_BETA = 0.08           # VolSDF Laplace scale of the density variant, m
SHADOW_STEPS, SHADOW_FAR = 24, 150.0

# wall, frame, glass colours and window grids (cell width, floor height, half width, half height) to pick from
WALLS = ((0.62, 0.33, 0.26), (0.80, 0.72, 0.58), (0.55, 0.62, 0.70), (0.88, 0.82, 0.62), (0.52, 0.58, 0.42),
         (0.64, 0.74, 0.82), (0.86, 0.85, 0.82), (0.80, 0.58, 0.30), (0.42, 0.45, 0.50), (0.82, 0.55, 0.52))
FRAMES = ((0.90, 0.88, 0.84), (0.35, 0.30, 0.26), (0.92, 0.92, 0.92), (0.55, 0.42, 0.30), (0.70, 0.72, 0.75))
GLASS = ((0.10, 0.12, 0.15), (0.08, 0.10, 0.14), (0.12, 0.16, 0.22), (0.09, 0.11, 0.12))
WINDOWS = ((2.6, 3.2, 0.60, 0.85), (2.2, 3.0, 0.55, 0.95), (3.0, 3.4, 0.95, 0.80), (1.6, 3.5, 0.72, 1.30),
           (2.4, 3.1, 0.50, 0.90))
PAINTS = ((0.70, 0.08, 0.07), (0.12, 0.22, 0.45), (0.85, 0.85, 0.83), (0.15, 0.16, 0.17), (0.55, 0.57, 0.60),
          (0.80, 0.62, 0.10))

_MAT_TERRAIN, _MAT_BUILDING, _MAT_CAR, _MAT_TREE = range(4)
_SUB = 1 << 20             # material code = material * _SUB + sub index (building: lot id; car: slot id)
_FAR = 1e4                 # distance of an empty lot or slot


def _hash(*ints: torch.Tensor, salt: float = 0.0) -> torch.Tensor:
    """A number in [0, 1) from integer-valued float tensors (block, lot, side, ...): the same on every device."""
    v = salt + sum(float(k + 1) * 12.9898 * (i.double() + 0.37 * k) for k, i in enumerate(ints))
    return torch.frac(torch.sin(v) * 43758.5453).abs().float()


class CityField(StreetField):
    """A city of ``blocks`` blocks along an avenue (kind ``"sdf"``, metres, z up); see the module doc.

    Args:
        blocks: blocks along the avenue (even; 12: 1.2 km); origin: (3,) world position of the local origin;
        inv_s: NeuS sharpness in 1/m.

    Members as :class:`StreetField` (``geometry``, ``radiance``, ``background``, ``normal``, ``material``,
    ``default_cameras``, ``lane_shift_cameras``, ``aabb``, ``inv_s``, ``unbounded``, ``origin``, ``sun_dir``).
    """

    preset = "city"

    def __init__(self, blocks: int = 12, origin=(0.0, 0.0, 0.0), inv_s: float = CITY_INV_S):
        require(isinstance(blocks, int) and blocks >= 2 and blocks % 2 == 0,
                f"a city needs an even number of blocks >= 2, got {blocks!r}")
        super().__init__(origin=origin, inv_s=inv_s)
        self.blocks = blocks
        half_x = 0.5 * BLOCK * blocks
        self.half_x = half_x
        self.aabb = torch.tensor([[-half_x, -HALF_Y, -1.0], [half_x, HALF_Y, TOP_Z]]) + self.origin
        self._walls, self._frames = torch.tensor(WALLS), torch.tensor(FRAMES)
        self._glass, self._windows, self._paints = torch.tensor(GLASS), torch.tensor(WINDOWS), torch.tensor(PAINTS)

    def __repr__(self) -> str:
        return f"CityField(blocks={self.blocks}, origin={self.origin.tolist()}, inv_s={self.inv_s})"

    def _objects(self):
        """The street's object list is not used here (the city's objects are found by domain repetition)."""
        return []

    # ------------------------------------------------------------------ layout by index
    @staticmethod
    def _lot_box(k: torch.Tensor, lot: torch.Tensor, side: torch.Tensor):
        """Box of lot ``lot`` of block ``k`` on ``side`` (±1): x0, x1, facade |y|, height (each (N,)); a park
        lot has height 0 (no building)."""
        x0 = BLOCK * k + LOT_START + LOT * lot
        yf = FACADE_Y[0] + (FACADE_Y[1] - FACADE_Y[0]) * _hash(k, lot, side, salt=1.0)
        h = HEIGHT[0] + (HEIGHT[1] - HEIGHT[0]) * _hash(k, lot, side, salt=2.0).square()
        park = (k == PARK[0]) & (side == PARK[1])
        return x0, x0 + LOT, yf, torch.where(park, torch.zeros_like(h), h)

    def _block_of(self, px: torch.Tensor):
        """Block index k (N,) float of x (clamped to the city)."""
        return torch.floor(px / BLOCK).clamp(-self.blocks // 2, self.blocks // 2 - 1)

    # ------------------------------------------------------------------ geometry (local frame)
    def _terrain_city(self, px, py, pz):
        """Road (z <= 0) united with the raised pavements (|y| >= 10 and |x - 100 j| >= 7, z <= 0.15), cut at
        the slab bottom."""
        xl = px - BLOCK * torch.round(px / BLOCK)
        s_y = AVENUE_HALF - py.abs()        # > 0 on the avenue
        s_x = CROSS_HALF - xl.abs()         # > 0 on a side street
        d2 = torch.hypot(s_y.clamp(min=0.0), s_x.clamp(min=0.0)) + torch.maximum(s_y, s_x).clamp(max=0.0)
        qz = pz - CURB_H
        pave = torch.hypot(d2.clamp(min=0.0), qz.clamp(min=0.0)) + torch.maximum(d2, qz).clamp(max=0.0)
        return torch.maximum(torch.minimum(pz, pave), SLAB_BOTTOM - pz)

    def _buildings_city(self, px, py, pz):
        """Distance (N,) to the buildings of the point's block and side and the lot id (N,) long of the nearest
        (block, side, lot packed)."""
        k = self._block_of(px)
        side = torch.where(py >= 0, 1.0, -1.0)
        d = torch.full_like(px, _FAR)
        best = torch.zeros_like(px)
        ay = py.abs()
        r = BUILDING_ROUNDING
        for lot in range(LOTS):
            li = torch.full_like(px, float(lot))
            x0, x1, yf, h = self._lot_box(k, li, side)
            di = _rbox((px - 0.5 * (x0 + x1)).abs(), (ay - 0.5 * (yf + BACK_Y)).abs(),
                       (pz - 0.5 * (h + BUILDING_BOTTOM)).abs(), 0.5 * (x1 - x0), 0.5 * (BACK_Y - yf),
                       0.5 * (h - BUILDING_BOTTOM), r)
            di = torch.where(h > 0, di, torch.full_like(di, _FAR))
            best = torch.where(di < d, li, best)
            d = torch.minimum(d, di)
        ids = ((k + self.blocks // 2) * 2 + (side > 0).float()) * LOTS + best
        return d, ids.long()

    def _vehicles(self, px, py, pz, d, code):
        """Min of ``d`` (N,) with the cars of the lane slots the points lie in (in place), codes updated."""
        (bc, bh, br), (cc, ch, cr) = CAR_BODY, CAR_CABIN
        ax, az, wr, ww = CAR_WHEEL
        for lane, (ly0, heading, pitch, prob) in enumerate(LANES):
            bound = torch.maximum((py - ly0).abs() - 1.0, pz - 1.6)
            sel = _lower_bound_mask(d, bound)
            if sel.numel() == 0:
                continue
            x = px[sel]
            slot = torch.round(x / pitch)
            lane_t = torch.full_like(slot, float(lane))
            cx = slot * pitch + 0.25 * pitch * (_hash(slot, lane_t, salt=3.0) - 0.5)
            present = (_hash(slot, lane_t, salt=4.0) < prob) & ((cx.abs() + 3.0) < self.half_x)
            lx = (x - cx) * heading
            lyy = (py[sel] - ly0).abs()
            z = pz[sel]
            body = _rbox(lx.abs(), lyy, (z - bc[2]).abs(), bh[0], bh[1], bh[2], br)
            cabin = _rbox((lx - cc[0]).abs(), lyy, (z - cc[2]).abs(), ch[0], ch[1], ch[2], cr)
            wheel = _cyl(torch.hypot(lx.abs() - ax, z - az), lyy, wr, ww)
            dc, part = torch.stack([body, cabin, wheel], dim=1).min(dim=1)
            dc = torch.where(present, dc, torch.full_like(dc, _FAR))
            cur = d[sel]
            better = dc < cur
            d[sel] = torch.where(better, dc, cur)
            if code is not None:
                sub = ((slot.long() + 1000) * len(LANES) + lane) * 4 + part
                code[sel] = torch.where(better, _MAT_CAR * _SUB + sub, code[sel])

    def _trees(self, px, py, pz, d, code):
        """Min of ``d`` with the park's trees (a 12 m grid inside the park block), codes updated."""
        k0, side = PARK
        x_lo, x_hi = BLOCK * k0 + LOT_START + 3.0, BLOCK * (k0 + 1) - LOT_START - 3.0
        y_lo, y_hi = FACADE_Y[0] + 3.0, HALF_Y - 3.0
        trunk_r, top, cz, cr = TREE
        yy = py * side
        bound = torch.maximum(torch.maximum(x_lo - px, px - x_hi), torch.maximum(y_lo - yy, yy - y_hi))
        bound = torch.maximum(bound - cr - 1.0, pz - (cz + cr))   # centres jitter by up to 1 m
        sel = _lower_bound_mask(d, bound)
        if sel.numel() == 0:
            return
        x, y, z = px[sel], yy[sel], pz[sel]
        gx = torch.round((x - x_lo) / TREE_PITCH).clamp(0, math.floor((x_hi - x_lo) / TREE_PITCH))
        gy = torch.round((y - y_lo) / TREE_PITCH).clamp(0, math.floor((y_hi - y_lo) / TREE_PITCH))
        jx = x_lo + gx * TREE_PITCH + 2.0 * (_hash(gx, gy, salt=5.0) - 0.5)
        jy = y_lo + gy * TREE_PITCH + 2.0 * (_hash(gx, gy, salt=6.0) - 0.5)
        dx, dy = x - jx, y - jy
        trunk = _cyl(torch.hypot(dx, dy), (z - 0.5 * top).abs(), trunk_r, 0.5 * top)
        crown = torch.sqrt(dx.square() + dy.square() + (z - cz).square()) - cr
        dt = torch.minimum(trunk, crown)
        cur = d[sel]
        better = dt < cur
        d[sel] = torch.where(better, dt, cur)
        if code is not None:
            code[sel] = torch.where(better, _MAT_TREE * _SUB + (crown < trunk).long(), code[sel])

    def _scene(self, p: torch.Tensor, with_ids: bool = False):
        """Local points (N, 3) -> distance (N,) [and material codes (N,) long when ``with_ids``]."""
        px, py, pz = p.T.contiguous().unbind(0)
        d = self._terrain_city(px, py, pz)
        db, lot_id = self._buildings_city(px, py, pz)
        code = None
        if with_ids:
            code = torch.where(db < d, _MAT_BUILDING * _SUB + lot_id, torch.full_like(lot_id, _MAT_TERRAIN * _SUB))
        d = torch.minimum(d, db)
        self._vehicles(px, py, pz, d, code)
        self._trees(px, py, pz, d, code)
        return (d, code) if with_ids else d

    # ------------------------------------------------------------------ appearance
    def _albedo(self, ps: torch.Tensor, n: torch.Tensor, code: torch.Tensor):
        """Albedo (M, 3) and gloss (M,) at local surface points ps with normals n and material codes."""
        px, py, pz = ps.unbind(-1)

        def car(sel, sub):
            part, slot = sub % 4, torch.div(sub, 4, rounding_mode="floor")
            paint = self._paints[(_hash(slot.float(), salt=7.0) * len(PAINTS)).long().clamp(max=len(PAINTS) - 1)]
            return car_albedo(paint, part, pz[sel])

        def tree(sel, sub):
            q = ps[sel]
            v = 0.5 + 0.5 * torch.sin(1.3 * q[:, 0] + 0.9 * q[:, 2]) * torch.sin(1.1 * q[:, 1] - 1.7 * q[:, 2])
            leaf = torch.tensor([0.16, 0.30, 0.10]) + torch.tensor([0.10, 0.12, 0.03]) * v[:, None]
            return torch.where((sub == 1)[:, None], leaf, torch.tensor([0.30, 0.21, 0.13]))

        return shade_materials(code, _SUB, {
            _MAT_TERRAIN: lambda sel, sub: self._ground_albedo(px[sel], py[sel], pz[sel]),
            _MAT_BUILDING: lambda sel, sub: self._lot_albedo(ps[sel], n[sel], sub),
            _MAT_CAR: car, _MAT_TREE: tree})

    def _lot_albedo(self, ps, n, lot_id):
        """Facades of the lots ``lot_id`` (M,) (packed block, side, lot)."""
        lot = (lot_id % LOTS).float()
        bs = torch.div(lot_id, LOTS, rounding_mode="floor")
        side = torch.where(bs % 2 == 1, 1.0, -1.0)
        k = torch.div(bs, 2, rounding_mode="floor").float() - self.blocks // 2
        x0, x1, yf, h = self._lot_box(k, lot, side)

        def pick(table, salt):
            return table[(_hash(k, lot, side, salt=salt) * len(table)).long().clamp(max=len(table) - 1)]

        return facade_albedo(ps, n, pick(self._walls, 8.0), pick(self._frames, 9.0), pick(self._glass, 10.0),
                             pick(self._windows, 11.0), x0, x1, yf, h, BACK_Y)

    def _ground_albedo(self, px, py, pz):
        """Asphalt with lane lines and zebra crossings, pavements with slab joints, the park's grass: (M, 3)."""
        ay = py.abs()
        xl = px - BLOCK * torch.round(px / BLOCK)
        stain = 0.5 + 0.5 * torch.sin(0.37 * px + 1.1 * torch.sin(0.9 * py)) * torch.sin(0.23 * px - 0.8 * py)
        asphalt = torch.tensor([0.25, 0.25, 0.26]) + 0.05 * stain[:, None]
        w = 0.04
        on_avenue = (ay < AVENUE_HALF).float()
        lane = smoothstep(0.08 + w, 0.08 - w, (ay - 5.0).abs()) * \
            smoothstep(-w, w, 1.5 - (torch.remainder(px, 9.0) - 1.5).abs())
        centre = smoothstep(0.08 + w, 0.08 - w, (ay - 0.2).abs())
        edge = smoothstep(0.08 + w, 0.08 - w, (ay - 9.6).abs())
        crossing = smoothstep(w, -w, (xl.abs() - CROSS_HALF - 2.5).abs() - 1.5) * \
            smoothstep(0.25 + w, 0.25 - w, (torch.remainder(py + 0.5, 1.0) - 0.5).abs())
        paint = torch.maximum(torch.maximum(lane, centre), edge) * (xl.abs() > CROSS_HALF + 4.5).float()
        paint = torch.maximum(paint, crossing) * on_avenue
        road = asphalt + (torch.tensor([0.86, 0.86, 0.82]) - asphalt) * paint[:, None]
        jx = (torch.remainder(px, 1.5) - 0.75).abs()
        jy = (torch.remainder(ay, 1.5) - 0.75).abs()
        joint = torch.maximum(smoothstep(0.70, 0.74, jx), smoothstep(0.70, 0.74, jy))
        walk = torch.tensor([0.62, 0.60, 0.56]) * (1.0 - 0.25 * joint)[:, None]
        park = ((torch.floor(px / BLOCK) == PARK[0]) & (py * PARK[1] > FACADE_Y[0]))
        grass = torch.tensor([0.24, 0.38, 0.14]) * (0.9 + 0.1 * stain)[:, None]
        walk = torch.where(park[:, None], grass, walk)
        raised = smoothstep(0.03, 0.1, pz)[:, None]
        return road + (walk - road) * raised

    def _sun_visibility(self, p: torch.Tensor) -> torch.Tensor:
        """(M,) in [0, 1]: soft sun visibility from local points p (M, 3), traced through the SDF toward the
        sun (``SHADOW_STEPS`` sphere-tracing steps out to ``SHADOW_FAR`` m; penumbra k = 8)."""
        sun = self.sun_dir.to(p.device)
        t = torch.full((p.shape[0],), 0.3, device=p.device)
        vis = torch.ones(p.shape[0], device=p.device)
        for _ in range(SHADOW_STEPS):
            live = torch.nonzero((t < SHADOW_FAR) & (vis > 0.02)).squeeze(1)
            if live.numel() == 0:
                break
            dist = self._scene(p[live] + t[live, None] * sun)
            vis[live] = torch.minimum(vis[live], (8.0 * dist / t[live]).clamp(0.0, 1.0))
            t[live] = t[live] + dist.clamp(0.3, 20.0)
        return smoothstep(0.0, 1.0, vis)

    # ------------------------------------------------------------------ cameras
    def default_cameras(self, n: int, width: int = 320, height: int = 180):
        """``n`` cameras driving the inner right lane (y = -2.5, 1.6 m up) from 40 m inside one end of the city
        to 40 m inside the other, looking ahead (+x) with a slow yaw wobble of up to 12 degrees (toward the
        facades on both sides), a slight upward pitch, horizontal field of view 70 degrees."""
        from ..render.cameras import Cameras, look_at

        require(n >= 1, f"need at least one camera, got {n}")
        origin = self.origin.double()
        x0, x1 = -self.half_x + TRAJ_MARGIN, self.half_x - TRAJ_MARGIN
        poses = []
        for i in range(n):
            u = i / max(n - 1, 1)
            yaw = math.radians(12.0 * math.sin(2 * math.pi * 0.37 * i) + 2.0 * math.sin(2 * math.pi * 3.1 * u))
            pitch = math.radians(PITCH_DEG + 3.0 + 1.5 * math.sin(2 * math.pi * 0.23 * i))
            fwd = torch.tensor([math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw),
                                math.sin(pitch)], dtype=torch.float64)
            eye = torch.tensor([x0 + (x1 - x0) * u, CAMERA_LANE_Y, EYE_HEIGHT], dtype=torch.float64) + origin
            poses.append(look_at(eye, eye + fwd, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)))
        f = 0.5 * width / math.tan(0.5 * math.radians(FOV_DEG))
        return Cameras(torch.stack(poses).float(), f, f, width / 2.0, height / 2.0, width, height)


def make_city(origin=(0.0, 0.0, 0.0)) -> CityField:
    """The 1.2 km city (the ``SCENES["city"]`` factory)."""
    return CityField(blocks=12, origin=origin)


def make_small_city(origin=(0.0, 0.0, 0.0)) -> CityField:
    """The same city cut to 6 blocks, 0.6 km (``SCENES["city-small"]``)."""
    return CityField(blocks=6, origin=origin)
