"""The tileset streamed by the 3dtiles page against the tiles drawn by TilesRenderer, and against one bundle of the
whole scene in our web player.

For CITY (a ``tiles plan`` folder whose tiles ran, merged into CITY/tileset) and optionally a single run of the
same scene (``--single RUN``): exports the page (``export --format 3dtiles``) and, with ``--single``, the run's
bundle as the web player's folder; serves both; opens them in headless Chromium (as the tests: Debian's chromium
through selenium, WebGL2 on SwiftShader) at the plan's held-out cameras (``--cameras``, resized to ``--width``).
Prints per camera:

* the tiles the page drew (content per level), the tiles it loaded and the bytes it fetched, against the tileset;
* PSNR of the page against ``TilesRenderer`` drawing the same tiles at the same levels, and drawing every tile at
  full detail;
* frame times: ``window.neurasTimeFrames(n)`` of the page and, with ``--single``, of the web player playing the
  single run's bundle, in interleaved rounds, their medians and ratio (SwiftShader frame times: a CPU's).

Usage: python benchmarks/tiles_page.py CITY --three .tools/node_modules/three
           --tiles-renderer .tools/node_modules/3d-tiles-renderer [--single RUN] [--cameras 0,1,2] [--width 480]
           [--frames 10] [--rounds 3]
Run it with nothing else running (frame times).
"""

from __future__ import annotations

import argparse
import functools
import json
import statistics
import sys
import tempfile
import threading
from http.server import ThreadingHTTPServer
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from threejs_frame_time import _Quiet, canvas, chromium, open_page  # noqa: E402


def _bundle_of(city: Path, uri: str):
    from neuras_distill.bake.bundle import load_bundle
    from neuras_distill.tiles.levels import level_folder

    k, _, level = uri.split("/")[-1][:-4].partition("_")
    return load_bundle(level_folder(city, int(level or 0), int(k)) / "tile")


def main() -> None:
    from neuras_distill.export.tiles_page import export_3dtiles
    from neuras_distill.export.web import export_web
    from neuras_distill.metrics import psnr
    from neuras_distill.playback.tiles import TilesRenderer
    from neuras_distill.render.cameras import Cameras

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("city", type=Path)
    parser.add_argument("--three", type=Path, required=True)
    parser.add_argument("--tiles-renderer", type=Path, required=True)
    parser.add_argument("--single", type=Path, default=None, help="a run folder of the same scene")
    parser.add_argument("--cameras", default="0,1,2")
    parser.add_argument("--width", type=int, default=480)
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    tileset = args.city / "tileset"
    plan = json.loads((args.city / "plan.json").read_text())
    cams = Cameras.from_json(json.loads((tileset / "cameras.json").read_text())["test"]).resized(args.width)
    picked = [int(c) for c in args.cameras.split(",") if int(c) < len(cams)]
    whole = sum(p.stat().st_size for p in (tileset / "tiles").glob("*.glb"))
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        import shutil

        copy = root / "tileset"
        shutil.copytree(tileset, copy)
        (copy / "cameras.json").write_text(json.dumps({"train": cams.to_json(), "test": cams.to_json()}))
        export_3dtiles(copy, root / "page", args.three, args.tiles_renderer)
        if args.single:
            export_web(args.single / "bundle", root / "web")
            data = json.loads((root / "web" / "cameras.json").read_text())
            (root / "web" / "cameras.json").write_text(json.dumps(dict(data, test=cams.to_json())))
        httpd = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_Quiet, directory=str(root)))
        threading.Thread(target=httpd.serve_forever, daemon=True).start()
        base = f"http://127.0.0.1:{httpd.server_address[1]}"
        driver = chromium()
        full_bundles = [_bundle_of(args.city, f"tiles/{t['index']}.glb") for t in plan["tiles"]]
        try:
            print(f"{args.city}: {len(plan['tiles'])} tiles, {len(list((tileset / 'tiles').glob('*.glb')))} glbs, "
                  f"{whole / 1e6:.2f} MB; {cams.width}x{cams.height}")
            with TilesRenderer(full_bundles) as full:
                for i in picked:
                    open_page(driver, f"{base}/page/index.html?camera={i}")
                    shot = canvas(driver).astype(np.float32) / 255.0
                    stats = driver.execute_script("return window.neurasStats;")
                    with TilesRenderer([_bundle_of(args.city, u) for u in stats["visible"]], ctx=full.ctx) as same:
                        same_db = psnr(shot, same.render(cams, i))
                    full_db = psnr(shot, full.render(cams, i))
                    levels = {}
                    for uri in stats["visible"]:
                        level = int(uri.split("/")[-1][:-4].partition("_")[2] or 0)
                        levels[level] = levels.get(level, 0) + 1
                    print(f"camera {i}: drew " + ", ".join(f"{n} at level {lv}" for lv, n in sorted(levels.items()))
                          + f"; loaded {stats['tiles']} contents, {stats['bytes'] / 1e6:.2f} of {whole / 1e6:.2f} MB; "
                          f"{same_db:.2f} dB against TilesRenderer at the same levels, {full_db:.2f} at full detail")
            pages = [("tiles page", "page")] + ([("web player, one bundle", "web")] if args.single else [])
            times = {name: [] for name, _ in pages}
            for _ in range(args.rounds):
                for name, folder in pages:
                    open_page(driver, f"{base}/{folder}/index.html?camera={picked[0]}")
                    driver.execute_script("return window.neurasTimeFrames(2);")
                    times[name] += driver.execute_script(f"return window.neurasTimeFrames({args.frames});")
            medians = {k: statistics.median(v) for k, v in times.items()}
            print(f"frame time at camera {picked[0]} (SwiftShader, {args.rounds} x {args.frames} frames): "
                  + ", ".join(f"{k} {v:.1f} ms" for k, v in medians.items())
                  + (f", ratio {medians['tiles page'] / medians['web player, one bundle']:.2f}" if args.single else ""))
        finally:
            driver.quit()
            httpd.shutdown()


if __name__ == "__main__":
    main()
