"""Run the demo, the Instant-NGP ball and the street end to end on one device and print one table (wall time per stage, FPS, PSNR).

    python benchmarks/device_runs.py --device cuda --out runs/cuda [--scenes demo,ngp-ball,street]
    python benchmarks/device_runs.py --device cpu  --out runs/cpu  --scenes demo
    python benchmarks/device_runs.py --device cuda --out runs/cuda_fp16 --scenes demo -- --precision fp16

Each scene is the command a user types (``neuras-distill demo``, ``from-ngp tests/data/ngp/ball.ingp``,
``from-synthetic street``, ``from-synthetic city``) with ``--device`` and held-out frames 1920 pixels wide
(``--eval-width 0``: the preset's own), run in a child process and
timed from outside (wall clock, including the interpreter's start). The table comes from each run's
report.json: ``stage_seconds``, field and bundle FPS at the same cameras, the speedup, PSNR / FLIP against the
field, the training steps the plan chose and what ran each side (``report.device``). A scene that fails is
listed with its exit code and the tail of its log; the others still run.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENES = {
    "demo": ["demo"],
    "ngp-ball": ["from-ngp", str(ROOT / "tests/data/ngp/ball.ingp")],
    "ngp-bunny": ["from-ngp", str(ROOT / "tests/data/ngp/bunny.ingp")],
    "street": ["from-synthetic", "street"],
    "city": ["from-synthetic", "city"],
}


def run_scene(name: str, device: str, out: Path, eval_width: int, extra: list[str]) -> dict:
    """Run one scene into ``out/name``; return its report (or the failure) with the outside wall time."""
    run_dir = out / name
    width = ["--eval-width", str(eval_width)] if eval_width > 0 else []      # 0: the scene preset's own
    cmd = [sys.executable, "-m", "neuras_distill.cli", *SCENES[name], "--out", str(run_dir),
           "--device", device, *width, "--fresh", *extra]
    log = out / f"{name}.log"
    start = time.perf_counter()
    with open(log, "w") as fh:
        rc = subprocess.call(cmd, stdout=fh, stderr=subprocess.STDOUT, cwd=ROOT,
                             env={**os.environ, "PYTHONUNBUFFERED": "1"})
    wall = time.perf_counter() - start
    if rc != 0:
        return {"scene": name, "rc": rc, "wall_s": wall, "log_tail": log.read_text()[-1500:]}
    report = json.loads((run_dir / "report.json").read_text())
    return {"scene": name, "rc": 0, "wall_s": wall, "report": report}


def summary_row(result: dict) -> dict:
    """The stage times, frame times, speedup and scores of one run's report."""
    if result["rc"] != 0:
        return {"scene": result["scene"], "rc": result["rc"], "wall_s": round(result["wall_s"], 1)}
    r = result["report"]
    return {
        "scene": result["scene"], "wall_s": round(result["wall_s"], 1),
        "resolution": r["resolution"], "stage_seconds": r["stage_seconds"],
        "field_fps": round(r["fps_before"], 4), "bundle_fps": round(r["fps_after"], 1),
        "field_ms": round(1000.0 / r["fps_before"], 1), "bundle_ms": round(1000.0 / r["fps_after"], 2),
        "speedup": round(r["speedup"], 1), "psnr": round(r["psnr"], 2), "flip": round(r["flip"], 4),
        "bundle_gpu_ms": r["frame_time_ms"].get("bundle_gpu_median"),
        "bundle_pipelined_ms": r["frame_time_ms"].get("bundle_pipelined"),
        "speedup_pipelined": r.get("speedup_pipelined"), "precision": r["device"].get("precision"),
        "evaluate_parts": r.get("evaluate_seconds"), "peak_rss_mb": r.get("peak_rss_mb"),
        "geometry_parts": {k: round(v, 2) for k, v in r.get("mesh_stats", {}).items()
                           if k.startswith("seconds_") and isinstance(v, (int, float))},
        "peak_gpu_mb": r.get("peak_gpu_mb"),
        "steps": r["training_plan"].get("steps"), "plan": r["training_plan"].get("reason"),
        "device": r["device"],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--scenes", default="demo,ngp-ball,street")
    parser.add_argument("--eval-width", type=int, default=1920, help="held-out width; 0 keeps each preset's")
    parser.add_argument("extra", nargs="*", help="more options for every run (after --)")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in args.scenes.split(","):
        result = run_scene(name, args.device, args.out, args.eval_width, args.extra)
        row = summary_row(result)
        rows.append(row)
        print(json.dumps(row), flush=True)
        if result["rc"] != 0:
            print(result["log_tail"], flush=True)
        (args.out / "summary.json").write_text(json.dumps(rows, indent=1))   # after each scene: a cut-off run keeps it
    print(f"\n{'scene':10s} {'res':>10s} {'wall s':>7s} {'field ms':>9s} {'bundle ms':>9s} {'speedup':>8s} "
          f"{'PSNR':>6s} {'FLIP':>6s} {'steps':>6s}")
    for row in rows:
        if "rc" in row:
            print(f"{row['scene']:10s} failed (exit {row['rc']}) after {row['wall_s']} s")
            continue
        res = "x".join(str(v) for v in row["resolution"])
        print(f"{row['scene']:10s} {res:>10s} {row['wall_s']:7.1f} {row['field_ms']:9.1f} {row['bundle_ms']:9.2f} "
              f"{row['speedup']:8.1f} {row['psnr']:6.2f} {row['flip']:6.4f} {row['steps']!s:>6s}")
        print("           stages: " + ", ".join(f"{k} {v:.1f}" for k, v in row["stage_seconds"].items()))
        if row.get("geometry_parts"):
            print("           geometry: " + ", ".join(f"{k[8:]} {v:.1f}" for k, v in row["geometry_parts"].items()))
        if row.get("evaluate_parts"):
            print("           evaluate: " + ", ".join(f"{k} {v:.1f}" for k, v in row["evaluate_parts"].items()))
        if row.get("bundle_pipelined_ms"):
            gpu = row["bundle_gpu_ms"]
            print(f"           bundle back to back {row['bundle_pipelined_ms']:.2f} ms (speedup "
                  f"{row['speedup_pipelined']:.1f}), GPU time " + (f"{gpu:.2f} ms" if gpu else "not measured")
                  + f"; field precision {row['precision']}")
    return 0 if all("rc" not in row for row in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
