"""Field frames in float32 and in float16 (``--precision fp16``) on one device: time and error, one table.

    python benchmarks/precision_speed.py --device cuda [--width 1920] [--fields tests/data/ngp/ball.ingp,...]

For each field: the volume renderer's median time per frame over ``--frames`` cameras of an orbit around the
field's box at ``--width`` x 9/16 (after one untimed warm-up frame, synchronised around each frame: the
"before" timing of a run), once with the field in float32 and once through ``on_device(field, device, "fp16")``
(half hash-grid tables, float16 MLPs, float32 compositing); the PSNR and largest pixel difference of the fp16
frames against the fp32 ones. Both use the renderer's default occupancy grid, built from each field.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from neuras_distill.device import describe, resolve_device
from neuras_distill.device_field import on_device
from neuras_distill.registry import load_field
from neuras_distill.render.volume import VolumeRenderer
from neuras_distill.scenes.analytic import orbit_framing

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_FIELDS = ("tests/data/ngp/ball.ingp", "tests/data/ngp/bunny.ingp", "tests/data/nerfstudio/bunny/config.yml")


def measure(path: str, device: torch.device, width: int, frames: int, steps: int) -> dict:
    field = load_field(ROOT / path)
    cams = orbit_framing(field.aabb, frames, width, width * 9 // 16)
    out = {"field": path}
    images = {}
    for precision in ("fp32", "fp16"):
        t0 = time.perf_counter()
        renderer = VolumeRenderer(on_device(field, device, precision), num_steps=steps, device=device)
        out[f"{precision}_setup_s"] = round(time.perf_counter() - t0, 2)
        timing = renderer.time_frames(cams)
        out[f"{precision}_ms"] = round(1000 * timing["seconds_per_frame"], 1)
        images[precision] = renderer.render(cams, 0)["rgb"]
    mse = float(np.mean((images["fp16"] - images["fp32"]) ** 2))
    out["fp16_psnr_vs_fp32"] = round(10 * np.log10(1.0 / max(mse, 1e-20)), 2)
    out["fp16_max_abs_diff"] = float(np.abs(images["fp16"] - images["fp32"]).max())
    out["speedup"] = round(out["fp32_ms"] / out["fp16_ms"], 2)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="auto")
    parser.add_argument("--width", type=int, default=1920)
    parser.add_argument("--frames", type=int, default=3)
    parser.add_argument("--steps", type=int, default=256)
    parser.add_argument("--fields", default=",".join(DEFAULT_FIELDS))
    args = parser.parse_args()
    device = resolve_device(args.device)
    print(f"device: {describe(device)}", flush=True)
    rows = []
    for path in args.fields.split(","):
        try:
            rows.append(measure(path, device, args.width, args.frames, args.steps))
        except Exception as exc:             # noqa: BLE001 - one field that cannot load does not end the table
            print(f"{path}: {type(exc).__name__}: {exc}", flush=True)
            continue
        print(json.dumps(rows[-1]), flush=True)
    print(f"\n{'field':45s} {'fp32 ms':>8s} {'fp16 ms':>8s} {'ratio':>6s} {'PSNR fp16 vs fp32':>18s}")
    for r in rows:
        print(f"{r['field']:45s} {r['fp32_ms']:8.1f} {r['fp16_ms']:8.1f} {r['speedup']:6.2f} "
              f"{r['fp16_psnr_vs_fp32']:18.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
