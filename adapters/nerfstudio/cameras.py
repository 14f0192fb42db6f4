"""Cameras from ``ns-export cameras`` (``transforms_train.json`` / ``transforms_eval.json``), in the data frame.

That file is a JSON list of ``{"file_path", "transform"}``: each ``transform`` the (3, 4) camera-to-world pose in
nerfstudio's frame (after the data parser's transform and scale, and the camera optimiser's corrections),
OpenGL axes, and no intrinsics. This module owns :func:`exported_cameras`: the
poses moved into the field's frame (``x = R^T (x_ns / scale - t)``, axes ``R^T R_ns``) with the intrinsics the
user gives (image size and focal length in pixels; principal point at the centre). The dataset's own
``transforms.json`` carries intrinsics and is read by ``Cameras.from_transforms`` instead. The CLI tells the two
apart by the JSON's top level (a list here, an object with ``frames`` there).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from neuras_distill.errors import BadInputError, require


def exported_cameras(path, field, width: int | None, height: int | None, focal: float | None):
    """``Cameras`` of an ``ns-export cameras`` file in ``field``'s frame (a :class:`.field.NerfstudioField`).

    Raises BadInputError (one line) without ``width``/``height``/``focal`` or for a malformed frame."""
    from neuras_distill.render.cameras import Cameras

    require(width is not None and height is not None and focal is not None,
            f"--cameras {path}: ns-export camera files hold poses only; give the images' size and focal length "
            "with --image-size WxH --focal PIXELS (or pass the dataset's transforms.json, which has them)")
    require(focal > 0, f"--focal must be positive pixels, got {focal}")
    frames = json.loads(Path(path).read_text())
    poses = []
    for i, frame in enumerate(frames):
        try:
            m = np.asarray(frame["transform"], dtype=np.float64)
        except (KeyError, TypeError, ValueError):
            raise BadInputError(f"frame {i} of {path}: no 3x4 'transform' of numbers") from None
        require(m.shape in ((3, 4), (4, 4)) and bool(np.isfinite(m).all()),
                f"frame {i} of {path}: transform has shape {m.shape} or non-finite values, not a 3x4 pose")
        poses.append(m[:3])
    rot, t, scale = field._rotation64.numpy(), field._translation64.numpy(), float(field.scale)
    c2w = np.zeros((len(poses), 4, 4))
    for i, m in enumerate(poses):
        c2w[i, :3, :3] = rot.T @ m[:, :3]
        c2w[i, :3, 3] = rot.T @ (m[:, 3] / scale - t)
        c2w[i, 3, 3] = 1.0
    n = len(poses)
    return Cameras(torch.as_tensor(c2w, dtype=torch.float32), [focal] * n, [focal] * n, [width / 2.0] * n,
                   [height / 2.0] * n, int(width), int(height))
