"""Camera paths in nerfstudio's viewer format (``camera_path.json``), read, written and put in a bundle's frame.

The format is what nerfstudio's viewer exports and ``ns-render camera-path`` reads::

    {"camera_type": "perspective", "render_width": W, "render_height": H, "fps": 24, "seconds": 10,
     "camera_path": [{"camera_to_world": [16 numbers, row-major 4x4], "fov": 50.0, "aspect": 1.777}, ...],
     "keyframes": [...], "smoothness_value": 0.5, "is_cycle": false, "crop": null}

Each pose is camera-to-world with OpenGL's camera axes (x right, y up, looking down -z), as :class:`Cameras`;
``fov`` is the vertical field of view in degrees (focal length ``(H / 2) / tan(fov / 2)``, principal point at
the image centre); one pose is one frame. Only ``camera_path``, ``render_width`` and ``render_height`` are
required; ``fps`` defaults to 24 and the other keys are kept for nerfstudio but not read.

Frames: nerfstudio's viewer draws, and its paths are written in, the dataparser's frame ``x_ns = s (R x + t)``,
where ``x`` is the frame of the dataset's ``transforms.json``, which is the frame a nerfstudio run's field and
bundle are in here (``[R | t]`` and ``s`` from the run's ``dataparser_transforms.json``, recorded in the run's
report as ``field.viewer_frame``). :func:`to_dataset_frame` undoes that map; a path for a bundle of any other
field is in the field's own frame.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import BadInputError, require
from .cameras import Cameras

#: Frames per second of a path that does not say (nerfstudio's viewer default).
DEFAULT_FPS = 24.0


@dataclass(frozen=True)
class CameraPath:
    """A path's poses and image size, in the frame it was written in.

    Attributes:
        c2w: (N, 4, 4) float64 camera-to-world, OpenGL camera axes.
        fov_deg: (N,) float64 vertical field of view in degrees.
        width, height: the render size in pixels; fps: frames per second.
    """

    c2w: np.ndarray
    fov_deg: np.ndarray
    width: int
    height: int
    fps: float

    def cameras(self, c2w: np.ndarray | None = None) -> Cameras:
        """The path as :class:`Cameras` (``c2w``: (N, 4, 4) poses to use instead, e.g. after a frame change)."""
        poses = self.c2w if c2w is None else c2w
        focal = 0.5 * self.height / np.tan(np.radians(self.fov_deg) / 2.0)
        return Cameras(poses.astype(np.float32), focal, focal, 0.5 * self.width, 0.5 * self.height,
                       self.width, self.height)

    @property
    def seconds(self) -> float:
        return len(self.c2w) / self.fps


def read_camera_path(path: str | Path) -> CameraPath:
    """``camera_path.json`` -> :class:`CameraPath`; BadInputError naming the problem for a file that is not one."""
    p = Path(path)
    require(p.is_file(), f"--camera-path {p}: no such file")
    try:
        data = json.loads(p.read_text("utf-8"))
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise BadInputError(f"--camera-path {p} is not JSON ({exc.__class__.__name__}: {exc}); pass a "
                            "camera_path.json that nerfstudio's viewer exported") from None
    if isinstance(data, dict) and "frames" in data and "camera_path" not in data:
        raise BadInputError(f"--camera-path {p} is a transforms.json (a dataset's cameras), not a camera path; "
                            "export a path from nerfstudio's viewer (camera_path.json)")
    require(isinstance(data, dict) and isinstance(data.get("camera_path"), list) and data["camera_path"],
            f"--camera-path {p} has no \"camera_path\" list of poses: it is not nerfstudio's camera_path.json "
            "format; export the path from nerfstudio's viewer")
    kind = data.get("camera_type", "perspective")
    require(kind == "perspective", f"--camera-path {p}: camera_type {kind!r} is not supported (only "
                                   "\"perspective\"); choose a perspective camera in nerfstudio's viewer")
    width, height = _size(data, "render_width", p), _size(data, "render_height", p)
    fps = data.get("fps", DEFAULT_FPS)
    require(isinstance(fps, (int, float)) and not isinstance(fps, bool) and math.isfinite(fps) and 0 < fps <= 240,
            f"--camera-path {p}: fps must be a number in (0, 240], got {fps!r}")
    poses, fovs = [], []
    for i, cam in enumerate(data["camera_path"]):
        m = cam.get("camera_to_world") if isinstance(cam, dict) else None
        try:
            pose = np.asarray(m, dtype=np.float64)
        except (TypeError, ValueError):
            pose = np.zeros(0)
        require(pose.size == 16 and np.isfinite(pose).all(),
                f"--camera-path {p}: pose {i} needs \"camera_to_world\" as 16 finite numbers (a row-major 4x4)")
        fov = cam.get("fov")
        require(isinstance(fov, (int, float)) and not isinstance(fov, bool) and 0 < fov < 180,
                f"--camera-path {p}: pose {i} needs \"fov\", a vertical field of view in (0, 180) degrees, "
                f"got {fov!r}")
        poses.append(pose.reshape(4, 4))
        fovs.append(float(fov))
    c2w = np.stack(poses)
    c2w[:, 3] = (0.0, 0.0, 0.0, 1.0)
    out = CameraPath(c2w, np.asarray(fovs), width, height, float(fps))
    out.cameras()                       # checks the poses are rigid (Cameras.validate), with its message
    return out


def _size(data: dict, key: str, p: Path) -> int:
    v = data.get(key)
    require(isinstance(v, int) and not isinstance(v, bool) and 8 <= v <= 8192,
            f"--camera-path {p}: {key} must be a whole number of pixels in 8..8192, got {v!r}")
    return v


def to_dataset_frame(c2w: np.ndarray, viewer_frame: dict) -> np.ndarray:
    """Poses from nerfstudio's dataparser frame into the dataset's.

    Args:
        c2w: (N, 4, 4) camera-to-world in the dataparser's frame (``x_ns = s (R x + t)``).
        viewer_frame: ``{"transform": (3, 4) [R | t], "scale": s}`` (the report's ``field.viewer_frame``).
    Returns:
        (N, 4, 4) float64 camera-to-world in the dataset's frame: ``x = R^T (x_ns / s - t)``; the camera's axes
        turned by ``R^T`` (rigid: the scale moves positions only).
    """
    t = np.asarray(viewer_frame["transform"], np.float64).reshape(3, 4)
    scale = float(viewer_frame["scale"])
    rot, shift = t[:, :3], t[:, 3]
    out = np.array(c2w, np.float64, copy=True)
    out[:, :3, :3] = rot.T @ out[:, :3, :3]
    out[:, :3, 3] = (out[:, :3, 3] / scale - shift) @ rot
    return out


def from_dataset_frame(c2w: np.ndarray, viewer_frame: dict) -> np.ndarray:
    """The inverse of :func:`to_dataset_frame`: (N, 4, 4) dataset-frame poses into the dataparser's frame."""
    t = np.asarray(viewer_frame["transform"], np.float64).reshape(3, 4)
    scale = float(viewer_frame["scale"])
    rot, shift = t[:, :3], t[:, 3]
    out = np.array(c2w, np.float64, copy=True)
    out[:, :3, :3] = rot @ out[:, :3, :3]
    out[:, :3, 3] = scale * (out[:, :3, 3] @ rot.T + shift)
    return out


def camera_path_json(cameras: Cameras, fps: float = DEFAULT_FPS, c2w: np.ndarray | None = None) -> dict:
    """``cameras`` as nerfstudio's ``camera_path.json`` (one pose a frame; their vertical field of view from
    ``fy``, the principal point taken as the centre). ``c2w``: (N, 4, 4) poses to write instead (another frame)."""
    poses = cameras.c2w.double().numpy() if c2w is None else np.asarray(c2w, np.float64)
    fovs = np.degrees(2.0 * np.arctan(0.5 * cameras.height / cameras.fy.double().numpy()))
    frames = [{"camera_to_world": pose.reshape(-1).tolist(), "fov": float(fov),
               "aspect": cameras.width / cameras.height} for pose, fov in zip(poses, fovs)]
    return {"camera_type": "perspective", "render_width": cameras.width, "render_height": cameras.height,
            "camera_path": frames, "fps": float(fps), "seconds": len(frames) / float(fps),
            "smoothness_value": 0.0, "is_cycle": False, "crop": None, "keyframes": []}
