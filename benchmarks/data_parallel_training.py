"""Training throughput of ``fit`` in one process and data-parallel over ``--nproc`` CPU processes (gloo).

    python benchmarks/data_parallel_training.py [--nproc 2] [--steps 300] [--batches 32,128]

For each batch size (patches of 16x16 pixels per step): the same model (a 512² x 8 atlas, the default shader)
trained for ``--steps`` steps on a synthetic G-buffer (24 views of 256², a smooth colour over the atlas) by one
process with all the machine's threads and by ``--nproc`` processes (each ``cpu_count / nproc`` threads,
gradients summed every step); steps/s, pixels/s per process, and the final training-batch PSNR of both. Run it
alone: two torch processes on a busy machine slow each other down.
"""

from __future__ import annotations

import argparse
import os

import numpy as np
import torch

from neuras_distill.config import TrainConfig
from neuras_distill.neural.model import NeuralTextureModel
from neuras_distill.neural.train import fit
from neuras_distill.neural.train_batches import TrainingPixels
from neuras_distill.pipeline.parallel import RenderPool
from neuras_distill.scenes.analytic import SphereSDF


def synthetic_views(n: int = 24, res: int = 256, seed: int = 0):
    """uv (n, res, res, 2), coverage, unit view directions (n, res, res, 3) and targets (n, res, res, 3)."""
    rng = np.random.default_rng(seed)
    ys, xs = np.meshgrid((np.arange(res) + 0.5) / res, (np.arange(res) + 0.5) / res, indexing="ij")
    uv = np.zeros((n, res, res, 2), np.float32)
    dirs = np.zeros((n, res, res, 3), np.float32)
    for k in range(n):
        o = rng.uniform(0, 0.5, 2)
        uv[k, ..., 0], uv[k, ..., 1] = o[0] + 0.5 * xs, o[1] + 0.5 * ys
        d = np.stack([xs - 0.5, ys - 0.5, -np.ones_like(xs)], -1)
        dirs[k] = d / np.linalg.norm(d, axis=-1, keepdims=True)
    u, v = uv[..., 0], uv[..., 1]
    tgt = np.stack([0.5 + 0.3 * np.sin(12 * u) * np.cos(9 * v), 0.5 + 0.3 * np.cos(11 * v + u),
                    0.4 + 0.2 * u + 0.2 * v], -1).astype(np.float32)
    return uv, np.ones((n, res, res), bool), dirs, tgt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nproc", type=int, default=2)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--batches", default="32,128", help="patches per step, comma-separated")
    args = ap.parse_args()
    data = synthetic_views()
    print(f"{os.cpu_count()} CPUs, torch {torch.__version__}, {args.steps} steps, 16x16 patches")
    print(f"{'patches':>8} {'procs':>5} {'steps/s':>8} {'px/s/proc':>10} {'batch PSNR':>10}")
    with RenderPool(SphereSDF(radius=0.5), args.nproc, timeout_s=600) as pool:
        for batch in (int(b) for b in args.batches.split(",")):
            for nproc in (1, args.nproc):
                torch.manual_seed(0)
                model = NeuralTextureModel(512, 512, feature_dim=8, num_codes=256)
                kwargs = dict(steps=args.steps, config=TrainConfig(batch_patches=batch, patch=16), progress=False)
                if nproc == 1:
                    log = fit(model, TrainingPixels(*data), num_threads=os.cpu_count(), **kwargs)
                else:
                    log = pool.fit(model, TrainingPixels(*data), **kwargs)
                print(f"{batch:>8} {nproc:>5} {log.steps_per_second:>8.1f} {log.pixels_per_second_per_process:>10.0f} "
                      f"{log.entries[-1]['psnr']:>10.2f}")


if __name__ == "__main__":
    main()
