"""A field seen from a local frame: what every float32 stage of a run works in.

This module owns:

* :func:`box_centre`: the run's origin, the foreground box's centre in float64 world units;
* :func:`far_from_origin`: whether a box lies so far from the world origin that float32 world positions lose
  precision against its own size (its centre is farther from the origin than its diagonal is long);
* :class:`LocalFrameField`: the field with positions relative to that origin. Marching cubes, cleanup,
  decimation, culling, the unwrap, the G-buffers and the players all work on small float32 coordinates around
  the scene; only the field sees world positions, which this wrapper forms in float64
  (``local.double() + origin``).

Frames: ``x`` given to :class:`LocalFrameField` are local points (N, 3) (world minus ``origin``), any float
dtype; the wrapped field receives world points (N, 3): float64 when the box is far from the origin (a field that
computes in float64 keeps its precision there; one that casts to float32 rounds them as it would anyway), else
float32 as every near-origin run has always handed them. Directions are the same in both frames.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from .occupancy import OccupancyGrid

#: Members of the wrapped field that do not depend on the frame (directions, distances along rays, settings):
#: forwarded as they are. Positional members (``aabb``, ``occupancy_grid``) are translated; any other member
#: (``cameras``, ``default_cameras``, an analytic ``exact_sdf``) is not offered, so nothing positional leaks
#: through in world coordinates.
FRAME_FREE_MEMBERS = ("background", "background_color", "inv_s", "unbounded", "far_region", "surface_level",
                      "lane_shifts", "preset", "source_digest", "notes", "device")


def box_centre(aabb) -> np.ndarray:
    """(3,) float64 centre of the box ``aabb`` ((2, 3) world units)."""
    box = np.asarray(torch.as_tensor(aabb).detach().double().reshape(2, 3).cpu().numpy())
    return 0.5 * (box[0] + box[1])


def far_from_origin(aabb) -> bool:
    """True when the box's centre lies farther from the world origin than its diagonal is long: float32 world
    positions there are coarser, against the box's size, than anywhere around the origin (a 10-unit box 1e5 away:
    0.0078 apart, 1/1300 of the box)."""
    box = np.asarray(torch.as_tensor(aabb).detach().double().reshape(2, 3).cpu().numpy())
    return bool(np.linalg.norm(box_centre(aabb)) > np.linalg.norm(box[1] - box[0]))


def float64_positions(field: Any) -> bool:
    """Whether the wrapped field's answers change when its float64 inputs are not float32 numbers: it then
    computes positions in float64 (as the teacher of a georeferenced capture should); False when it rounds
    them to float32 or refuses float64 input. Probed on 64 points of its box."""
    box = torch.as_tensor(field.aabb).detach().double().reshape(2, 3).cpu()
    t = torch.linspace(0.0, 1.0, 64, dtype=torch.float64)[:, None]
    points = box[0] + t * (box[1] - box[0])
    rounded = points.float().double()
    nudged = rounded + 0.25 * (torch.nextafter(rounded.float(), torch.full_like(rounded.float(), np.inf)).double()
                               - rounded)                        # a quarter of a float32 step away
    try:
        with torch.no_grad():
            a = torch.as_tensor(field.geometry(rounded)).detach().double().cpu().reshape(-1)
            b = torch.as_tensor(field.geometry(nudged)).detach().double().cpu().reshape(-1)
    except (RuntimeError, TypeError):
        return False
    both = torch.isfinite(a) & torch.isfinite(b)
    return bool((a[both] != b[both]).any())


class LocalFrameField:
    """``field`` with positions relative to ``origin`` ((3,) float64 world units).

    Attributes: ``kind``, ``aabb`` ((2, 3) float32, local), ``origin``, ``field`` (the wrapped one),
    ``world_dtype`` (what the wrapped field receives: float64 when the box is far from the origin). Members:
    ``geometry(x)``, ``radiance(x, d)`` on local points, ``world(x)`` (local -> world), ``local(x)``,
    ``occupancy_grid(r)`` (the field's own grid moved into the frame, or None) and :data:`FRAME_FREE_MEMBERS`
    as the field's.
    """

    def __init__(self, field: Any, origin):
        self.field = field
        self.kind = field.kind
        self.origin = np.asarray(origin, dtype=np.float64).reshape(3)
        self._origin = torch.from_numpy(self.origin.copy())
        box = torch.as_tensor(field.aabb).detach().double().reshape(2, 3).cpu()
        self.aabb = (box - self._origin).float()
        self.world_dtype = torch.float64 if far_from_origin(box) else torch.float32

    def world(self, x: torch.Tensor) -> torch.Tensor:
        """Local points (N, 3) -> world points (N, 3) in ``world_dtype`` (the sum formed in float64)."""
        return (x.double() + self._origin.to(x.device)).to(self.world_dtype)

    def local(self, x: torch.Tensor) -> torch.Tensor:
        """World points (N, 3) -> local points (N, 3) float32 (the difference formed in float64)."""
        return (x.double() - self._origin.to(x.device)).float()

    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        """Local points (N, 3) -> the field's density or signed distance (N,) there."""
        return self.field.geometry(self.world(x))

    def radiance(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """Local points (N, 3), unit directions (N, 3) -> colour (N, 3)."""
        return self.field.radiance(self.world(x), d)

    def occupancy_grid(self, resolution: int):
        """The field's own occupancy grid with its box in the local frame, or None when it has none."""
        make = getattr(self.field, "occupancy_grid", None)
        grid = make(resolution) if callable(make) else None
        if grid is None:
            return None
        return OccupancyGrid(self.local(grid.aabb.reshape(2, 3).cpu()), grid.occupied)

    def __getattr__(self, name: str) -> Any:
        if name in FRAME_FREE_MEMBERS:
            return getattr(self.__dict__["field"], name)
        raise AttributeError(name)

    def __repr__(self) -> str:
        return f"LocalFrameField({self.field!r}, origin={self.origin.tolist()})"
