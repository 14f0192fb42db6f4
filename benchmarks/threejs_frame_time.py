"""The bundle in three.js (``export --format threejs``) against our own web player and the desktop player.

For a run folder: exports its bundle as the web player's folder and as the three.js page (three.js copied from
``--three``), serves both, and opens each at ``index.html?camera=N`` in headless Chromium (Debian's chromium
and chromedriver through selenium; WebGL2 on SwiftShader, as the tests). Prints, per held-out camera:

* PSNR of the three.js page (GLTFLoader + ``neuras-three.js``) against ``BundleRenderer`` (desktop OpenGL), of
  the same page without the plugin (``&plain``: what other glTF viewers show) against BundleRenderer playing the
  plain texture, and of our web player against BundleRenderer;
* frame times: ``window.neurasTimeFrames(n)`` on both pages (n frames back to back, each read back), in
  interleaved rounds (web, three.js, web, ...) so a busy machine slows both alike; the medians and their ratio.

Usage: python benchmarks/threejs_frame_time.py RUN_FOLDER --three .tools/node_modules/three
           [--cameras 0,1,2] [--width W] [--frames 10] [--rounds 3]
(--width: the held-out cameras resized to W pixels wide, in both pages and for BundleRenderer.)
Run it with nothing else running (frame times).
"""

from __future__ import annotations

import argparse
import base64
import functools
import io
import json
import statistics
import tempfile
import threading
import time
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
from PIL import Image

from neuras_distill.bake.bundle import load_bundle
from neuras_distill.export.threejs import export_threejs
from neuras_distill.export.web import export_web
from neuras_distill.metrics import psnr
from neuras_distill.playback.renderer import BundleRenderer
from neuras_distill.playback.view_modes import mode_bundle
from neuras_distill.render.cameras import Cameras

CHROMIUM_ARGS = ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--use-angle=swiftshader",
                 "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist", "--disable-extensions",
                 "--force-device-scale-factor=1", "--window-size=800,600")


class _Quiet(SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


def chromium():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = "/usr/bin/chromium"
    for arg in CHROMIUM_ARGS:
        opts.add_argument(arg)
    return webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=opts)


def open_page(driver, url: str, timeout: float = 600.0) -> None:
    driver.get(url)
    deadline = time.monotonic() + timeout
    while True:
        ready, error = driver.execute_script("return [window.neurasReady === true, window.neurasError || null];")
        if error:
            raise SystemExit(f"{url}: {error}")
        if ready:
            return
        if time.monotonic() > deadline:
            raise SystemExit(f"{url}: not ready within {timeout:.0f} s")
        time.sleep(0.2)


def canvas(driver) -> np.ndarray:
    url = driver.execute_script("return document.getElementById('view').toDataURL('image/png');")
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))).convert("RGB"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path)
    parser.add_argument("--three", type=Path, required=True, help="node_modules/three")
    parser.add_argument("--cameras", default="0,1,2")
    parser.add_argument("--width", type=int, default=None)
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    bundle = load_bundle(args.run / "bundle")
    cams = Cameras.from_json(json.loads((args.run / "cameras.json").read_text())["test"])
    picked = [int(c) for c in args.cameras.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        export_web(args.run / "bundle", root / "web")
        _, version = export_threejs(args.run / "bundle", root / "three", args.three)
        if args.width:
            cams = cams.resized(args.width)
            for page in ("web", "three"):
                data = json.loads((root / page / "cameras.json").read_text())
                (root / page / "cameras.json").write_text(json.dumps(dict(data, test=cams.to_json())))
        httpd = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_Quiet, directory=str(root)))
        threading.Thread(target=httpd.serve_forever, daemon=True).start()
        base = f"http://127.0.0.1:{httpd.server_address[1]}"
        driver = chromium()
        try:
            print(f"{args.run}: {cams.width}x{cams.height}, three.js {version}, "
                  f"{bundle.mesh.num_faces} faces, skyboxes {'yes' if bundle.sky_fragment_shader else 'no'}")
            with BundleRenderer(bundle) as neural, BundleRenderer(mode_bundle(bundle, "plain")) as plain:
                for i in picked:
                    want = np.round(neural.render(cams, i) * 255.0).astype(np.uint8)
                    want_plain = np.round(plain.render(cams, i) * 255.0).astype(np.uint8)
                    scores = {}
                    for name, page, ref in (("three.js + plugin", f"three/index.html?camera={i}", want),
                                            ("three.js plain", f"three/index.html?camera={i}&plain", want_plain),
                                            ("web player", f"web/index.html?camera={i}", want)):
                        open_page(driver, f"{base}/{page}")
                        scores[name] = psnr(canvas(driver).astype(np.float32) / 255.0, ref.astype(np.float32) / 255.0)
                    print(f"camera {i}: " + ", ".join(f"{k} {v:.2f} dB" for k, v in scores.items())
                          + " (against BundleRenderer; plain against its plain texture)")
            times = {"web player": [], "three.js + plugin": []}
            for _ in range(args.rounds):
                for name, page in (("web player", "web"), ("three.js + plugin", "three")):
                    open_page(driver, f"{base}/{page}/index.html?camera={picked[0]}")
                    driver.execute_script("return window.neurasTimeFrames(2);")           # warm up
                    times[name] += driver.execute_script(f"return window.neurasTimeFrames({args.frames});")
            web, three = (statistics.median(times[k]) for k in ("web player", "three.js + plugin"))
            print(f"frame time at camera {picked[0]} ({cams.width}x{cams.height}, {args.rounds} x {args.frames} "
                  f"frames): web player {web:.1f} ms, three.js + plugin {three:.1f} ms, ratio {three / web:.2f}")
        finally:
            driver.quit()
            httpd.shutdown()


if __name__ == "__main__":
    main()
