"""Cameras from ``ns-export cameras`` (``transforms_train.json`` / ``transforms_eval.json``), in the data frame.

That file is a JSON list of ``{"file_path", "transform"}``: each ``transform`` the (3, 4) camera-to-world pose in
nerfstudio's frame (after the data parser's transform and scale, and the camera optimiser's corrections),
OpenGL axes, and no intrinsics. This module owns :func:`exported_cameras`: the
poses moved into the field's frame (``x = R^T (x_ns / scale - t)``, axes ``R^T R_ns``) with the intrinsics the
user gives (image size and focal length in pixels; principal point at the centre). The dataset's own
``transforms.json`` carries intrinsics and is read by ``Cameras.from_transforms`` instead. The CLI tells the two
apart by the JSON's top level (a list here, an object with ``frames`` there).

It also owns :func:`corrected_cameras`: the dataset's training cameras moved by the pose corrections the camera
optimizer learned (``_model.camera_optimizer.pose_adjustment``, mode SO3xR3, nerfacto's default), which
nerfstudio applies to every training ray.
"""

from __future__ import annotations

import json
import math
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


def training_frame_indices(names: list[str], eval_mode: str, eval_interval: int, train_fraction: float
                           ) -> dict[str, int]:
    """Image file path -> index among nerfstudio's training images, as its data parser splits a dataset: frames
    sorted by file path, then the ``eval_mode`` split (``interval``: every ``eval_interval``-th is held out;
    ``fraction``: ``round(linspace)`` of ``train_fraction``; ``all``: every frame trains). Other modes (e.g.
    ``filename``) -> {} (corrections are then not applied)."""
    order = sorted(range(len(names)), key=lambda i: names[i])
    n = len(order)
    if eval_mode == "interval":
        train = [k for k in range(n) if k % max(1, int(eval_interval)) != 0]
    elif eval_mode == "fraction":
        count = math.ceil(n * float(train_fraction))
        train = sorted(set(np.linspace(0, n - 1, count, dtype=int).tolist()))
    elif eval_mode == "all":
        train = list(range(n))
    else:
        return {}
    return {names[order[k]]: j for j, k in enumerate(train)}


def so3xr3(tangent: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(K, 6) tangents (translation, then so(3) log rotation) -> (K, 3, 3) rotations, (K, 3) translations:
    nerfstudio's ``exp_map_SO3xR3`` (its angle floored at 1e-2 rad as nerfstudio does, float64 here)."""
    log_rot = tangent[:, 3:]
    angle = np.sqrt(np.maximum((log_rot ** 2).sum(1), 1e-4))
    fac1, fac2 = np.sin(angle) / angle, (1.0 - np.cos(angle)) / angle ** 2
    skew = np.zeros((len(tangent), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -log_rot[:, 2], log_rot[:, 1], -log_rot[:, 0]
    skew[:, 1, 0], skew[:, 2, 0], skew[:, 2, 1] = log_rot[:, 2], -log_rot[:, 1], log_rot[:, 0]
    rot = fac1[:, None, None] * skew + fac2[:, None, None] * skew @ skew + np.eye(3)[None]
    return rot, tangent[:, :3].copy()


def corrected_cameras(cameras, names: list[str], field) -> tuple:
    """``cameras`` (the dataset's transforms.json frames ``names``, data frame) with the camera optimizer's pose
    corrections of the frames nerfstudio trained on: in nerfstudio's frame the rotation becomes ``R_adj R`` and
    the position ``p + t_adj`` (``CameraOptimizer.apply_to_camera``), here ``R^T R_adj R`` applied to the
    data-frame axes and ``R^T t_adj / scale`` added to the centre. Returns (cameras, how many were corrected)."""
    from neuras_distill.render.cameras import Cameras

    adjust = getattr(field, "pose_adjustment", None)
    index = training_frame_indices(names, *field.split) if adjust is not None else {}
    rows = [(i, index[name]) for i, name in enumerate(names) if name in index and index[name] < len(adjust)]
    if not rows:
        return cameras, 0
    rot_adj, t_adj = so3xr3(adjust[[j for _, j in rows]])
    rot, scale = field._rotation64.numpy(), float(field.scale)
    c2w = cameras.c2w.double().numpy().copy()
    for (i, _), r, t in zip(rows, rot_adj, t_adj):
        c2w[i, :3, :3] = rot.T @ r @ rot @ c2w[i, :3, :3]
        c2w[i, :3, 3] = c2w[i, :3, 3] + rot.T @ t / scale
    return Cameras(torch.as_tensor(c2w, dtype=torch.float32), cameras.fx, cameras.fy, cameras.cx, cameras.cy,
                   cameras.width, cameras.height), len(rows)
