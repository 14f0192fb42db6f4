"""Speedup benchmark: the field (volume rendering) against a bundle (OpenGL) on the same cameras, repeated.

Prints one JSON line per repeat and a summary with medians, so noisy shared machines can be read fairly.
Usage: python benchmarks/speedup.py RUN_FOLDER [--repeats 3]
(RUN_FOLDER is a run of `neuras-distill demo`: it needs bundle/ and cameras.json; the field is the demo's.)
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import neuras_distill as nd
from neuras_distill.playback.renderer import BundleRenderer
from neuras_distill.render.volume import VolumeRenderer


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("run", type=Path)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scene", default="bunny")
    args = parser.parse_args()
    report = json.loads((args.run / "report.json").read_text())
    cams = nd.Cameras.from_json(json.loads((args.run / "cameras.json").read_text())["test"])
    field = nd.make_scene(args.scene)
    teacher = VolumeRenderer(field, num_steps=report["teacher_steps"])
    player = BundleRenderer(nd.load_bundle(args.run / "bundle"))
    ratios = []
    for r in range(args.repeats):
        field_s = []
        for i in range(len(cams)):
            t0 = time.perf_counter()
            teacher.render(cams, i)
            field_s.append(time.perf_counter() - t0)
        bundle_ms = player.time_frames(cams, warmup=5, frames=30)["median_ms"]
        ratio = statistics.median(field_s) * 1000 / bundle_ms
        ratios.append(ratio)
        print(json.dumps({"repeat": r, "field_ms_median": 1000 * statistics.median(field_s),
                          "bundle_ms_median": bundle_ms, "speedup": ratio,
                          "resolution": [cams.width, cams.height]}))
    print(json.dumps({"speedup_median": statistics.median(ratios), "speedup_min": min(ratios),
                      "speedup_max": max(ratios)}))


if __name__ == "__main__":
    main()
