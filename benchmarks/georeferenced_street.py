"""The street distilled at its own coordinates and moved to UTM-like ones, with the same settings and fixed steps.

A georeferenced capture's field subtracts its own centre in float64 before anything float32; ``TranslatedField``
does that for the embedded street (world = street + offset, cameras moved with it). Every float32 stage of the run
works relative to the scene's centre, so both runs should score alike; the float32 cameras of the shifted run sit up
to half a float32 step off (0.25 m at a northing of 4.2e6), so their views differ slightly.

Usage: python benchmarks/georeferenced_street.py OUT_DIR [--steps 1500] [--eval-width 480]
       [--offset 500000 4200000 50]
Prints one JSON line per run (PSNR, interior, faces, holes, origin) and the difference.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

import neuras_distill as nd
from neuras_distill.playback.projection import shift_cameras
from neuras_distill.scenes.street import make_street
from neuras_distill.stability.georeferenced import UTM_LIKE


class TranslatedField:
    """``inner`` moved by ``offset`` ((3,) float64): positions are taken back in float64 before the inner field
    sees them, as a georeferenced field's adapter does."""

    def __init__(self, inner, offset):
        self.inner = inner
        self.offset = torch.as_tensor(offset, dtype=torch.float64).reshape(3)
        self.kind = inner.kind
        self.aabb = torch.as_tensor(inner.aabb).double() + self.offset

    def _inner(self, x: torch.Tensor) -> torch.Tensor:
        return (x.double() - self.offset.to(x.device)).float()

    def geometry(self, x):
        return self.inner.geometry(self._inner(x))

    def radiance(self, x, d):
        return self.inner.radiance(self._inner(x), d)

    def default_cameras(self, *args, **kwargs):
        return shift_cameras(self.inner.default_cameras(*args, **kwargs), -self.offset.numpy())

    def __getattr__(self, name):
        if name in ("inv_s", "unbounded", "background", "background_color", "lane_shifts", "preset", "sun_dir"):
            return getattr(self.__dict__["inner"], name)
        raise AttributeError(name)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path)
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--eval-width", type=int, default=480)
    parser.add_argument("--offset", type=float, nargs=3, default=list(UTM_LIKE))
    args = parser.parse_args()
    rows = {}
    for name, field in (("street", make_street()), ("street at offset", TranslatedField(make_street(), args.offset))):
        cfg = nd.load_config("street", overrides={"train": {"steps": args.steps}, "eval": {"width": args.eval_width}})
        out = args.out / name.replace(" ", "-")
        result = nd.distill(field, None, cfg, out=out, progress=False, log=lambda m: None)
        rep = result.report
        rows[name] = {"psnr": rep["psnr"], "psnr_interior": rep.get("psnr_interior"),
                      "faces": rep["mesh_faces"], "hole_fraction": rep["hole_fraction"], "origin": rep["origin"],
                      "run": str(out)}
        print(json.dumps({"run": name, **rows[name]}), flush=True)
    a, b = rows["street"], rows["street at offset"]
    print(json.dumps({"psnr_difference_db": b["psnr"] - a["psnr"],
                      "faces_ratio": b["faces"] / a["faces"],
                      "origin_error": float(np.abs(np.asarray(b["origin"]) - np.asarray(a["origin"])
                                                - np.asarray(args.offset)).max())}))


if __name__ == "__main__":
    main()
