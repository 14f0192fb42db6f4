"""report.html (pipeline/report_html.py): the run's report as a page, with the web player embedded.

On conftest's ``small_run``: the page shows report.json's figures in the same tables as report.md, every image it
names is a file of the run folder, and it embeds ``web/`` (the bundle exported for the browser). In headless
Chromium (as test_web.py drives it) the page is opened from a ``file://`` URL: its images load and the embedded
player draws held-out camera 0 like ``BundleRenderer``.
"""

from __future__ import annotations

import json
from html.parser import HTMLParser

import numpy as np
import pytest

from neuras_distill.export.web import DATA_SCRIPT, MARKER
from neuras_distill.pipeline.report import markdown, report_blocks
from neuras_distill.pipeline.report_html import PLAYER_SRC, render_html
from test_web import assert_matches_desktop, wait_for_player

needs_gl = pytest.mark.gl  # tests/conftest.py: skipped without GL, failed under CI=true


class _Page(HTMLParser):
    """Collects <img src>, <iframe src> and the text of each table cell."""

    def __init__(self):
        super().__init__()
        self.images, self.frames, self.cells, self._cell = [], [], [], None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img":
            self.images.append(a["src"])
        elif tag == "iframe":
            self.frames.append(a["src"])
        elif tag in ("td", "th"):
            self._cell = ""

    def handle_data(self, data):
        if self._cell is not None:
            self._cell += data

    def handle_endtag(self, tag):
        if tag in ("td", "th"):
            self.cells.append(self._cell)
            self._cell = None


def sample_report() -> dict:
    """The keys report.md needs, without the optional sections (no FLIP, no skyboxes, no plain texture)."""
    return {"resolution": [64, 48], "fps_before": 2.0, "fps_after": 500.0, "speedup": 250.0, "psnr": 31.234,
            "ssim": 0.95, "lpips": None, "lpips_note": "no weights", "parity_psnr": 60.0, "mesh_faces": 12,
            "texture_resolution": [8, 8], "feature_dim": 4, "codebook_size": 16, "bundle_bytes": 1000,
            "views": {"test": 1, "train": 2, "train_resolution": [32, 24]},
            "device": {"field": "cpu", "bundle": "llvmpipe"}, "stage_seconds": {"bake": 1.0},
            "distill_seconds": 2.0, "left_out": [], "psnr_per_view": [31.234],
            "error_vs_runtime": [{"label": "bundle", "seconds_per_frame": 0.002, "psnr": 31.2}]}


def _parse(text: str) -> _Page:
    page = _Page()
    page.feed(text)
    return page


@needs_gl
def test_report_html_shows_the_report_and_embeds_the_player(small_run):
    _, out = small_run
    rep = json.loads((out / "report.json").read_text())
    text = (out / "report.html").read_text("utf-8")
    page = _parse(text)
    # the summary table's figures, as report.json has them
    for figure in (f"{rep['psnr']:.2f} dB", f"{rep['ssim']:.4f}", f"{rep['flip']:.4f}", f"{rep['mesh_faces']}",
                   f"{rep['parity_psnr']:.1f} dB", f"{rep['speedup']:.0f}x"):
        assert figure in page.cells, figure
    # every table of report.md, cell for cell (the same rows render both)
    tables = [b for b in report_blocks(rep) if b[0] == "table"]
    assert len(tables) == 4                       # summary, stages, error vs run time, fidelity by region
    want_cells = [c for _, header, rows in tables for row in [header, *rows] for c in row]
    assert page.cells == want_cells
    md = (out / "report.md").read_text()
    assert f"| PSNR vs field | reference | {rep['psnr']:.2f} dB |" in md
    # images: every <img src> is a file of the run folder, and the page shows every image report.md shows
    assert page.images and all((out / src).is_file() for src in page.images), page.images
    md_images = [line.split("](", 1)[1].split(")", 1)[0] for line in md.splitlines() if "![" in line]
    assert md_images and set(md_images) <= set(page.images)
    assert {"error_vs_runtime.png", "views/view_00.png", "views/crop_00_a.png"} <= set(page.images)
    # the player: web/ exported from the run's bundle, with data.js for file:// pages
    assert page.frames == [PLAYER_SRC] and PLAYER_SRC.startswith("web/index.html?camera=0")
    for name in ("index.html", "player.js", "scene.json", "cameras.json", DATA_SCRIPT, MARKER):
        assert (out / "web" / name).is_file(), name
    assert (out / "web" / "cameras.json").read_bytes() == (out / "cameras.json").read_bytes()
    assert "http" not in text.replace("http.server", "")          # nothing from outside the folder


def test_render_html_escapes_text_and_keeps_bold_spans(tmp_path):
    rep = sample_report()
    rep["left_out"] = [{"component": "a <b> & c", "reason": "x < y"}]
    text = render_html(rep, tmp_path, None)
    assert "<strong>a &lt;b&gt; &amp; c</strong>: x &lt; y" in text
    assert "No web player" in text and "<iframe" not in text
    assert "- **a <b> & c**: x < y" in markdown(rep)


@needs_gl
def test_report_html_from_a_file_url_shows_its_images_and_plays_camera_0(small_run, browser):
    from neuras_distill.bake.bundle import load_bundle
    from neuras_distill.playback.renderer import BundleRenderer
    from neuras_distill.render.cameras import Cameras

    _, out = small_run
    browser.get((out / "report.html").as_uri())
    loaded = browser.execute_script(
        "return Array.from(document.images).map((im) => [im.getAttribute('src'), im.complete && im.naturalWidth]);")
    assert loaded and all(width for _, width in loaded), loaded
    frame = browser.find_element("css selector", "iframe.player")
    browser.execute_script("arguments[0].scrollIntoView();", frame)     # Chrome pauses frames out of view
    browser.switch_to.frame(frame)
    try:
        got = wait_for_player(browser)
        assert browser.execute_script("return window.location.protocol;") == "file:"
    finally:
        browser.switch_to.default_content()
    cams = Cameras.from_json(json.loads((out / "cameras.json").read_text())["test"])
    with BundleRenderer(load_bundle(out / "bundle")) as player:
        want = np.round(player.render(cams, 0) * 255.0).astype(np.uint8)
    assert float(got.std()) > 5.0                                   # not a blank canvas
    assert_matches_desktop(got, want, "report.html's player, camera 0, from file://")


@needs_gl
def test_report_html_plays_a_bundle_of_the_default_demos_size_from_a_file_url(tmp_path, browser):  # noqa: F811
    """The default demo's 34,403 codes (a 6 x 11468 codebook as baked) and a 12,000-code sky codebook: the page's
    player gets them within 4096 texels a side and draws camera 0 like ``BundleRenderer``."""
    from neuras_distill.bake.bundle import load_bundle
    from neuras_distill.pipeline.report_html import write_report_html
    from neuras_distill.playback.renderer import BundleRenderer
    from test_web import _run_folder, assert_textures_fit

    bundle, cams = _run_folder(tmp_path, "demo-size-skybox")
    run = bundle.parent
    page = write_report_html(run, sample_report())
    assert _parse(page.read_text("utf-8")).frames == [PLAYER_SRC]
    assert max(load_bundle(bundle).textures["u_codebook"].shape[:2]) > 8192       # as baked: too tall for Chromium
    assert assert_textures_fit(run / "web", 4096) <= 4096
    browser.get(page.as_uri())
    frame = browser.find_element("css selector", "iframe.player")
    browser.execute_script("arguments[0].scrollIntoView();", frame)
    browser.switch_to.frame(frame)
    try:
        got = wait_for_player(browser)
    finally:
        browser.switch_to.default_content()
    with BundleRenderer(load_bundle(bundle)) as player:
        want = np.round(player.render(cams, 0) * 255.0).astype(np.uint8)
    assert_matches_desktop(got, want, "report.html's player, a demo-sized bundle with skyboxes, camera 0")


def test_a_bundle_the_web_export_refuses_gets_a_page_saying_why(tmp_path):
    """An atlas wider than the web's 4096 texels (a texture.page_size above it): the run still gets its report,
    without a player, and no web/ folder (an earlier one is removed)."""
    from neuras_distill.bake.bundle import bake
    from neuras_distill.pipeline.report_html import write_report_html
    from test_bake import make_model, quad_mesh

    bake(make_model(h=2, w=4100, k=8), quad_mesh(), (0, 0, 0)).save(tmp_path / "bundle")
    (tmp_path / "web").mkdir()
    (tmp_path / "web" / MARKER).write_text("{}")                       # a player of an earlier bundle
    text = write_report_html(tmp_path, sample_report()).read_text("utf-8")
    assert "No web player in this run folder (the web export refused the bundle: texture u_index is 4100x2, " \
           "above the export&#x27;s limit of 4096 texels per side" in text
    assert "<iframe" not in text and not (tmp_path / "web").exists()


def test_the_page_has_no_player_section_without_a_bundle(tmp_path):
    from neuras_distill.pipeline.report_html import write_report_html
    path = write_report_html(tmp_path, sample_report())
    assert path == tmp_path / "report.html" and not (tmp_path / "web").exists()
    assert "No web player" in path.read_text()

