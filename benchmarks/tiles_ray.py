"""Tiles on Ray against the loop in turn: wall time, and whether they wrote the same bytes.

    python benchmarks/tiles_ray.py CITY [--ray ADDRESS] [--threads N]

CITY is a folder of ``neuras-distill tiles plan`` (with fixed ``--steps``, so a tile's bundle is reproducible).
The script copies it twice and runs every tile (1) in turn in this process with ``--threads`` torch threads (the
default: the machine's cores) and (2) as Ray tasks (``tiles run --ray``: a local Ray with every core of this
machine, or the cluster at ``--ray ADDRESS``), each task one CPU and one thread. It prints both wall times, their
ratio and, tile by tile, whether the two wrote the same bytes (they do when the loop ran with one thread, as a
task does). On a machine with C cores and T >= C tiles the tasks run C at a time; on 2 cores no speedup is
expected (the loop already uses both cores for one tile): the figure is Ray's overhead. Run it alone.
"""

from __future__ import annotations

import argparse
import filecmp
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _same(a: Path, b: Path) -> bool:
    names = sorted(p.name for p in a.iterdir())
    if names != sorted(p.name for p in b.iterdir()):
        return False
    _, mismatch, errors = filecmp.cmpfiles(a, b, names, shallow=False)
    return not mismatch and not errors


def main() -> int:
    import json
    import os

    import torch

    from neuras_distill.cli import main as cli

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("city", type=Path)
    ap.add_argument("--ray", default="", metavar="ADDRESS", help="a Ray cluster's address (default: a local Ray)")
    ap.add_argument("--threads", type=int, default=os.cpu_count(), help="torch threads of the loop in turn")
    args = ap.parse_args()
    plan = json.loads((args.city / "plan.json").read_text())
    with tempfile.TemporaryDirectory(prefix="tiles-ray-") as tmp:
        turn, ray = Path(tmp) / "in-turn", Path(tmp) / "ray"
        for dst in (turn, ray):
            shutil.copytree(args.city, dst, ignore=shutil.ignore_patterns("tiles", "tileset"))
        torch.set_num_threads(args.threads)
        t0 = time.perf_counter()
        assert cli(["tiles", "run", str(turn), "--quiet"]) == 0
        t_turn = time.perf_counter() - t0
        t0 = time.perf_counter()
        assert cli(["tiles", "run", str(ray), "--ray", *([args.ray] if args.ray else []), "--quiet"]) == 0
        t_ray = time.perf_counter() - t0
        same = [_same(turn / "tiles" / str(t["index"]) / "tile", ray / "tiles" / str(t["index"]) / "tile")
                for t in plan["tiles"]]
    print(f"{len(plan['tiles'])} tiles on {os.cpu_count()} cores")
    print(f"in turn ({args.threads} threads): {t_turn:.1f} s")
    print(f"Ray ({args.ray or 'local'}, 1 CPU a task): {t_ray:.1f} s ({t_turn / t_ray:.2f}x the loop's speed)")
    print("same bytes, tile by tile: " + ", ".join(f"{k}: {'yes' if s else 'no'}" for k, s in enumerate(same)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
