"""Playback benchmark: re-play run folders' bundles alone, with and without the soft-silhouette pass, and the
plain baked RGB texture (what the neural shader costs; bundles that store plain_rgb.png).

For each run: the median frame time of each variant (interleaved, ``--repeats`` rounds of 30 frames on the
held-out cameras, so a busy machine slows both alike), and the PSNR / FLIP of each against the field views the
run saved (the left panel of ``views/view_XX.png``, 8-bit). Frame times inside a run vary with what ran just
before; this is the fair comparison.

Usage: python benchmarks/playback.py RUN_FOLDER [RUN_FOLDER ...] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

import numpy as np
from PIL import Image

import neuras_distill as nd
from neuras_distill.bake.plain_texture import plain_bundle
from neuras_distill.flip_metric import flip
from neuras_distill.metrics import psnr
from neuras_distill.playback.renderer import BundleRenderer


def field_views(run: Path, cams) -> list[np.ndarray]:
    """The field renders a run saved: the first (W-wide) panel of each ``views/view_XX.png``, float32 [0, 1]."""
    w = int(cams.width)
    return [np.asarray(Image.open(run / "views" / f"view_{i:02d}.png").convert("RGB"), np.float32)[:, :w] / 255.0
            for i in range(len(cams))]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    for run in args.runs:
        cams = nd.Cameras.from_json(json.loads((run / "cameras.json").read_text())["test"])
        bundle = nd.load_bundle(run / "bundle")
        refs = field_views(run, cams)
        out = {"run": str(run)}
        players = {"hard": BundleRenderer(bundle, silhouette_blend=False),
                   "soft": BundleRenderer(bundle, silhouette_blend=True)}
        if bundle.plain_rgb is not None:       # the report's baseline: same mesh, passes and cameras, no sky
            players["plain"] = BundleRenderer(plain_bundle(bundle, bundle.plain_rgb.astype(np.float32) / 255.0))
        try:
            for name, player in players.items():
                images = [player.render(cams, i) for i in range(len(cams))]
                out[f"psnr_{name}"] = float(np.mean([psnr(a, b) for a, b in zip(images, refs)]))
                out[f"flip_{name}"] = float(np.mean([flip(a, b)[0] for a, b in zip(images, refs)]))
            times = {name: [] for name in players}
            for _ in range(args.repeats):
                for name, player in players.items():
                    times[name].append(player.time_frames(cams, warmup=5, frames=30)["median_ms"])
        finally:
            for player in players.values():
                player.release()
        for name, values in times.items():
            out[f"ms_{name}"] = statistics.median(values)
        out["soft_overhead"] = out["ms_soft"] / out["ms_hard"] - 1.0
        if "ms_plain" in out:
            played = out["ms_soft" if bundle.manifest.get("silhouette_blend", False) else "ms_hard"]
            out["neural_overhead"] = played / out["ms_plain"] - 1.0
        out["bundle_plays_soft"] = bool(bundle.manifest.get("silhouette_blend", False))
        print(json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in out.items()}), flush=True)


if __name__ == "__main__":
    main()
