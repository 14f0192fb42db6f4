"""``neuras-distill tiles plan | run | merge``: the tile commands' work behind the command line.

Owns :func:`plan_command`, :func:`run_command` and :func:`merge_command` (each takes the parsed arguments and
returns the exit code; bad input raises BadInputError, which the command line prints as one line, exit 2).
"""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import BadInputError, require
from ..logs import say


def plan_command(args) -> int:
    from ..config import load_config
    from ..pipeline.cache import field_fingerprint
    from ..pipeline.run import pick_cameras
    from ..stability.source import load_source
    from .plan import estimates, make_plan, plan_bytes, plan_table

    out = Path(args.out)
    existing = out / "plan.json"
    require(not out.exists() or (out.is_dir() and (existing.is_file() or not any(out.iterdir()))),
            f"--out {out} exists and holds no tile plan: choose another folder or remove it")
    field, cameras = load_source(args.source, kind=args.kind, cameras_path=args.cameras)
    preset = args.preset or getattr(field, "preset", None)
    overrides: dict = {}
    if args.steps is not None:
        overrides.setdefault("train", {})["steps"] = args.steps
    if args.face_budget is not None:
        overrides.setdefault("geometry", {})["face_budget"] = args.face_budget
    cfg = load_config(preset=preset, path=args.config, overrides=overrides)
    cameras, _ = pick_cameras(field, cameras, cfg)
    margin = args.margin if args.margin is not None else 0.1 * args.tile_size
    source = {"source": args.source, "kind": args.kind, "cameras": args.cameras, "preset": preset,
              "config": str(Path(args.config).resolve()) if args.config else None, "overrides": overrides}
    plan = make_plan(field, cameras, cfg, tile_size=args.tile_size, margin=margin, source=source,
                     fingerprint=field_fingerprint(field), levels=args.levels)
    if args.dry_run:
        print(plan_table(plan, estimates(plan, cameras, cfg, field)))
        return 0
    data = plan_bytes(plan)
    if existing.is_file() and existing.read_bytes() != data:
        raise BadInputError(f"{existing} holds another plan (another source, size or settings): choose another "
                            "--out, or remove that folder to plan again")
    out.mkdir(parents=True, exist_ok=True)
    from ..export.folder_output import write_file

    write_file(out / plan["cameras"], json.dumps(cameras.to_json()).encode("utf-8"))
    write_file(existing, data)
    print(f"wrote {existing}: {len(plan['tiles'])} tiles; run them with `neuras-distill tiles run {out}` "
          f"(or --tile K each, 0..{len(plan['tiles']) - 1})")
    return 0


def run_command(args) -> int:
    from ..pipeline.parallel import check_nproc
    from .plan import read_plan
    from .run import run_tile, run_tiles

    nproc = check_nproc(args.nproc)
    log = say
    if args.ray is not None:
        require(args.tile is None, "--ray runs every unfinished tile; leave --tile out (or run that tile without --ray)")
        from .ray_jobs import run_tiles_on_ray

        device = "cpu" if args.device == "auto" else args.device
        statuses = run_tiles_on_ray(args.city, args.ray or None, device=device, nproc=nproc, log=log)
        print(f"{sum(s != 'skipped' for s in statuses.values())} tiles distilled on Ray, "
              f"{sum(s == 'skipped' for s in statuses.values())} finished before; {len(statuses)} in all")
        return 0
    if args.tile is None:
        statuses = run_tiles(args.city, nproc=nproc, device=args.device, log=log, progress=not args.quiet)
        print(f"{sum(s != 'skipped' for s in statuses.values())} tiles distilled, "
              f"{sum(s == 'skipped' for s in statuses.values())} finished before; {len(statuses)} in all")
        return 0
    read_plan(Path(args.city))
    status = run_tile(args.city, args.tile, nproc=nproc, device=args.device, log=log, progress=not args.quiet)
    print(f"tile {args.tile}: " + {"skipped": "finished before, skipped", "done": "distilled"}[status])
    return 0


def merge_command(args) -> int:
    from .tileset import merge_tiles

    limit = None
    if args.max_texture_size is not None:
        try:
            limit = int(args.max_texture_size)
        except ValueError:
            raise BadInputError(f"--max-texture-size must be an integer, got {args.max_texture_size!r}") from None
    out, size = merge_tiles(args.city, args.out, max_texture_size=limit, crs=args.crs)
    print(f"wrote {out / 'tileset.json'} and its tiles ({size} bytes)")
    return 0


COMMANDS = {"plan": plan_command, "run": run_command, "merge": merge_command}

__all__ = ["COMMANDS", "merge_command", "plan_command", "run_command"]
