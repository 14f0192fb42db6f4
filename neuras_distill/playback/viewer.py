"""Headless orbit viewer: renders a bundle into numbered PNG frames (this module owns ``render_orbit_frames``;
used by ``neuras-distill view --orbit``)."""

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


def render_orbit_frames(bundle, cameras=None, out_dir=None, *, frames: int = 36, width: int = 512,
                        height: int = 512, prefix: str = "frame", ctx=None) -> list[Path]:
    """Render ``bundle`` for every camera and write ``out_dir/{prefix}_NNNN.png`` (8-bit RGB, top row first).

    Two call forms: ``render_orbit_frames(bundle, cameras, out_dir)`` with explicit ``Cameras``, or
    ``render_orbit_frames(bundle, out_dir, frames=36, width=512, height=512)`` which orbits the bundle's mesh
    (:func:`orbit_cameras_for`). Creates ``out_dir``; returns the written paths in camera order.
    """
    from PIL import Image  # noqa: PLC0415 (lazy)

    if isinstance(cameras, (str, os.PathLike)) and out_dir is None:
        cameras, out_dir = None, cameras
    require(out_dir is not None, "render_orbit_frames needs an output folder")
    if cameras is None:
        cameras = orbit_cameras_for(bundle.mesh, frames, width, height)
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
