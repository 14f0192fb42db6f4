"""One tile as one job (``neuras-distill tiles run CITY --tile K``), and every unfinished tile in turn.

Owns :func:`run_tile`, :func:`run_tiles`, :func:`load_plan_source` and the layout of ``CITY/tiles/K/``:

    CITY/tiles/K/            the tile's run folder, written by ``distill`` (``.K.partial`` while it runs:
                             killed, the same command resumes it; its report scores the tile's own box)
        bundle/              the bundle as trained, on the tile's training box
        tile/                the bundle cut back to the tile's own box (``geometry/clip.py``): what is merged
        tile.json            written last: the tile is finished (its index, boxes, the plan's digest, face counts)

A tile whose ``tile.json`` matches the plan is skipped (idempotent); any other is run into its folder again, which
reuses every stored stage whose inputs are unchanged (a killed job resumes; a finished run under a changed plan
redoes only what the change touches). Each step writes under a temporary name and renames, so a killed job leaves
nothing half-written.

Frames: the plan's boxes are world boxes; the cut is done in the bundle's frame (world minus its origin).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from pathlib import Path

import numpy as np

from ..errors import AtlasTooSmallError, BadInputError, require
from ..export.folder_output import write_file
from .plan import plan_bytes, read_plan

DONE = "tile.json"


def plan_digest(plan: dict) -> str:
    """SHA-256 (hex, 16 characters) of the plan's bytes: which plan a finished tile belongs to."""
    return hashlib.sha256(plan_bytes(plan)).hexdigest()[:16]


def load_plan_source(plan: dict):
    """(field, fingerprint) of the plan's source, loaded as ``tiles plan`` loaded it; BadInputError when the
    field is no longer the one the plan was made for (another checkpoint at that path, another version)."""
    from ..pipeline.cache import field_fingerprint
    from ..stability.source import load_source

    src = plan["source"]
    field, _ = load_source(src["source"], kind=src.get("kind"), cameras_path=src.get("cameras"),
                           options=src.get("options") or {})
    fingerprint = field_fingerprint(field)
    if fingerprint != plan["field"]:
        raise BadInputError(f"the plan was made for another field than {src['source']} is now (another checkpoint "
                            "or neuras-distill version): make the plan again with `tiles plan`")
    return field, fingerprint


def tile_config(plan: dict, tile: dict):
    """The DistillConfig of one tile: the plan's settings (preset, config file, overrides) with the tile's
    budget, the scene's voxel and ray step, no skyboxes (the far field is the scene's, not a tile's) and a
    light evaluation of its own (320 pixels wide, 5 timed frames, one field point)."""
    from ..config import load_config

    src, bud = plan["source"], tile["budget"]
    overrides: dict = json.loads(json.dumps(src.get("overrides") or {}))
    overrides.setdefault("geometry", {}).update(face_budget=bud["faces"], grid_resolution=bud["grid_resolution"])
    overrides.setdefault("teacher", {})["num_steps"] = bud["teacher_steps"]
    overrides.setdefault("skybox", {})["mode"] = "off"
    # a tile's own report is a check on its box; the scene's figures are the tiles drawn together
    # (benchmarks/tiled_scene.py): a few held-out views at 320 pixels, one cheaper field point
    evaluation = overrides.setdefault("eval", {})
    evaluation.update(width=min(int(evaluation.get("width", 320) or 320), 320), fps_frames=5, runtime_steps=[32])
    if bud.get("texture_resolution"):
        overrides.setdefault("texture", {})["resolution"] = bud["texture_resolution"]
    if "steps" in bud:
        overrides.setdefault("train", {})["steps"] = bud["steps"]
    if "train_seconds" in bud:
        overrides.setdefault("train", {})["time_budget_s"] = bud["train_seconds"]
    return load_config(preset=src.get("preset"), path=src.get("config"), overrides=overrides)


def _tile(plan: dict, index: int) -> dict:
    n = len(plan["tiles"])
    if not (0 <= index < n):
        raise BadInputError(f"--tile {index} is out of range: the plan has tiles 0..{n - 1}")
    return plan["tiles"][index]


def tile_done(city: Path, plan: dict, index: int) -> bool:
    """Whether tile ``index`` is finished for this plan (its ``tile.json`` names the plan's digest)."""
    path = Path(city) / "tiles" / str(index) / DONE
    try:
        return json.loads(path.read_text("utf-8")).get("plan") == plan_digest(plan)
    except (OSError, ValueError, UnicodeDecodeError, AttributeError):
        return False


def _distill_tile(field, fingerprint, plan: dict, tile: dict, cameras, cfg, run: Path, *, log, progress, device,
                  nproc, reuse_from=(), source_extra=None) -> dict:
    """One distillation of the tile into ``run`` (resumable), then its cut (``cut_tile``)."""
    import neuras_distill as nd

    from .tile_field import TileField

    # a run folder left by a killed job or an earlier plan is run into again: distill reuses every stage whose
    # inputs did not change (a finished run: all of them) and recomputes the rest
    nd.distill(TileField(field, tile["training_box"], fingerprint), cameras[tile["cameras"]], cfg, out=run,
               held_out=cameras[tile["held_out"] or tile["cameras"][:1]], log=log, progress=progress, device=device,
               nproc=nproc, reuse_from=reuse_from, source={"tile": tile["index"], **(source_extra or {}),
                                                           **plan["source"]})
    return cut_tile(run, tile)


def _coarse_levels(city: Path, plan: dict, tile: dict, field, fingerprint, cameras, cfg, *, log, progress, device,
                   nproc) -> list[dict]:
    """Levels 1 .. ``plan["levels"]`` - 1 of the tile (``tiles/levels.py``), each distilled from level 0's stored
    stages, cut, and measured against level 0: [{"level", "faces", "side", "deviation_m", "texel_m", "error_m"}]."""
    from ..bake.bundle import load_bundle
    from .levels import atlas_side, level_error, level_folder, level_overrides

    k = tile["index"]
    fine_run = level_folder(city, 0, k)
    fine = load_bundle(fine_run / "tile")
    side0 = atlas_side(fine_run)
    out, floor = [], 0.0
    for level in range(1, int(plan.get("levels", 1))):
        overrides = level_overrides(cfg, level, side0)
        run = level_folder(city, level, k)
        try:
            _distill_tile(field, fingerprint, plan, tile, cameras, cfg.updated(overrides, f"level {level}"), run,
                          log=log, progress=progress, device=device, nproc=nproc, reuse_from=[fine_run / "work"],
                          source_extra={"level": level})
        except AtlasTooSmallError as small:   # a fragmented mesh's charts need more than half the side: give them it
            overrides["texture"]["resolution"] = min(side0, -(-small.need // 16) * 16)
            _distill_tile(field, fingerprint, plan, tile, cameras, cfg.updated(overrides, f"level {level}"), run,
                          log=log, progress=progress, device=device, nproc=nproc, reuse_from=[fine_run / "work"],
                          source_extra={"level": level})
        coarse = load_bundle(run / "tile")
        error = level_error(fine, coarse, overrides["texture"]["resolution"])
        floor = max(floor, error["error_m"])
        out.append({"level": level, "faces": int(coarse.mesh.num_faces), "side": overrides["texture"]["resolution"],
                    **error, "error_m": floor})
    return out


def cut_tile(run: Path, tile: dict) -> dict:
    """Cut ``run/bundle`` to the tile's own box on the ground plane into ``run/tile`` (atomically); returns the
    clip's counts."""
    from ..bake.bundle import load_bundle
    from ..geometry.clip import clip_mesh_to_box

    bundle = load_bundle(run / "bundle")
    core = np.asarray(tile["box"], np.float64) - bundle.origin
    axes = tile["ground_axes"]
    mesh = clip_mesh_to_box(bundle.mesh, core[0], core[1], axes=axes)
    require(mesh.num_faces > 0, f"tile {tile['index']}: nothing of its mesh lies inside its own box")
    bundle.mesh = mesh
    out = run / "tile"
    tmp = run / f".tile.tmp-{os.getpid()}-{int(time.time() * 1000)}"
    try:
        bundle.save(tmp)
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)
    return mesh.stats["clipped_faces"]


def run_tile(city, index: int, *, device="auto", nproc: int = 1, log=None, progress: bool = True,
             field=None) -> str:
    """Distill tile ``index`` of the plan in ``city`` (module docstring); returns "done" or "skipped".
    ``field``: the plan's field already loaded (``run_tiles`` loads it once)."""
    from ..render.cameras import Cameras

    city = Path(city)
    plan = read_plan(city)
    tile = dict(_tile(plan, index), ground_axes=plan["ground_axes"])
    if tile_done(city, plan, index):
        return "skipped"
    if field is None:
        field, fingerprint = load_plan_source(plan)
    else:
        fingerprint = plan["field"]
    run = city / "tiles" / str(index)
    cameras = Cameras.from_json(json.loads((city / plan["cameras"]).read_text("utf-8")))
    cfg = tile_config(plan, tile)
    options = dict(log=log, progress=progress, device=device, nproc=nproc)
    counts = _distill_tile(field, fingerprint, plan, tile, cameras, cfg, run,
                           source_extra={"plan": str(city / "plan.json")}, **options)
    levels = _coarse_levels(city, plan, tile, field, fingerprint, cameras, cfg, **options)
    record = {"index": index, "plan": plan_digest(plan), "box": tile["box"], "training_box": tile["training_box"],
              "faces": counts, **({"levels": levels} if levels else {})}
    write_file(run / DONE, (json.dumps(record, indent=2) + "\n").encode("utf-8"))
    return "done"


def run_tiles(city, *, device="auto", nproc: int = 1, log=None, progress: bool = True) -> dict:
    """Every unfinished tile of the plan in ``city``, one after another (the shell loop, built in): {index:
    status}. The field is loaded once."""
    city = Path(city)
    plan = read_plan(city)
    say = log or (lambda m: None)
    field = None
    out = {}
    for tile in plan["tiles"]:
        k = tile["index"]
        if tile_done(city, plan, k):
            out[k] = "skipped"
            say(f"tile {k}: finished before, skipped ({len(out)}/{len(plan['tiles'])} tiles)")
            continue
        if field is None:
            field, _ = load_plan_source(plan)
        out[k] = run_tile(city, k, device=device, nproc=nproc, log=log, progress=progress, field=field)
        say(f"tile {k}: {out[k]} ({len(out)}/{len(plan['tiles'])} tiles)")
    return out


__all__ = ["DONE", "cut_tile", "load_plan_source", "plan_digest", "run_tile", "run_tiles", "tile_config",
           "tile_done"]
