"""What a texture pinned to one sphere can score on the gradient ball, with no learning at all.

The gradient ball's colour is constant along each radius, so an ideal texture on a sphere of radius r shows,
at each pixel, the field's colour where the pixel's ray meets that sphere. Against the volume-rendered
field, the PSNR over interior pixels (``metrics.interior_mask``) says how much parallax through the soft
fringe costs a mesh at that radius: the ceiling of any opaque core there (``docs/decisions.md``, "Where
the colour comes from"). The surface level's mesh sits at r = 0.5 (the silhouette), the colour level's at
about 0.478.

    python benchmarks/colour_parallax.py [--width 640] [--radii 0.5,0.49,0.48,0.47,0.46,0.45]

Prints one line per radius: the PSNR of each held-out view and their mean.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from neuras_distill.metrics import interior_mask, psnr, silhouette_band
from neuras_distill.pipeline import evaluate
from neuras_distill.render.volume import VolumeRenderer
from neuras_distill.scenes.gradient_ball import make_gradient_ball


def sphere_hits(origins: np.ndarray, dirs: np.ndarray, centre: np.ndarray, radius: float):
    """(P, 3) ray origins and unit directions -> ((P,) bool hit, (P, 3) first intersection with the sphere)."""
    oc = origins - centre
    b = (oc * dirs).sum(-1)
    disc = b * b - ((oc * oc).sum(-1) - radius * radius)
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    return disc > 0, origins + dirs * t[:, None]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--radii", default="0.5,0.49,0.48,0.47,0.46,0.45")
    args = ap.parse_args()
    torch.set_num_threads(2)
    field = make_gradient_ball()
    _, test = field.default_cameras(48, 1920, 1080).split(12)
    test = test.resized(args.width)
    views = evaluate.render_field_views(VolumeRenderer(field, num_steps=256), test)
    centre = field.center.double().numpy()
    print(f"gradient ball, {len(test)} held-out views at {test.width}x{test.height}, interior PSNR of the field's "
          "colour on a sphere of radius r")
    for radius in (float(r) for r in args.radii.split(",")):
        scores = []
        for i, (image, opacity) in enumerate(zip(views.images, views.opacities)):
            inside = interior_mask(opacity, silhouette_band(opacity))
            o, d = (t.double().numpy().reshape(-1, 3) for t in test.rays(i))
            hit, points = sphere_hits(o, d, centre, radius)
            hit &= inside.reshape(-1)
            oracle = np.array(image, dtype=np.float32).reshape(-1, 3)
            with torch.no_grad():
                oracle[hit] = field.radiance(torch.as_tensor(points[hit], dtype=torch.float32),
                                             torch.as_tensor(d[hit], dtype=torch.float32)).numpy()
            scores.append(psnr(oracle.reshape(image.shape), image, inside))
        print(f"r = {radius:.3f}: " + " ".join(f"{s:6.2f}" for s in scores) + f"   mean {np.mean(scores):6.2f} dB")


if __name__ == "__main__":
    main()
