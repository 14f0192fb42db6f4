"""Where a ball's error sits: held-out pixels binned by how close their ray passes the ball's centre.

For a run folder of a ball scene (``from-synthetic gradient-ball``; for another frame pass ``--center``), re-plays
the bundle at the held-out cameras (``cameras.json``), compares it with the field's held-out renders the run
stored (``work/field_views``), and prints per bin of p (the ray's closest distance to the centre, world units)
the pixel count, PSNR and share of the squared error; with ``--train`` the same at the training cameras
against the teacher's renders (``work/teacher``), which tells a representation limit (poor on training views
too) from a generalisation gap. It showed that the gradient ball's remaining interior error is the
core's grazing rim (p 0.46-0.477) and the band the shell's first ring (docs/decisions.md).

Usage: python benchmarks/ball_error_profile.py RUN_FOLDER [--center X,Y,Z] [--train]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from neuras_distill.bake.bundle import load_bundle
from neuras_distill.playback.renderer import BundleRenderer
from neuras_distill.render.cameras import Cameras

EDGES = (0.0, 0.40, 0.44, 0.46, 0.47, 0.475, 0.48, 0.49, 0.50, 0.51, 0.52, 0.53, 0.54, 0.56, 0.60)


def stored_images(run: Path, stage: str) -> np.ndarray:
    """(N, H, W, 3) float images of a stored stage (``field_views`` or ``teacher``), memory-mapped."""
    folders = sorted((run / "work" / stage).glob("*/images.npy"))
    if not folders:
        raise SystemExit(f"{run} has no stored {stage} stage (run without --no-keep-work)")
    return np.load(folders[0], mmap_mode="r")


def closest_approach(cams: Cameras, i: int, center: np.ndarray) -> np.ndarray:
    """(H, W) distance of each pixel's ray from ``center`` at its closest approach."""
    o, d = (t.numpy().astype(np.float64) for t in cams.rays(i))
    v = center - o
    t = (v * d).sum(-1, keepdims=True)
    return np.linalg.norm(v - t * d, axis=-1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--center", default="0,0,0.5", help="the ball's centre in the run's world frame")
    ap.add_argument("--train", action="store_true", help="training cameras against the teacher's renders")
    args = ap.parse_args()
    center = np.array([float(x) for x in args.center.split(",")])
    split = "train" if args.train else "test"
    cams = Cameras.from_json(json.loads((args.run / "cameras.json").read_text())[split])
    references = stored_images(args.run, "teacher" if args.train else "field_views")
    total, count = np.zeros(len(EDGES) - 1), np.zeros(len(EDGES) - 1)
    with BundleRenderer(load_bundle(args.run / "bundle")) as renderer:
        for i in range(len(cams)):
            image = renderer.render(cams, i).astype(np.float64)
            reference = np.asarray(references[i], np.float64)
            err = ((image - reference) ** 2).mean(-1).ravel()
            k = np.digitize(closest_approach(cams, i, center).ravel(), EDGES) - 1
            ok = (k >= 0) & (k < len(EDGES) - 1)
            np.add.at(total, k[ok], err[ok])
            np.add.at(count, k[ok], 1)
    print(f"{split} views of {args.run}: p (distance of the ray from the centre), pixels, PSNR, share of error")
    for j in range(len(EDGES) - 1):
        mse = total[j] / max(count[j], 1)
        print(f"  {EDGES[j]:.3f}-{EDGES[j + 1]:.3f}  {int(count[j]):9d}  {-10 * np.log10(mse + 1e-12):6.2f} dB  "
              f"{total[j] / max(total.sum(), 1e-30):.3f}")


if __name__ == "__main__":
    main()
