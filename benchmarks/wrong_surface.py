"""Which held-out pixels of a run see the wrong surface, and how much of the error they carry.

For a run of a synthetic scene with an SDF (``from-synthetic street|city|city-small|...``): sphere-traces the
field's SDF along every held-out pixel (the run's ``cameras.json``), casts the same rays against the bundle's
mesh (libigl), and calls a pixel wrong where the two depths differ by more than ``--tolerance`` (relative) or
one of them hits nothing. With the run's side-by-side images (``views/view_NN.png``: field | bundle | ...) it
splits the squared error between wrong-surface and right-surface pixels: if the wrong ones carry most of it,
the mesh is what holds the run back, otherwise the texture is. The city's decimation was found this way
(docs/decisions.md, "Cleanup and decimation").

Usage: python benchmarks/wrong_surface.py RUN_FOLDER --scene city [--tolerance 0.03] [--max-views 16]
Prints one line per held-out view and a final JSON line. About 10 s per 640x360 view of the city on 2 cores.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

MAX_DISTANCE = 3000.0     # world units: rays that travel further hit the sky
HIT_EPSILON = 0.01        # world units: |SDF| below which a traced ray has hit
MIN_STEP = 0.02           # world units: smallest sphere-tracing step (bounds the steps near grazing surfaces)


def trace_sdf(sdf, origins: torch.Tensor, dirs: torch.Tensor, iterations: int = 400) -> np.ndarray:
    """(R,) distance along unit ``dirs`` (R, 3) from ``origins`` (R, 3) to the SDF's zero set (world units),
    inf where the ray leaves ``MAX_DISTANCE``. ``sdf``: (N, 3) world points -> (N,) signed distances."""
    t = torch.zeros(len(origins), dtype=torch.float32)
    alive = torch.ones(len(origins), dtype=torch.bool)
    with torch.no_grad():
        for _ in range(iterations):
            idx = alive.nonzero().squeeze(1)
            if len(idx) == 0:
                break
            d = sdf(origins[idx] + t[idx, None] * dirs[idx]).float()
            t[idx] += d.clamp(min=MIN_STEP) * 0.9
            alive[idx[(d < HIT_EPSILON) | (t[idx] > MAX_DISTANCE)]] = False
    out = t.numpy().astype(np.float64)
    out[out > MAX_DISTANCE] = np.inf
    return out


def view_panels(path: Path, width: int) -> tuple[np.ndarray, np.ndarray]:
    """The field and bundle panels (H, W, 3) in [0, 1] of a side-by-side image (panels ``width`` wide, 4 px
    apart), as ``pipeline.evaluate._strip`` writes them."""
    from PIL import Image

    img = np.asarray(Image.open(path).convert("RGB")).astype(np.float64) / 255.0
    return img[:, :width], img[:, width + 4:2 * width + 4]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--scene", required=True, help="the from-synthetic scene name of the run")
    parser.add_argument("--tolerance", type=float, default=0.03, help="relative depth difference called wrong")
    parser.add_argument("--max-views", type=int, default=16)
    args = parser.parse_args()

    from neuras_distill.geometry.raycast import cast_rays, raycasting_scene
    from neuras_distill.render.cameras import Cameras
    from neuras_distill.scenes.synthetic import make_scene

    field = make_scene(args.scene, kind="sdf")
    cams = Cameras.from_json(json.loads((args.run / "cameras.json").read_text())["test"])
    mesh = np.load(args.run / "bundle" / "mesh.npz")
    origin = np.asarray(json.loads((args.run / "bundle" / "manifest.json").read_text()).get("origin", [0, 0, 0]))
    scene = raycasting_scene(mesh["vertices"].astype(np.float64) + origin, mesh["faces"])
    rows = []
    for i in range(min(len(cams), args.max_views)):
        o, d = cams.rays(i)
        h, w = o.shape[:2]
        o, d = o.reshape(-1, 3), d.reshape(-1, 3)
        truth = trace_sdf(field.geometry, o, d)
        _, t_mesh = cast_rays(scene, np.concatenate([o.numpy(), d.numpy()], axis=1))
        t_mesh = t_mesh.astype(np.float64)
        both = np.isfinite(truth) & np.isfinite(t_mesh)
        close = np.zeros_like(both)
        close[both] = np.abs(t_mesh[both] - truth[both]) <= args.tolerance * truth[both]
        wrong = ~close & (np.isfinite(truth) | np.isfinite(t_mesh))
        row = {"view": i, "wrong_fraction": float(wrong.mean())}
        image = args.run / "views" / f"view_{i:02d}.png"
        if image.is_file():
            a, b = view_panels(image, w)
            se = ((a - b) ** 2).mean(axis=-1).reshape(-1)
            total = float(se.sum())
            row["error_share_wrong"] = float(se[wrong].sum() / total) if total > 0 else 0.0
            row["psnr_right_surface"] = float(-10 * np.log10(max(se[~wrong].mean(), 1e-12))) if (~wrong).any() else None
        rows.append(row)
        print(json.dumps(row), flush=True)
    mean = {k: float(np.mean([r[k] for r in rows if r.get(k) is not None]))
            for k in ("wrong_fraction", "error_share_wrong", "psnr_right_surface")
            if any(r.get(k) is not None for r in rows)}
    print(json.dumps({"views": len(rows), "tolerance": args.tolerance, **mean}))


if __name__ == "__main__":
    main()
