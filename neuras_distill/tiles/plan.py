"""The tile plan: a scene's foreground cut into tiles on its ground plane (``neuras-distill tiles plan``).

Owns :func:`make_plan`, :func:`read_plan` / :func:`write_plan` (``CITY/plan.json``, docs/formats.md "Tile
plans") and :func:`plan_table` (``--dry-run``).

Frames: world (the field's). The ground plane is spanned by the two axes other than the capture's up (the
cameras' mean up snapped to an axis, ``export/gltf_up.snapped_up``); tiles of about ``tile_size`` a side on it
divide the foreground box evenly (:func:`tile_counts`), each the box's whole height. A tile's training box is the
tile grown by ``margin`` on the ground plane (clipped to the foreground box): its run sees its neighbours' edges,
then keeps only its own box (``geometry/clip.py``).

Decisions (docs/decisions.md "Tiles"):

* A camera sees a tile when the tile's training box, sampled on a 5 x 5 x 3 lattice, covers at least
  :data:`MIN_FOOTPRINT` of its image (the bounding rectangle of the lattice points in front of it, clipped to the
  image); a tile seen by no training camera is refused (the tile size is too small for the cameras).
* Budgets follow what the cameras see of each tile: a tile's weight is its share of the footprints summed over
  the training cameras; faces and training time (or steps) are the scene's settings times that weight, so the
  tiles together spend what one run of the scene would. The marching-cubes voxel and the teacher's ray step stay
  the scene's (lattice points and steps scaled by the tile box's size against the scene's).
* The plan is deterministic: the same source, cameras, settings and sizes give the same bytes.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from ..errors import BadInputError, require

PLAN_FORMAT = "neuras-distill tile plan"
PLAN_VERSION = 1
#: Levels of detail a plan may ask for (``--levels``): level l has 1/4^l of the faces.
MAX_LEVELS = 4
#: Share of a camera's image a tile's training box must cover for the camera to train (or score) it.
MIN_FOOTPRINT = 0.01
#: Fewest faces and training seconds a tile gets, whatever its weight.
MIN_FACES, MIN_TRAIN_SECONDS, MIN_STEPS = 2000, 20.0, 200


def ground_axes(up: np.ndarray) -> tuple[int, int, int]:
    """(first ground axis, second ground axis, up axis) indices for an up axis vector (3,)."""
    up_axis = int(np.argmax(np.abs(np.asarray(up, np.float64))))
    a, b = (i for i in range(3) if i != up_axis)
    return a, b, up_axis


def tile_counts(box: np.ndarray, axes: tuple[int, int, int], tile_size: float) -> tuple[int, int]:
    """Tiles along each ground axis: the whole number nearest the box's extent over ``tile_size`` (at least 1)."""
    a, b, _ = axes
    extent = box[1] - box[0]
    return max(1, round(extent[a] / tile_size)), max(1, round(extent[b] / tile_size))


def tile_boxes(box: np.ndarray, axes: tuple[int, int, int], tile_size: float) -> list[tuple[tuple[int, int],
                                                                                            np.ndarray]]:
    """[((i, j), (2, 3) float64 box)] of the tiles covering the foreground ``box`` (2, 3): :func:`tile_counts`
    equal tiles along each ground axis (each side within a third of ``tile_size``: the box divides evenly, no
    sliver at its edge), each the box's whole height."""
    a, b, _ = axes
    counts = tile_counts(box, axes, tile_size)
    edges = [np.linspace(box[0][k], box[1][k], n + 1) for k, n in zip((a, b), counts)]
    out = []
    for i in range(counts[0]):
        for j in range(counts[1]):
            lo, hi = box[0].copy(), box[1].copy()
            lo[a], hi[a] = edges[0][i], edges[0][i + 1]
            lo[b], hi[b] = edges[1][j], edges[1][j + 1]
            out.append(((i, j), np.stack([lo, hi])))
    return out


def footprints(box: np.ndarray, cameras) -> np.ndarray:
    """(N,) share of each camera's image that ``box`` (2, 3) covers: the bounding rectangle of a 5 x 5 x 3 lattice
    of the box's points in front of the camera, projected and clipped to the image."""
    grid = np.stack(np.meshgrid(*[np.linspace(box[0][k], box[1][k], n) for k, n in zip(range(3), (5, 5, 3))],
                                indexing="ij"), -1).reshape(-1, 3)
    c2w = cameras.c2w.double().numpy()
    out = np.zeros(len(cameras))
    for n in range(len(cameras)):
        local = (grid - c2w[n, :3, 3]) @ c2w[n, :3, :3]                 # camera frame: x right, y up, -z forward
        front = local[:, 2] < -1e-6
        if not front.any():
            continue
        z = -local[front, 2]
        u = float(cameras.fx[n]) * local[front, 0] / z + float(cameras.cx[n])
        v = -float(cameras.fy[n]) * local[front, 1] / z + float(cameras.cy[n])
        w, h = cameras.width, cameras.height
        du = max(0.0, min(u.max(), w) - max(u.min(), 0.0))
        dv = max(0.0, min(v.max(), h) - max(v.min(), 0.0))
        out[n] = du * dv / (w * h)
    return out


def _scaled(count: int, weight: float, floor: int) -> int:
    return max(floor, int(round(count * weight)))


def make_plan(field, cameras, cfg, *, tile_size: float, margin: float, source: dict, fingerprint: str,
              levels: int = 1) -> dict:
    """The plan (a JSON-ready dict, module docstring) for ``field`` seen by ``cameras`` (all of them; held out as
    the run would hold them out, ``cfg.cameras.test_every``) with the settings ``cfg``. ``source`` says how to
    load the field again (``tiles run``), ``fingerprint`` identifies it (``pipeline.cache.field_fingerprint``).
    ``levels``: levels of detail a tile is baked at (1: full detail only; ``tiles/levels.py``).
    BadInputError for a tile size larger than the scene or so small that a tile has no camera."""
    from .. import __version__
    from ..export.gltf_up import snapped_up
    from ..playback.camera_control import mean_up

    require(math.isfinite(tile_size) and tile_size > 0, f"--tile-size must be a positive length, got {tile_size}")
    require(math.isfinite(margin) and margin >= 0, f"--margin must be a length of 0 or more, got {margin}")
    require(isinstance(levels, int) and 1 <= levels <= MAX_LEVELS,
            f"--levels must be 1..{MAX_LEVELS} (1: full detail only; each more level has 1/4 the faces), got {levels}")
    box = np.asarray(field.aabb, np.float64).reshape(2, 3)
    up, up_name = snapped_up(mean_up(cameras.c2w.double().numpy()))
    axes = ground_axes(up)
    a, b, _ = axes
    extent = box[1] - box[0]
    require(tile_counts(box, axes, tile_size) != (1, 1),
            f"--tile-size {tile_size:g} makes one tile of the whole scene ({extent[a]:g} x {extent[b]:g} on the "
            f"ground plane): distill it with a run command, or give a size under {max(extent[a], extent[b]) / 1.5:g}")
    n = len(cameras)
    test_every = max(2, int(cfg.cameras.test_every))
    test = [i for i in range(n) if i % test_every == test_every // 2] or [n // 2]
    train = [i for i in range(n) if i not in test]
    tiles, seen = [], []
    for index, (grid, core) in enumerate(tile_boxes(box, axes, tile_size)):
        grown = core.copy()
        for axis in (a, b):
            grown[0][axis] = max(box[0][axis], core[0][axis] - margin)
            grown[1][axis] = min(box[1][axis], core[1][axis] + margin)
        share = footprints(grown, cameras)
        tile_train = [i for i in train if share[i] >= MIN_FOOTPRINT]
        tile_test = [i for i in test if share[i] >= MIN_FOOTPRINT]
        if not tile_train:
            raise BadInputError(f"--tile-size {tile_size:g}: tile {index} (grid {grid[0]}, {grid[1]}) is seen by no "
                                "training camera: give a larger tile size, or cameras that see the whole scene")
        seen.append(float(share[tile_train].sum()))
        tiles.append({"index": index, "grid": list(grid), "box": core.tolist(), "training_box": grown.tolist(),
                      "cameras": tile_train, "held_out": tile_test})
    total = sum(seen)
    scene_diag, scene_long = float(np.linalg.norm(extent)), float(extent.max())
    for tile, weight in zip(tiles, seen):
        w = weight / total
        grown = np.asarray(tile["training_box"])
        size = grown[1] - grown[0]
        budget = {"weight": round(w, 6),
                  "faces": _scaled(cfg.geometry.face_budget, w, MIN_FACES),
                  "grid_resolution": max(32, math.ceil(cfg.geometry.grid_resolution * size.max() / scene_long)),
                  "teacher_steps": max(32, math.ceil(cfg.teacher.num_steps * np.linalg.norm(size) / scene_diag)),
                  "texture_resolution": (_scaled(cfg.texture.resolution, math.sqrt(w), 64)
                                         if cfg.texture.resolution else 0)}
        if cfg.train.steps:
            budget["steps"] = _scaled(cfg.train.steps, w, MIN_STEPS)
        if cfg.train.time_budget_s:
            budget["train_seconds"] = max(MIN_TRAIN_SECONDS, round(cfg.train.time_budget_s * w, 1))
        tile["budget"] = budget
    extra = {"levels": levels} if levels > 1 else {}          # absent: 1 (plans made before levels keep their bytes)
    return {**extra, "format": PLAN_FORMAT, "version": PLAN_VERSION, "generator": f"neuras-distill {__version__}",
            "source": source, "field": fingerprint, "scene_box": box.tolist(),
            "up": up.tolist(), "up_axis": up_name, "ground_axes": [a, b], "tile_size": float(tile_size),
            "margin": float(margin), "cameras": "cameras.json", "train": train, "test": test,
            "settings": {"face_budget": cfg.geometry.face_budget, "grid_resolution": cfg.geometry.grid_resolution,
                         "teacher_steps": cfg.teacher.num_steps, "texture_resolution": cfg.texture.resolution,
                         "steps": cfg.train.steps, "train_seconds": cfg.train.time_budget_s},
            "tiles": tiles}


def plan_bytes(plan: dict) -> bytes:
    """plan.json's bytes (sorted keys, two-space indent: the same plan, the same bytes)."""
    return (json.dumps(plan, indent=2, sort_keys=True) + "\n").encode("utf-8")


def read_plan(city: Path) -> dict:
    """``city/plan.json``, checked: ours, of this version, with tiles. BadInputError naming what is wrong."""
    path = Path(city) / "plan.json"
    if not path.is_file():
        raise BadInputError(f"{city} has no plan.json: make one with `neuras-distill tiles plan SOURCE --tile-size "
                            f"METRES --out {city}`")
    try:
        plan = json.loads(path.read_text("utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise BadInputError(f"{path} is not JSON ({exc}): make the plan again with `tiles plan`") from None
    if not isinstance(plan, dict) or plan.get("format") != PLAN_FORMAT:
        raise BadInputError(f"{path} is not a neuras-distill tile plan: make one with `tiles plan`")
    if plan.get("version") != PLAN_VERSION:
        raise BadInputError(f"{path} is a tile plan of version {plan.get('version')}; this neuras-distill reads "
                            f"version {PLAN_VERSION}: make the plan again with `tiles plan`")
    if not isinstance(plan.get("tiles"), list) or not plan["tiles"]:
        raise BadInputError(f"{path} has no tiles: make the plan again with `tiles plan`")
    return plan


def plan_table(plan: dict, estimates: list[dict]) -> str:
    """The ``--dry-run`` table: a row per tile (its box on the ground plane, cameras, budget and estimates)."""
    a, b = plan["ground_axes"]
    names = "xyz"
    lines = [f"{len(plan['tiles'])} tiles of {plan['tile_size']:g} (+{plan['margin']:g} overlap) on the "
             f"{names[a]}{names[b]} plane (up {plan['up_axis']}); {len(plan['train'])} training and "
             f"{len(plan['test'])} held-out cameras",
             f"{'tile':>4} {'grid':>6} {names[a] + ' range':>18} {names[b] + ' range':>18} {'train':>5} {'held':>4} "
             f"{'weight':>6} {'faces':>7} {'train s':>7} {'est. s':>7} {'est. MB':>7}"]
    for tile, est in zip(plan["tiles"], estimates):
        box, bud = tile["box"], tile["budget"]
        train_s = bud.get("train_seconds", bud.get("steps", 0))
        lines.append(f"{tile['index']:>4} {tile['grid'][0]:>3},{tile['grid'][1]:<2} "
                     f"{box[0][a]:>8.1f}..{box[1][a]:<8.1f} {box[0][b]:>8.1f}..{box[1][b]:<8.1f} "
                     f"{len(tile['cameras']):>5} {len(tile['held_out']):>4} {bud['weight']:>6.3f} {bud['faces']:>7} "
                     f"{train_s:>7.0f} {est['seconds']:>7.0f} {est['megabytes']:>7.0f}")
    lines.append("est. s: the teacher (one view of each tile rendered at 64 and 160 px, taken to its views) plus the "
                 "training budget; est. MB: the marching-cubes lattice and the teacher's images")
    return "\n".join(lines)


def estimates(plan: dict, cameras, cfg, field) -> list[dict]:
    """Per tile {"seconds", "megabytes"}, measured where it can be: the teacher's time from one of the tile's
    views volume-rendered on its box at 64 and 160 pixels wide (``render/volume.py``, the tile's ray steps; a
    frame's fixed cost and its cost a pixel), taken to its training views at the teacher's width (the pixels
    its box covers in each; twice as many views with ``cameras.extra_views`` "on"), plus its
    training budget; memory: the marching-cubes lattice (16 bytes a point) and the teacher's images (RGB,
    opacity, depths: 5 float32 a pixel). The evaluation (a few held-out views at 320 pixels wide) is left out."""
    import torch

    from ..render.volume import VolumeRenderer
    from .tile_field import TileField

    out = []
    width = min(cfg.teacher.train_width or cameras.width, cameras.width)
    height = round(cameras.height * width / cameras.width)
    views = 2.0 if cfg.cameras.extra_views == "on" else 1.0
    for tile in plan["tiles"]:
        bud = tile["budget"]
        view = cameras[tile["cameras"][len(tile["cameras"]) // 2:][:1]]
        renderer = VolumeRenderer(TileField(field, tile["training_box"], plan["field"]), num_steps=bud["teacher_steps"])
        timed = []
        for probe_width in (64, 160):                # a line through two sizes: a frame's fixed cost, then pixels
            probe = view.resized(probe_width, max(1, round(view.height * probe_width / view.width)))
            t = time.perf_counter()
            with torch.no_grad():
                renderer.render(probe, 0)
            timed.append((probe.width * probe.height, time.perf_counter() - t))
        (p0, t0), (p1, t1) = timed
        per_pixel = max(t1 - t0, 0.0) / (p1 - p0)
        share = footprints(np.asarray(tile["training_box"]), cameras[tile["cameras"]])
        teacher = (max(t0 - per_pixel * p0, 0.0) * len(tile["cameras"])      # a frame's fixed cost, each view
                   + per_pixel * width * height * float(share.sum())) * views  # the pixels that see the box
        train_s = bud.get("train_seconds", bud.get("steps", 0) * 0.05)
        size = np.asarray(tile["training_box"][1]) - np.asarray(tile["training_box"][0])
        lattice = np.prod(np.ceil(bud["grid_resolution"] * size / size.max()) + 1)
        images = len(tile["cameras"]) * views * width * height * 5 * 4
        out.append({"seconds": teacher + train_s, "megabytes": (lattice * 16 + images) / 2 ** 20})
    return out


__all__ = ["MIN_FOOTPRINT", "PLAN_FORMAT", "PLAN_VERSION", "estimates", "footprints", "ground_axes", "make_plan",
           "plan_bytes", "plan_table", "read_plan", "tile_boxes", "tile_counts"]
