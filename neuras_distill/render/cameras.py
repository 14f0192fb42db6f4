"""Pinhole cameras in the OpenGL/Blender/NeRF convention, and the rays through their pixel centres.

Frames and conventions (shared by the volume renderer, the G-buffer rasterizer and playback):

* ``c2w`` (N, 4, 4) maps camera coordinates to world coordinates. Camera axes: x right, y up, looking down -z.
* Pixel (u, v): column u to the right, row v downwards (row 0 is the top of the image, as in every image
  file). The ray of pixel (u, v) passes through the pixel centre (u + 0.5, v + 0.5):
  ``x_cam = (u + 0.5 - cx) / fx``, ``y_cam = -(v + 0.5 - cy) / fy``, ``z_cam = -1``.
* Images are (H, W, 3) arrays, row-major, top row first.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..errors import BadInputError, require


def _as_per_camera(value, n: int, name: str) -> torch.Tensor:
    t = torch.as_tensor(value, dtype=torch.float32).reshape(-1)
    if t.numel() == 1:
        t = t.expand(n).clone()
    require(t.numel() == n, f"camera {name} has {t.numel()} values for {n} cameras; give one or one per camera")
    return t


@dataclass
class Cameras:
    """N pinhole cameras sharing one image size.

    Attributes:
        c2w: (N, 4, 4) float32 camera-to-world, OpenGL convention (x right, y up, -z forward).
        fx, fy, cx, cy: (N,) float32 intrinsics in pixels.
        width, height: image size in pixels.
    """

    c2w: torch.Tensor
    fx: torch.Tensor
    fy: torch.Tensor
    cx: torch.Tensor
    cy: torch.Tensor
    width: int
    height: int

    def __post_init__(self) -> None:
        c2w = torch.as_tensor(self.c2w, dtype=torch.float32)
        if c2w.ndim == 2:
            c2w = c2w[None]
        require(c2w.ndim == 3 and c2w.shape[0] > 0, "no cameras given: need at least one camera pose")
        if c2w.shape[1:] == (3, 4):
            bottom = torch.tensor([0.0, 0.0, 0.0, 1.0]).expand(c2w.shape[0], 1, 4)
            c2w = torch.cat([c2w, bottom], dim=1)
        require(c2w.shape[1:] == (4, 4), f"camera poses must be (N, 4, 4) or (N, 3, 4), got {tuple(c2w.shape)}")
        n = c2w.shape[0]
        self.c2w = c2w.contiguous()
        self.fx = _as_per_camera(self.fx, n, "fx")
        self.fy = _as_per_camera(self.fy, n, "fy")
        self.cx = _as_per_camera(self.cx, n, "cx")
        self.cy = _as_per_camera(self.cy, n, "cy")
        self.width, self.height = int(self.width), int(self.height)
        self.validate()

    # ------------------------------------------------------------------ checks
    def validate(self) -> None:
        """Raise :class:`BadInputError` for poses or intrinsics no renderer can use."""
        require(self.width > 0 and self.height > 0, f"image size must be positive, got {self.width}x{self.height}")
        require(self.width <= 16384 and self.height <= 16384,
                f"image size {self.width}x{self.height} is too large (at most 16384 per side)")
        for name in ("fx", "fy", "cx", "cy"):
            v = getattr(self, name)
            require(bool(torch.isfinite(v).all()), f"camera {name} contains NaN or Inf; fix the camera file")
        require(bool((self.fx > 0).all() and (self.fy > 0).all()),
                "focal length must be positive (got zero or negative fx/fy); check camera_angle_x or fl_x/fl_y")
        require(bool(torch.isfinite(self.c2w).all()),
                "a camera pose contains NaN or Inf; fix or drop that frame in the camera file")
        rot = self.c2w[:, :3, :3].double()
        eye = torch.eye(3, dtype=torch.float64)
        ortho_err = (rot.transpose(1, 2) @ rot - eye).abs().amax(dim=(1, 2))
        bad = torch.nonzero(ortho_err > 1e-3).flatten()
        require(bad.numel() == 0,
                f"camera pose {int(bad[0]) if bad.numel() else 0} is not rigid (rotation part is not orthonormal, "
                f"error {float(ortho_err.max()):.3g}); poses must be rotation + translation without scale or shear")
        det = torch.linalg.det(rot)
        bad = torch.nonzero(det < 0).flatten()
        require(bad.numel() == 0, f"camera pose {int(bad[0]) if bad.numel() else 0} is a reflection (det < 0)")
        bottom_ok = torch.allclose(self.c2w[:, 3, :], torch.tensor([0.0, 0.0, 0.0, 1.0]).expand(len(self), 4),
                                   atol=1e-5)
        require(bottom_ok, "camera poses must have [0, 0, 0, 1] as their last row")

    # ------------------------------------------------------------------ basics
    def __len__(self) -> int:
        return int(self.c2w.shape[0])

    def __getitem__(self, index) -> "Cameras":
        if isinstance(index, int):
            index = [index]
        return Cameras(self.c2w[index], self.fx[index], self.fy[index], self.cx[index], self.cy[index],
                       self.width, self.height)

    def __repr__(self) -> str:
        return (f"Cameras(n={len(self)}, {self.width}x{self.height}, fx~{float(self.fx.mean()):.1f}, "
                f"c2w={tuple(self.c2w.shape)} {self.c2w.dtype})")

    @property
    def centers(self) -> torch.Tensor:
        """(N, 3) camera positions in world space."""
        return self.c2w[:, :3, 3]

    def resized(self, width: int, height: int | None = None) -> "Cameras":
        """Same poses and fields of view at another image size (intrinsics scaled per axis)."""
        if height is None:
            height = max(1, round(self.height * width / self.width))
        sx, sy = width / self.width, height / self.height
        return Cameras(self.c2w, self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, width, height)

    def joined(self, other: "Cameras | None") -> "Cameras":
        """These cameras followed by ``other``'s (same image size; None: these alone)."""
        if other is None:
            return self
        require((other.width, other.height) == (self.width, self.height),
                f"cannot join cameras of {other.width}x{other.height} to {self.width}x{self.height}")
        return Cameras(torch.cat([self.c2w, other.c2w]), torch.cat([self.fx, other.fx]),
                       torch.cat([self.fy, other.fy]), torch.cat([self.cx, other.cx]), torch.cat([self.cy, other.cy]),
                       self.width, self.height)

    def lane_shifted(self, metres: float) -> "Cameras":
        """Every camera moved by ``metres`` along its own right axis projected onto the horizontal plane
        (world z up) and renormalised; positive moves to the camera's right. Orientation and intrinsics are
        unchanged (a lane change for driving cameras)."""
        require(math.isfinite(float(metres)), f"lane shift must be finite, got {metres}")
        right = self.c2w[:, :3, 0].double().clone()
        right[:, 2] = 0.0
        norm = right.norm(dim=-1, keepdim=True)
        bad = torch.nonzero(norm[:, 0] < 1e-6).flatten()
        require(bad.numel() == 0, f"camera {int(bad[0]) if bad.numel() else 0} has a vertical right axis "
                                  "(rolled by 90 degrees): no horizontal direction to shift it along")
        c2w = self.c2w.double().clone()
        c2w[:, :3, 3] += float(metres) * right / norm
        return Cameras(c2w.float(), self.fx, self.fy, self.cx, self.cy, self.width, self.height)

    def split(self, test_every: int = 8) -> tuple["Cameras", "Cameras"]:
        """(train, held_out): every ``test_every``-th camera (starting at index test_every // 2) is held out."""
        n = len(self)
        require(n >= 2, f"need at least 2 cameras to hold some out for evaluation, got {n}")
        test_every = max(2, int(test_every))
        test = [i for i in range(n) if i % test_every == test_every // 2]
        if not test:
            test = [n // 2]
        train = [i for i in range(n) if i not in test]
        return self[train], self[test]

    # ------------------------------------------------------------------ rays
    def pixel_directions_cam(self, index: int) -> torch.Tensor:
        """(H, W, 3) un-normalised ray directions in camera space through pixel centres (z = -1)."""
        v, u = torch.meshgrid(torch.arange(self.height, dtype=torch.float32),
                              torch.arange(self.width, dtype=torch.float32), indexing="ij")
        x = (u + 0.5 - self.cx[index]) / self.fx[index]
        y = -(v + 0.5 - self.cy[index]) / self.fy[index]
        return torch.stack([x, y, -torch.ones_like(x)], dim=-1)

    def rays(self, index: int) -> tuple[torch.Tensor, torch.Tensor]:
        """World-space rays of camera ``index``: origins (H, W, 3) and unit directions of travel (H, W, 3)."""
        d_cam = self.pixel_directions_cam(index)
        rot = self.c2w[index, :3, :3]
        d = d_cam @ rot.T
        d = d / d.norm(dim=-1, keepdim=True)
        o = self.c2w[index, :3, 3].expand_as(d)
        return o.contiguous(), d.contiguous()

    def view_matrix(self, index: int) -> np.ndarray:
        """(4, 4) float64 world-to-camera matrix of camera ``index``."""
        return np.linalg.inv(self.c2w[index].double().numpy())

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_transforms(cls, path: str | Path, *, warn=None) -> "Cameras":
        """Read a NeRF / Instant-NGP ``transforms.json``.

        Supports ``camera_angle_x``/``camera_angle_y`` or ``fl_x``/``fl_y``, ``cx``/``cy``, ``w``/``h``, and
        per-frame overrides of any of these. Lens distortion (k1, k2, p1, p2, ...) is reported and ignored.
        All frames must share one image size. Poses are used as they are (no ngp rescaling).
        """
        if warn is None:                 # ``warn``: a (line) callable for what is ignored; default the package's logger
            from ..logs import LOGGER

            warn = LOGGER.warning
        path = Path(path)
        require(path.exists(), f"camera file {path} does not exist")
        require(path.is_file(), f"camera file {path} is a directory; give the transforms.json inside it")
        try:
            meta = json.loads(path.read_text())
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise BadInputError(f"camera file {path} is not valid JSON ({exc}); give a NeRF transforms.json") from None
        require(isinstance(meta, dict) and isinstance(meta.get("frames"), list),
                f"camera file {path} has no 'frames' list; it does not look like a NeRF transforms.json")
        frames = meta["frames"]
        require(len(frames) > 0, f"camera file {path} has an empty 'frames' list: no cameras")
        distortion = sorted({k for k in ("k1", "k2", "k3", "k4", "p1", "p2")
                             for src in [meta, *frames] if abs(float(src.get(k, 0.0) or 0.0)) > 0})
        if distortion:
            warn(f"note: {path.name} has lens distortion ({', '.join(distortion)}); it is ignored (pinhole model)")

        def get(frame: dict, key: str):
            return frame.get(key, meta.get(key))

        c2ws, fxs, fys, cxs, cys, sizes = [], [], [], [], [], set()
        for i, frame in enumerate(frames):
            require(isinstance(frame, dict) and "transform_matrix" in frame,
                    f"frame {i} of {path} has no transform_matrix")
            try:
                m = np.asarray(frame["transform_matrix"], dtype=np.float64)
            except (TypeError, ValueError):
                raise BadInputError(f"frame {i} of {path}: transform_matrix is not a 4x4 matrix of numbers") from None
            require(m.shape in ((4, 4), (3, 4)), f"frame {i} of {path}: transform_matrix has shape {m.shape}, not 4x4")
            w, h = get(frame, "w"), get(frame, "h")
            require(w is not None and h is not None,
                    f"frame {i} of {path}: image size unknown; add 'w' and 'h' to the file")
            w, h = int(round(float(w))), int(round(float(h)))
            sizes.add((w, h))
            fl_x, fl_y = get(frame, "fl_x"), get(frame, "fl_y")
            if fl_x is None and get(frame, "camera_angle_x") is not None:
                fl_x = 0.5 * w / math.tan(0.5 * float(get(frame, "camera_angle_x")))
            if fl_y is None and get(frame, "camera_angle_y") is not None:
                fl_y = 0.5 * h / math.tan(0.5 * float(get(frame, "camera_angle_y")))
            require(fl_x is not None or fl_y is not None,
                    f"frame {i} of {path}: no focal length (need fl_x/fl_y or camera_angle_x)")
            fl_x = float(fl_x if fl_x is not None else fl_y)
            fl_y = float(fl_y if fl_y is not None else fl_x)
            cx = get(frame, "cx")
            cy = get(frame, "cy")
            c2ws.append(m)
            fxs.append(fl_x)
            fys.append(fl_y)
            cxs.append(float(cx) if cx is not None else w / 2.0)
            cys.append(float(cy) if cy is not None else h / 2.0)
        require(len(sizes) == 1, f"{path}: frames have different image sizes {sorted(sizes)}; one size is supported")
        (w, h), = sizes
        c2w = torch.as_tensor(np.stack([_to4x4(m) for m in c2ws]), dtype=torch.float32)
        return cls(c2w, fxs, fys, cxs, cys, w, h)

    @classmethod
    def orbit(cls, center, radius: float, n: int, *, width: int = 512, height: int = 512,
              fov_deg: float = 40.0, elevation_deg: float | tuple[float, float] = 25.0,
              up_axis: int = 2, phase_deg: float = 0.0) -> "Cameras":
        """``n`` cameras on a circle (or a helix when ``elevation_deg`` is a (low, high) range) looking at
        ``center``. World up is +z by default (``up_axis``)."""
        require(n > 0, "an orbit needs at least one camera")
        require(radius > 0 and math.isfinite(radius), f"orbit radius must be positive and finite, got {radius}")
        center = torch.as_tensor(center, dtype=torch.float64).reshape(3)
        if isinstance(elevation_deg, (tuple, list)):
            lo, hi = elevation_deg
            elev = [lo + (hi - lo) * (0.5 - 0.5 * math.cos(2 * math.pi * i / max(n, 1) * 1.0)) for i in range(n)]
        else:
            elev = [float(elevation_deg)] * n
        up = torch.zeros(3, dtype=torch.float64)
        up[up_axis] = 1.0
        a1, a2 = [a for a in range(3) if a != up_axis]
        poses = []
        for i in range(n):
            az = math.radians(phase_deg + 360.0 * i / n)
            el = math.radians(elev[i])
            offset = torch.zeros(3, dtype=torch.float64)
            offset[a1] = math.cos(el) * math.cos(az)
            offset[a2] = math.cos(el) * math.sin(az)
            offset[up_axis] = math.sin(el)
            poses.append(look_at(center + radius * offset, center, up))
        f = 0.5 * width / math.tan(0.5 * math.radians(fov_deg))
        return cls(torch.stack(poses).float(), f, f, width / 2.0, height / 2.0, width, height)

    # ------------------------------------------------------------------ serialisation
    def to_json(self) -> dict:
        """A plain dict (transforms.json style, one entry per camera) that :meth:`from_json` reads back."""
        return {
            "w": self.width, "h": self.height,
            "frames": [{"transform_matrix": self.c2w[i].tolist(), "fl_x": float(self.fx[i]),
                        "fl_y": float(self.fy[i]), "cx": float(self.cx[i]), "cy": float(self.cy[i])}
                       for i in range(len(self))],
        }

    @classmethod
    def from_json(cls, data: dict) -> "Cameras":
        frames = data["frames"]
        return cls(torch.tensor([f["transform_matrix"] for f in frames], dtype=torch.float32),
                   [f["fl_x"] for f in frames], [f["fl_y"] for f in frames],
                   [f["cx"] for f in frames], [f["cy"] for f in frames], data["w"], data["h"])


def _to4x4(m: np.ndarray) -> np.ndarray:
    if m.shape == (4, 4):
        return m
    return np.concatenate([m, np.array([[0.0, 0.0, 0.0, 1.0]])], axis=0)


def look_at(eye: torch.Tensor, target: torch.Tensor, up: torch.Tensor) -> torch.Tensor:
    """(4, 4) float64 camera-to-world pose at ``eye`` looking at ``target`` (OpenGL convention)."""
    eye, target, up = (torch.as_tensor(v, dtype=torch.float64) for v in (eye, target, up))
    forward = target - eye
    require(float(forward.norm()) > 0, "camera position equals its look-at target")
    forward = forward / forward.norm()
    right = torch.linalg.cross(forward, up)
    if float(right.norm()) < 1e-9:  # looking straight along up: pick any perpendicular
        right = torch.linalg.cross(forward, torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))
    right = right / right.norm()
    true_up = torch.linalg.cross(right, forward)
    pose = torch.eye(4, dtype=torch.float64)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, true_up, -forward, eye
    return pose
