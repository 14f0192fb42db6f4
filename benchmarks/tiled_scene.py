"""A tiled scene against its field at the scene's held-out cameras: every tile drawn together.

    python benchmarks/tiled_scene.py CITY [--width W] [--views N] [--single RUN_DIR] [--out DIR]

CITY is a folder of ``neuras-distill tiles plan`` whose tiles ran (``tiles run``). The field is volume-rendered
at the plan's held-out cameras (``--width``: their width, default 320; the teacher's steps of the whole scene);
the tiles are drawn together by ``playback/tiles.TilesRenderer`` (their cut bundles, one depth buffer). Prints,
per view and as the mean: PSNR of the tiles against the field over the whole frame, in the band within 4 pixels
of a seam (two tiles meeting on screen at nearly the same depth: one surface crossing a tile boundary), and
elsewhere; with ``--single RUN_DIR`` (a run of the same scene and
cameras, e.g. ``neuras-distill from-synthetic NAME``) the same for its bundle drawn without its skyboxes and with
them. ``--out DIR`` writes field | tiles | tile ids | 8x error PNGs per view. Nothing else should run meanwhile:
the field's renders are timed by nothing here, but the figures of a busy machine are still the same; the
tile runs' own figures are not (their training plans measure speed).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

BAND_PX = 4


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    d = (np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2
    mse = float(d[mask].mean()) if mask is not None else float(d.mean())
    return float("inf") if mse == 0 else -10.0 * np.log10(mse)


def boundary_band(ids: np.ndarray, depth: np.ndarray, width: int = BAND_PX, depth_ratio: float = 0.03
                  ) -> np.ndarray:
    """(H, W) bool: pixels within ``width`` pixels (a square) of a seam: two 4-neighbours that show different
    tiles at nearly the same depth (within ``depth_ratio``), where one surface crosses a tile boundary (not a
    silhouette of one tile against another behind it)."""
    edge = np.zeros(ids.shape, bool)
    pairs = (((slice(1, None), slice(None)), (slice(None, -1), slice(None))),
             ((slice(None), slice(1, None)), (slice(None), slice(None, -1))))
    for a, b in pairs:
        seam = ((ids[a] != ids[b]) & (ids[a] >= 0) & (ids[b] >= 0)
                & (np.abs(depth[a] - depth[b]) < depth_ratio * np.minimum(depth[a], depth[b])))
        edge[a] |= seam
        edge[b] |= seam
    band = edge.copy()
    for _ in range(width):
        grown = band.copy()
        grown[1:] |= band[:-1]
        grown[:-1] |= band[1:]
        grown[:, 1:] |= band[:, :-1]
        grown[:, :-1] |= band[:, 1:]
        band = grown
    return band


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("city", type=Path)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--views", type=int, default=0, help="the first N held-out views (default all)")
    ap.add_argument("--single", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()

    import torch
    from PIL import Image

    from neuras_distill.bake.bundle import load_bundle
    from neuras_distill.playback.renderer import BundleRenderer
    from neuras_distill.playback.tiles import TilesRenderer
    from neuras_distill.render.cameras import Cameras
    from neuras_distill.render.volume import VolumeRenderer
    from neuras_distill.tiles.plan import read_plan
    from neuras_distill.tiles.run import load_plan_source

    torch.set_num_threads(2)
    plan = read_plan(args.city)
    field, _ = load_plan_source(plan)
    cams = Cameras.from_json(json.loads((args.city / plan["cameras"]).read_text()))[plan["test"]]
    if args.views:
        cams = cams[list(range(min(args.views, len(cams))))]
    width = min(args.width, cams.width)
    cams = cams.resized(width, round(cams.height * width / cams.width))
    field_renderer = VolumeRenderer(field, num_steps=plan["settings"]["teacher_steps"])
    tiles = [load_bundle(args.city / "tiles" / str(t["index"]) / "tile") for t in plan["tiles"]]
    single = load_bundle(args.single / "bundle") if args.single else None
    rows = []
    with TilesRenderer(tiles) as player:
        single_player = BundleRenderer(single) if single is not None else None
        for i in range(len(cams)):
            with torch.no_grad():
                want = field_renderer.render(cams, i)["rgb"]
            want = np.round(np.clip(want, 0, 1) * 255) / 255
            got = player.render(cams, i)
            ids, depth = player.render_ids(cams, i)
            band = boundary_band(ids, depth)
            row = {"view": i, "tiles": psnr(got, want), "band": psnr(got, want, band) if band.any() else None,
                   "rest": psnr(got, want, ~band), "band_share": float(band.mean())}
            if single_player is not None:
                mesh_only = single_player.render(cams, i, skybox=False)
                row["single_mesh"] = psnr(mesh_only, want)
                row["single_band"] = psnr(mesh_only, want, band) if band.any() else None
                row["single_rest"] = psnr(mesh_only, want, ~band)
                row["single"] = psnr(single_player.render(cams, i), want)
            rows.append(row)
            if args.out:
                args.out.mkdir(parents=True, exist_ok=True)
                palette = np.random.default_rng(0).uniform(0.2, 1.0, (len(tiles) + 1, 3))
                id_image = np.where(ids[..., None] >= 0, palette[np.maximum(ids, 0)], 0.0)
                id_image[band] *= 0.5
                err = np.clip(np.abs(got - want) * 8, 0, 1)
                Image.fromarray((np.concatenate([want, got, id_image, err], 1) * 255).astype(np.uint8)).save(
                    args.out / f"view{i}.png")
        if single_player is not None:
            single_player.release()
    for row in rows:
        print(json.dumps({k: (round(v, 2) if isinstance(v, float) else v) for k, v in row.items()}))

    def mean(key):
        vals = [r[key] for r in rows if r.get(key) is not None]
        return f"{np.mean(vals):.2f}" if vals else "-"
    print(f"{len(tiles)} tiles, {len(rows)} held-out views at {cams.width}x{cams.height}: tiles {mean('tiles')} dB "
          f"(band within {BAND_PX} px of a tile boundary {mean('band')} dB on {100 * np.mean([r['band_share'] for r in rows]):.1f}% "
          f"of the pixels, elsewhere {mean('rest')} dB)"
          + (f"; one run of the scene: {mean('single_mesh')} dB without its skyboxes (the same band "
             f"{mean('single_band')}, elsewhere {mean('single_rest')}), {mean('single')} with them"
             if single is not None else ""))


if __name__ == "__main__":
    main()
