"""Where a run's held-out error sits against the atlas's texel footprint: what a feature pyramid could buy.

A mipmapped neural texture changes only the pixels where the atlas is *minified*: a pixel
covering more than one texel (GL's level of detail ``lambda = log2(max(|d(uv)/dx|, |d(uv)/dy|) * texels) > 0``)
would read a coarser level. Pixels where the atlas is magnified (``lambda < 0``: the demo's 256² atlas from
640x360 training views played at 1920x1080) read level 0 with or without a pyramid; their blur is the atlas's
texel density, not its filtering. So the squared error on minified pixels bounds what a pyramid can remove.

For a finished run folder: rasterizes the bundle's mesh for the held-out cameras (``cameras.json``) at the
evaluation's resolution, takes ``lambda`` per pixel from the uv differences to the neighbouring pixel on the same
face (right or left, below or above; pixels on one-pixel faces are left out), plays the bundle
(``BundleRenderer``) and reads the field's held-out frames the run stored (``work/field_views``; run with
``--keep-work`` or from a run whose work area is still there). Prints per bucket of ``lambda``: the share of the
mesh's pixels, the share of the whole frames' squared error, and the PSNR there; the same for the mesh's pixels
without a lambda (one-pixel faces, a face's last row or column) and for the pixels off the mesh (background,
skyboxes); then the whole frames' PSNR if the minified pixels' error were gone (the most a pyramid could give).

Usage: python benchmarks/texel_footprint.py RUN_FOLDER [--max-views 8]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

#: Buckets of GL's level of detail lambda (log2 texels per pixel along the longer screen axis).
BUCKETS = ((-np.inf, -1.0, "magnified > 2x"), (-1.0, 0.0, "magnified 1-2x"), (0.0, 1.0, "minified 1-2x"),
           (1.0, np.inf, "minified > 2x"))


def level_of_detail(uv: np.ndarray, face_id: np.ndarray, height: int, width: int) -> np.ndarray:
    """(H', W') GL level of detail per pixel of one view: ``log2`` of the longer of the uv steps (in texels of an
    ``height`` x ``width`` atlas) to the next pixel right and down, each taken on the same face (the forward
    difference, else the backward one); NaN where either has no same-face neighbour or the face is absent.

    Args:
        uv: (H', W', 2) float32 G-buffer uvs; face_id: (H', W') int, -1 where uncovered.
    """
    scale = np.array([width, height], np.float64)
    steps = []
    for axis in (1, 0):                                   # x (columns), then y (rows)
        fwd = np.full(uv.shape, np.nan)
        same = np.zeros(face_id.shape, bool)
        a, b = [slice(None)] * 2, [slice(None)] * 2
        a[axis], b[axis] = slice(0, -1), slice(1, None)
        diff = (uv[tuple(b)] - uv[tuple(a)]).astype(np.float64) * scale
        ok = (face_id[tuple(a)] == face_id[tuple(b)]) & (face_id[tuple(a)] >= 0)
        fwd[tuple(a)] = np.where(ok[..., None], diff, np.nan)       # forward difference at the first pixel
        same[tuple(a)] = ok
        bwd = np.full(uv.shape, np.nan)
        bwd[tuple(b)] = np.where(ok[..., None], diff, np.nan)       # backward difference at the second
        steps.append(np.linalg.norm(np.where(same[..., None], fwd, bwd), axis=-1))
    longest = np.fmax(steps[0], steps[1])
    longest = np.where(np.isnan(steps[0]) | np.isnan(steps[1]), np.nan, longest)
    with np.errstate(divide="ignore"):
        return np.where(face_id >= 0, np.log2(np.maximum(longest, 1e-12)), np.nan)


def field_frames(run: Path, count: int, height: int, width: int) -> np.ndarray:
    """(count, H, W, 3) float32 held-out field frames stored in the run's work area (the newest that fit)."""
    found = sorted((run / "work" / "field_views").glob("*/images.npy"), key=lambda p: p.stat().st_mtime)
    for path in reversed(found):
        images = np.load(path, mmap_mode="r")
        if images.shape[:3] == (count, height, width):
            return np.asarray(images, np.float32)
    raise SystemExit(f"{run}: no stored field frames of {count} views at {width}x{height} under work/field_views "
                     "(run the scene again with --keep-work)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--max-views", type=int, default=8)
    args = parser.parse_args()

    from neuras_distill.bake.bundle import load_bundle
    from neuras_distill.geometry.mesh import MeshData
    from neuras_distill.playback.projection import shift_cameras
    from neuras_distill.playback.rasterize import rasterize_gbuffer
    from neuras_distill.playback.renderer import BundleRenderer
    from neuras_distill.render.cameras import Cameras

    bundle = load_bundle(args.run / "bundle")
    cams = Cameras.from_json(json.loads((args.run / "cameras.json").read_text())["test"])
    field = field_frames(args.run, len(cams), cams.height, cams.width)
    n = min(len(cams), args.max_views)
    height, width = bundle.textures["u_index"].shape
    mesh = bundle.mesh
    gbuffer = rasterize_gbuffer(MeshData(mesh.vertices, mesh.faces, mesh.uvs, core_faces=mesh.core_faces),
                                shift_cameras(cams, bundle.origin),
                                cull_back_faces=bool(bundle.manifest.get("cull_back_faces", False)))
    lods, errors = [], []
    with BundleRenderer(bundle) as player:
        for i in range(n):
            played = player.render(cams, i)
            errors.append(((played - field[i]) ** 2).sum(-1))
            lods.append(level_of_detail(gbuffer.uv[i], gbuffer.face_id[i], height, width))
    lod, err = np.stack(lods), np.stack(errors)
    total = float(err.sum())
    mesh_pixels = int(np.isfinite(lod).sum())
    rows = {}
    for lo, hi, name in BUCKETS:
        sel = np.isfinite(lod) & (lod >= lo) & (lod < hi)
        share_px = float(sel.sum()) / max(mesh_pixels, 1)
        share_err = float(err[sel].sum()) / max(total, 1e-30)
        mse = float(err[sel].mean()) / 3.0 if sel.any() else float("nan")
        rows[name] = {"pixels": share_px, "error": share_err,
                      "psnr": -10.0 * np.log10(mse) if sel.any() and mse > 0 else None}
        print(f"{name:>16}: {100 * share_px:5.1f}% of the mesh's pixels, {100 * share_err:5.1f}% of the squared "
              f"error" + (f", {rows[name]['psnr']:.2f} dB there" if rows[name]["psnr"] is not None else ""))
    coverage = np.stack([gbuffer.face_id[i] >= 0 for i in range(n)])
    for name, sel in (("mesh, no lambda", coverage & ~np.isfinite(lod)), ("not on the mesh", ~coverage)):
        share_err = float(err[sel].sum()) / max(total, 1e-30)
        psnr = -10.0 * np.log10(float(err[sel].mean()) / 3.0) if sel.any() and err[sel].mean() > 0 else None
        rows[name] = {"pixels_of_frame": float(sel.mean()), "error": share_err, "psnr": psnr}
        print(f"{name:>16}: {100 * float(sel.mean()):5.1f}% of the frames' pixels, {100 * share_err:5.1f}% of the "
              "squared error" + (f", {psnr:.2f} dB there" if psnr is not None else ""))
    mse_all = total / err.size / 3.0
    minified = np.isfinite(lod) & (lod >= 0.0)
    mse_without = (total - float(err[minified].sum())) / err.size / 3.0
    out = {"views": n, "resolution": [cams.width, cams.height], "atlas": [width, height],
           "psnr": -10.0 * np.log10(mse_all), "psnr_without_minified_error": -10.0 * np.log10(max(mse_without, 1e-30)),
           "median_lod": float(np.nanmedian(lod)), "buckets": rows}
    print(f"whole frames {out['psnr']:.2f} dB; with no error on the minified pixels (the most a pyramid could give) "
          f"{out['psnr_without_minified_error']:.2f} dB; median level of detail {out['median_lod']:.2f}")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
