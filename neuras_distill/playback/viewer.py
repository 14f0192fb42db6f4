"""Where a player starts and the headless orbit viewer (this module owns ``render_orbit_frames``, used by
``neuras-distill view --orbit``, and :func:`start_cameras`, the cameras every player starts from)."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from ..errors import require
from .projection import mesh_bounds
from .renderer import BundleRenderer


def orbit_cameras_for(mesh, frames: int = 36, width: int = 512, height: int = 512, *, fov_deg: float = 40.0,
                      elevation_deg: float = 25.0, up_axis: int = 2):
    """``Cameras.orbit`` around the mesh's bounding-box centre, far enough that its bounding sphere fits the
    narrower field of view with a 10% margin. World up is +z by default (the synthetic scenes' convention)."""
    from ..render.cameras import Cameras  # noqa: PLC0415 (torch; lazy)

    require(frames >= 1, "an orbit needs at least one frame")
    require(width > 0 and height > 0, f"frame size must be positive, got {width}x{height}")
    b = mesh_bounds(mesh.vertices)
    centre = 0.5 * (b[0] + b[1])
    radius = max(0.5 * float(np.linalg.norm(b[1] - b[0])), 1e-6)
    half_fov = 0.5 * math.radians(fov_deg) * min(1.0, height / width)  # fov_deg is horizontal
    distance = 1.1 * radius / math.sin(half_fov)
    return Cameras.orbit(centre, distance, frames, width=width, height=height, fov_deg=fov_deg,
                         elevation_deg=elevation_deg, up_axis=up_axis)


def world_orbit_cameras(bundle, frames: int = 36, width: int = 512, height: int = 512):
    """:func:`orbit_cameras_for` the bundle's mesh, moved from the bundle's frame into the world frame (the
    bundle's ``origin`` added), the frame every player takes cameras in."""
    from ..render.cameras import Cameras  # noqa: PLC0415 (torch; lazy)

    cams = orbit_cameras_for(bundle.mesh, frames, width, height)
    c2w = cams.c2w.double().numpy()
    c2w[:, :3, 3] += np.asarray(getattr(bundle, "origin", np.zeros(3)), np.float64).reshape(3)
    return Cameras(c2w.astype(np.float32), cams.fx, cams.fy, cams.cx, cams.cy, cams.width, cams.height)


def start_cameras(bundle, bundle_path, *, width: int = 960, height: int = 720):
    """(Cameras, where they come from): the held-out ("test") cameras of the run's ``cameras.json`` beside the
    bundle (``<bundle_path>/../cameras.json``, for a bundle folder or a .glb alike), else one
    :func:`world_orbit_cameras` view of ``width`` x ``height``. BadInputError when that file is not a run's."""
    import json  # noqa: PLC0415

    from ..errors import BadInputError  # noqa: PLC0415
    from ..render.cameras import Cameras  # noqa: PLC0415 (torch; lazy)

    path = Path(bundle_path).resolve().parent / "cameras.json"
    if not path.is_file():
        return world_orbit_cameras(bundle, 1, width, height), "an orbit view (no cameras.json beside the bundle)"
    try:
        cams = Cameras.from_json(json.loads(path.read_text("utf-8"))["test"])
    except (ValueError, KeyError, TypeError, UnicodeDecodeError) as exc:
        raise BadInputError(f"{path} is not a cameras.json of a run ({exc.__class__.__name__}: {exc}); fix or "
                            "remove it") from None
    return cams, f"held-out camera of {path}"


def render_orbit_frames(bundle, cameras=None, out_dir=None, *, frames: int = 36, width: int = 512,
                        height: int = 512, prefix: str = "frame", ctx=None) -> list[Path]:
    """Render ``bundle`` for every camera and write ``out_dir/{prefix}_NNNN.png`` (8-bit RGB, top row first).

    Two call forms: ``render_orbit_frames(bundle, cameras, out_dir)`` with explicit ``Cameras``, or
    ``render_orbit_frames(bundle, out_dir, frames=36, width=512, height=512)`` which orbits the bundle's mesh
    (:func:`world_orbit_cameras`). Creates ``out_dir``; returns the written paths in camera order.
    """
    from PIL import Image  # noqa: PLC0415 (lazy)

    if isinstance(cameras, (str, os.PathLike)) and out_dir is None:
        cameras, out_dir = None, cameras
    require(out_dir is not None, "render_orbit_frames needs an output folder")
    if cameras is None:
        cameras = world_orbit_cameras(bundle, frames, width, height)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    digits = max(4, len(str(len(cameras) - 1)))
    paths = []
    with BundleRenderer(bundle, ctx=ctx) as renderer:
        for i in range(len(cameras)):
            img = renderer.render(cameras, i)
            path = out / f"{prefix}_{i:0{digits}d}.png"
            Image.fromarray(np.round(img * 255.0).astype(np.uint8), mode="RGB").save(path)
            paths.append(path)
    return paths
