"""``neuras-distill render``: a bundle along a camera path or an orbit, as an MP4 or PNG frames, alone or beside
the field it was distilled from (``--compare RUN_DIR``: the field | the bundle, the before and after).

Cameras: nerfstudio's ``camera_path.json`` (:mod:`.render.camera_path`) or ``--orbit N`` around the bundle's
mesh. Which frame a path is in (``--path-frame``):

* ``auto``: nerfstudio's when the bundle's run recorded nerfstudio's dataparser frame (``report.json``
  ``field.viewer_frame``, or ``--dataparser-transforms``), else the bundle's own (the field's frame: an
  Instant-NGP snapshot, a NeuS checkpoint or a synthetic scene has no other);
* ``nerfstudio``: nerfstudio's, which needs that transform;
* ``bundle``: the bundle's own frame (a nerfstudio run's is the dataset's ``transforms.json`` frame).

A bundle whose frame a nerfstudio path cannot be put in (a nerfstudio run's bundle without a recorded
transform) is refused with the fix. Frames are drawn by :class:`~.playback.renderer.BundleRenderer` (the
desktop player); the field's by the run's teacher (its volume renderer with the run's settings).
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from .errors import BadInputError, require

#: ``--path-frame`` values.
PATH_FRAMES = ("auto", "nerfstudio", "bundle")
#: Pixels between the field and the bundle in a ``--compare`` frame (a dark gap).
COMPARE_GAP = 4


@dataclass(frozen=True)
class PathCameras:
    """Where the frames are seen from: ``cameras`` (world frame of the bundle), ``fps``, and ``said``, one
    phrase saying where they came from and in which frame."""

    cameras: object
    fps: float
    said: str


def bundle_location(path: str | Path) -> tuple[Path, Path | None]:
    """(the bundle: a folder or a .glb, the run folder holding it or None) for a bundle or a run folder."""
    p = Path(path)
    if (p / "bundle").is_dir() and (p / "report.json").is_file():
        return p / "bundle", p
    require(p.exists(), f"{p} does not exist; pass a bundle folder, a .glb or a run folder")
    run = p.resolve().parent
    return p, run if (run / "report.json").is_file() and (run / ".neuras-distill-run").is_file() else None


def _report(run: Path | None) -> dict:
    if run is None:
        return {}
    try:
        return json.loads((run / "report.json").read_text("utf-8"))
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise BadInputError(f"{run / 'report.json'} cannot be read ({exc}); re-run the distillation") from None


def read_dataparser_transforms(path: str | Path) -> dict:
    """nerfstudio's ``dataparser_transforms.json`` -> ``{"transform": (3, 4) list, "scale": float}``."""
    p = Path(path)
    try:
        data = json.loads(p.read_text("utf-8"))
        transform = np.asarray(data["transform"], np.float64).reshape(3, 4)
        scale = float(data["scale"])
    except (OSError, ValueError, KeyError, TypeError, UnicodeDecodeError) as exc:
        raise BadInputError(f"--dataparser-transforms {p} is not nerfstudio's dataparser_transforms.json "
                            f"({exc.__class__.__name__}: {exc}); pass the file from the run's folder") from None
    require(np.isfinite(transform).all() and np.isfinite(scale) and scale > 0,
            f"--dataparser-transforms {p}: the transform must be finite and the scale positive")
    return {"kind": "nerfstudio dataparser", "transform": transform.tolist(), "scale": scale}


def path_cameras(bundle, bundle_path: Path, run: Path | None, *, camera_path: str | None = None,
                 orbit: int | None = None, path_frame: str = "auto", dataparser: str | None = None,
                 width: int | None = None, height: int | None = None, fps: float | None = None) -> PathCameras:
    """The cameras of ``render``: a camera path put in the bundle's frame, or an orbit of ``orbit`` frames."""
    from .playback.viewer import world_orbit_cameras
    from .render.camera_path import DEFAULT_FPS, read_camera_path, to_dataset_frame

    require((camera_path is None) != (orbit is None), "pass one of --camera-path camera_path.json or --orbit N")
    require(path_frame in PATH_FRAMES, f"--path-frame must be one of {', '.join(PATH_FRAMES)}, got {path_frame!r}")
    require(fps is None or 0 < fps <= 240, f"--fps must be in (0, 240], got {fps}")
    require(width is None or 8 <= width <= 8192, f"--width must be 8..8192 pixels, got {width}")
    require(height is None or 8 <= height <= 8192, f"--height must be 8..8192 pixels, got {height}")
    if orbit is not None:
        require(orbit >= 1, f"--orbit needs at least 1 frame, got {orbit}")
        cams = world_orbit_cameras(bundle, orbit, width or 960, height or 540)
        return PathCameras(cams, fps or DEFAULT_FPS, f"an orbit of {orbit} frames around the bundle's mesh")
    path = read_camera_path(camera_path)
    report = _report(run)
    viewer = read_dataparser_transforms(dataparser) if dataparser else (report.get("field") or {}).get("viewer_frame")
    nerfstudio_run = ((report.get("source") or {}).get("command") or [None, None])[1:2] == ["from-nerfstudio"]
    if path_frame == "nerfstudio" or (path_frame == "auto" and (viewer or nerfstudio_run)):
        require(viewer is not None,
                f"{bundle_path}: the camera path is in nerfstudio's frame, but "
                + ("this run does not record nerfstudio's dataparser transform" if nerfstudio_run else
                   "the bundle's run is not a nerfstudio run") +
                ", so the path cannot be put in the bundle's frame; pass --dataparser-transforms "
                "<run>/dataparser_transforms.json, or --path-frame bundle for a path in the bundle's own frame")
        cams = path.cameras(to_dataset_frame(path.c2w, viewer))
        said = f"{len(cams)} poses of {camera_path} in nerfstudio's frame, put in the dataset's"
    else:
        cams = path.cameras()
        said = f"{len(cams)} poses of {camera_path} in the bundle's own frame"
    if width or height:
        w = width or max(8, round(cams.width * height / cams.height))
        cams = cams.resized(w, height or max(8, round(cams.height * w / cams.width)))
    return PathCameras(cams, fps or path.fps, said)


def _to_uint8(img: np.ndarray) -> np.ndarray:
    return np.round(np.clip(img, 0.0, 1.0) * 255.0).astype(np.uint8)


def compare_field(run: str | Path):
    """A ``(cameras, i) -> (H, W, 3) float`` renderer of the field the run distilled: the run's recorded command
    loaded again in its folder, volume-rendered with the run's teacher settings."""
    from .bench.run import rebuild_inputs
    from .render.volume import VolumeRenderer

    folder = Path(run)
    require((folder / ".neuras-distill-run").is_file() and (folder / "report.json").is_file(),
            f"--compare {folder} is not a run folder (no report.json); pass the --out of a distillation")
    report = _report(folder)
    require(bool((report.get("source") or {}).get("command")),
            f"--compare {folder} was distilled from Python, so its field cannot be loaded again here; render the "
            "field yourself, or distil it with the neuras-distill command")
    field, _ = rebuild_inputs(report)
    teacher = (report.get("config") or {}).get("teacher") or {}
    renderer = VolumeRenderer(field, **{k: teacher[k] for k in ("num_steps", "far_steps", "occupancy_resolution")
                                        if k in teacher})
    return lambda cameras, i: renderer.render(cameras, i)["rgb"]


def frames_along(bundle, cameras, field_render: Callable | None = None, progress: Callable | None = None):
    """(H, W, 3) uint8 frames, one per camera: the bundle as the desktop player draws it, or with
    ``field_render`` the field | a gap | the bundle, (H, 2W + COMPARE_GAP, 3)."""
    from .playback.renderer import BundleRenderer

    with BundleRenderer(bundle) as player:
        for i in range(len(cameras)):
            img = _to_uint8(player.render(cameras, i))
            if field_render is not None:
                gap = np.full((img.shape[0], COMPARE_GAP, 3), 16, np.uint8)
                img = np.concatenate([_to_uint8(np.asarray(field_render(cameras, i))), gap, img], axis=1)
            if progress is not None:
                progress(i + 1, len(cameras))
            yield img


def write_frames(frames, out: str | Path, fps: float) -> dict:
    """``frames`` into ``out``: an .mp4 (:func:`~.export.video.write_mp4`) or a folder of ``frame_NNNN.png``
    (written into a hidden folder beside it, moved into place when complete). Returns what was written."""
    from PIL import Image

    target = Path(out)
    if target.suffix.lower() == ".mp4":
        from .export.video import write_mp4

        return {"path": str(target), **write_mp4(frames, target, fps)}
    require(target.suffix == "" and not target.is_file(),
            f"--out {target}: pass a .mp4 file or a folder for PNG frames")
    require(not target.exists() or not any(target.iterdir()),
            f"--out {target} is a folder that is not empty; pass a new folder for the PNG frames")
    tmp = target.with_name(f".{target.name}.partial")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    count, size = 0, None
    try:
        for count, frame in enumerate(frames, 1):
            size = frame.shape[:2]
            Image.fromarray(frame, mode="RGB").save(tmp / f"frame_{count - 1:04d}.png")
        if target.exists():
            target.rmdir()
        os.replace(tmp, target)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    require(count > 0, "no frames to write: the camera path is empty")
    return {"path": str(target), "frames": count, "width": int(size[1]), "height": int(size[0]), "fps": fps}
