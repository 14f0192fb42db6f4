"""Held-out PSNR of the same atlas trained under different vector-quantization schedules and atlas sides.

Prepares one scene once (teacher renders of the training and held-out views, marching-cubes mesh unwrapped
at each atlas side, G-buffers), then trains a NeuralTextureModel per variant on exactly those inputs and
scores its torch forward pass (what the GL bundle plays, see the parity figures in any report) against the
field's held-out renders. Variants: "vq@F" quantizes from fraction F of the run (1.0 = after training, the
default), "none" never quantizes (continuous features; such an atlas cannot be baked above 65535 texels).

Usage: python benchmarks/vq_schedule.py [--field tests/data/sdf/neus_bunny.pth] [--cameras
       tests/data/sdf/cameras_sphere.npz] [--size 400] [--steps 1500] [--sides 512] [--variants vq@0.15,vq@1,none]
       [--views 44] [--ssim-weight 0] [--out result.json]
Prints one line per (side, variant) and a final JSON line. About 1 min per variant at 1500 steps on a
2-core CPU for the 400^2 NeuS fixture (after ~3 min of teacher renders).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch


def prepare(args):
    """(field, train cameras, held-out cameras, teacher images, held-out images, background)."""
    from neuras_distill.pipeline import rules, evaluate
    from neuras_distill.registry import load_field
    from neuras_distill.render.volume import VolumeRenderer

    options = {}
    if args.cameras:
        options.update(cameras=args.cameras, width=args.size, height=args.size)
    field = load_field(Path(args.field), **options)
    cameras = field.cameras if getattr(field, "cameras", None) is not None else field.default_cameras(
        args.views, args.size, args.size)
    train, test = cameras.split(args.test_every)
    teacher = VolumeRenderer(field, num_steps=args.teacher_steps)
    train_images = np.stack(evaluate.render_field_timed(teacher, train)[0]).astype(np.float32)
    test_images = np.stack(evaluate.render_field_timed(teacher, test)[0]).astype(np.float32)
    return field, train, test, train_images, test_images, rules.background_color(field).numpy()


def gbuffers(field, train, test, side: int, args):
    from neuras_distill.config import GeometryConfig
    from neuras_distill.geometry.extract import extract_surface, unwrap_surface
    from neuras_distill.playback.rasterize import rasterize_gbuffer

    surface = extract_surface(field, train, GeometryConfig(grid_resolution=args.grid, face_budget=args.faces),
                              trial_resolution=side)
    mesh = unwrap_surface(surface, side)
    return (rasterize_gbuffer(mesh, train), rasterize_gbuffer(mesh, test),
            np.stack([train.rays(i)[1].numpy() for i in range(len(train))]).astype(np.float32),
            np.stack([test.rays(i)[1].numpy() for i in range(len(test))]).astype(np.float32))


def score(variant: str, side: int, data, args) -> dict:
    from neuras_distill.metrics import psnr
    from neuras_distill.neural.model import NeuralTextureModel
    from neuras_distill.config import TrainConfig
    from neuras_distill.neural.train import fit
    from neuras_distill.neural.train_batches import TrainingPixels

    (gb_train, gb_test, dirs_train, dirs_test), targets, test_images, bg = data
    torch.manual_seed(0)
    use_vq = variant != "none"
    warmup = float(variant.split("@", 1)[1]) if use_vq else 1.0
    model = NeuralTextureModel(side, side, feature_dim=8, num_codes=1024, hidden=16, num_layers=2, use_vq=use_vq)
    t0 = time.perf_counter()
    fit(model, TrainingPixels(gb_train.uv, gb_train.coverage, dirs_train, targets), steps=args.steps,
        config=TrainConfig(vq_warmup=warmup, ssim_weight=args.ssim_weight), progress=False, num_threads=args.threads)
    seconds = time.perf_counter() - t0
    psnrs = [psnr(model.render_gbuffer(gb_test.uv[i], gb_test.coverage[i], dirs_test[i], bg), test_images[i])
             for i in range(len(test_images))]
    return {"side": side, "variant": variant, "psnr": float(np.mean(psnrs)), "train_seconds": seconds}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--field", default="tests/data/sdf/neus_bunny.pth")
    p.add_argument("--cameras", default="tests/data/sdf/cameras_sphere.npz", help="'' for the field's own")
    p.add_argument("--size", type=int, default=400)
    p.add_argument("--views", type=int, default=44)
    p.add_argument("--test-every", type=int, default=12)
    p.add_argument("--teacher-steps", type=int, default=256)
    p.add_argument("--grid", type=int, default=192)
    p.add_argument("--faces", type=int, default=40000)
    p.add_argument("--steps", type=int, default=1500)
    p.add_argument("--sides", default="512")
    p.add_argument("--variants", default="vq@0.15,vq@1,none")
    p.add_argument("--ssim-weight", type=float, default=0.0, help="weight of the (1 - SSIM) loss term")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out")
    args = p.parse_args()

    field, train, test, targets, test_images, bg = prepare(args)
    rows = []
    for side in [int(s) for s in args.sides.split(",")]:
        data = (gbuffers(field, train, test, side, args), targets, test_images, bg)
        for variant in args.variants.split(","):
            row = score(variant, side, data, args)
            rows.append(row)
            print(f"{side:5d}^2  {variant:9s}  held-out PSNR {row['psnr']:6.2f} dB  "
                  f"({row['train_seconds']:.0f} s training)", flush=True)
    result = {"field": args.field, "steps": args.steps, "ssim_weight": args.ssim_weight, "views": [len(train), len(test)], "rows": rows,
              "torch": torch.__version__}
    print(json.dumps(result))
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
