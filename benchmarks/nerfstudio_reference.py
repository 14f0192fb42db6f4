"""A distilled nerfstudio run against nerfstudio's own renders: the teacher and the bundle, inside and outside the
foreground box, with crops of the far background.

    python benchmarks/nerfstudio_reference.py FIXTURE RUN_DIR [--out FOLDER]

FIXTURE is a nerfstudio run folder holding ``reference_renders.npz`` (nerfstudio's renders of held-out cameras:
``rgb`` (N, H, W, 3) uint8, ``c2w`` (N, 4, 4) in the dataset's frame, ``focal``; as
``scripts/make_nerfstudio_unbounded_fixture.py`` stores them; ``seconds``, when stored, the time nerfstudio's
renderer took for each). RUN_DIR is a run of ``neuras-distill from-nerfstudio FIXTURE`` (its ``bundle/``). Prints
PSNR of teacher and bundle against nerfstudio's renders over the whole frame, inside the box (where the teacher's
box opacity is at least 0.5, as the report splits) and outside it, the holes of the bundle's mesh (the teacher's
box opacity above 0.5 where the mesh covers no pixel, ``metrics.hole_fraction``), and the seconds a view took
nerfstudio's renderer and our teacher (the torch threads of this process); writes
``nerfstudio_teacher_bundle.png`` (rows: views; columns: nerfstudio | teacher | bundle) and
``far_crops.png`` (the same columns, native-resolution crops of the top third of each frame: the skyline and
sky) into ``--out`` (default RUN_DIR).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from neuras_distill.bake.bundle import load_bundle
from neuras_distill.metrics import hole_fraction, psnr
from neuras_distill.pipeline.evaluate import INSIDE_BOX_OPACITY
from neuras_distill.playback.projection import shift_cameras
from neuras_distill.playback.rasterize import rasterize_gbuffer
from neuras_distill.playback.renderer import BundleRenderer
from neuras_distill.registry import load_field
from neuras_distill.render.cameras import Cameras
from neuras_distill.render.volume import VolumeRenderer


def reference_cameras(fixture: Path) -> tuple[Cameras, np.ndarray]:
    """(cameras, rgb (N, H, W, 3) float32 in 0..1) of the fixture's nerfstudio renders."""
    ref = np.load(fixture / "reference_renders.npz")
    rgb = ref["rgb"].astype(np.float32) / 255.0
    n, h, w, _ = rgb.shape
    f = float(ref["focal"])
    return Cameras(torch.from_numpy(ref["c2w"]).float(), f, f, w / 2, h / 2, w, h), rgb


def split_psnr(image: np.ndarray, reference: np.ndarray, inside: np.ndarray) -> dict:
    """PSNR (dB) over all pixels, inside (``inside`` (N, H, W) bool) and outside."""
    return {"all": psnr(image, reference), "inside": psnr(image[inside], reference[inside]),
            "outside": psnr(image[~inside], reference[~inside])}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("fixture", type=Path)
    parser.add_argument("run", type=Path)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    out = args.out or args.run
    out.mkdir(parents=True, exist_ok=True)
    report = json.loads((args.run / "report.json").read_text())
    teacher_cfg = report["config"]["teacher"]
    cameras, reference = reference_cameras(args.fixture)
    stored = np.load(args.fixture / "reference_renders.npz")
    field = load_field(args.fixture / "config.yml")
    teacher = VolumeRenderer(field, num_steps=int(teacher_cfg["num_steps"]), far_steps=int(teacher_cfg["far_steps"]))
    t0 = time.perf_counter()
    renders = [teacher.render(cameras, i) for i in range(len(cameras))]
    teacher_s = (time.perf_counter() - t0) / len(cameras)
    taught = np.stack([r["rgb"] for r in renders])
    inside = np.stack([r["opacity"] for r in renders]) >= INSIDE_BOX_OPACITY
    bundle = load_bundle(args.run / "bundle")
    player = BundleRenderer(bundle)
    played = np.stack([player.render(cameras, i) for i in range(len(cameras))])
    local = shift_cameras(cameras, bundle.origin)
    cull = bool(report["config"]["geometry"]["cull_back_faces"])
    coverage = np.stack([rasterize_gbuffer(bundle.mesh, local[i], cull_back_faces=cull).coverage[0]
                         for i in range(len(cameras))])
    holes = hole_fraction(np.stack([r["opacity"] for r in renders]), coverage)
    rows = {"teacher vs nerfstudio": split_psnr(taught, reference, inside),
            "bundle vs nerfstudio": split_psnr(played, reference, inside),
            "bundle vs teacher": split_psnr(played, taught, inside)}
    print(f"{len(cameras)} views at {cameras.width}x{cameras.height}; inside the box: {100 * inside.mean():.1f}% "
          f"of pixels; teacher {teacher_cfg['num_steps']} + {teacher_cfg['far_steps']} far steps, "
          f"{teacher_s:.1f} s a view ({torch.get_num_threads()} threads)"
          + (f"; nerfstudio {np.median(stored['seconds']):.1f} s a view (median; "
             f"{int(stored['threads'])} threads)" if "seconds" in stored else ""))
    print(f"holes (teacher box opacity > 0.5, no mesh): {100 * holes:.2f}% of pixels")
    for name, v in rows.items():
        print(f"{name:22s} all {v['all']:6.2f} dB   inside {v['inside']:6.2f} dB   outside {v['outside']:6.2f} dB")
    views = range(min(len(cameras), 4))
    grid = np.concatenate([np.concatenate([reference[i], taught[i], played[i]], 1) for i in views], 0)
    Image.fromarray((np.clip(grid, 0, 1) * 255 + 0.5).astype(np.uint8)).save(out / "nerfstudio_teacher_bundle.png")
    top = slice(0, cameras.height // 3)
    crops = np.concatenate([np.concatenate([reference[i][top], taught[i][top], played[i][top]], 1) for i in views], 0)
    Image.fromarray((np.clip(crops, 0, 1) * 255 + 0.5).astype(np.uint8)).save(out / "far_crops.png")


if __name__ == "__main__":
    main()
