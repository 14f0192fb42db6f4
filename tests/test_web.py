"""Web export (export/web.py, ``neuras-distill export BUNDLE --format web --out DIR``) and its WebGL2 player.

The browser test serves the exported folder over HTTP, opens ``index.html?camera=N`` in headless Chromium (the
system's /usr/bin/chromium through selenium and the system chromedriver; WebGL2 on SwiftShader) and compares the
canvas with ``BundleRenderer`` for the same camera: a single-layer bundle away from the world origin with the
silhouette pass and the default orbit camera, a two-layer bundle with back-face culling, and a bundle with
skyboxes; and the same from a ``file://`` URL (the player then reads ``data.js``; test_report_html.py plays the
run's report page that way).

What may differ: SwiftShader rasterizes with 4 subpixel bits (``SUBPIXEL_BITS``), Mesa's llvmpipe with 8, so a
pixel whose centre lies within ~1/32 pixel of a silhouette edge can be covered in one and not the other (GL allows
it). With the tests' random, high-frequency textures such a pixel differs by up to 160/255, so the test asks for
PSNR >= 40 dB and at most 0.3% of pixels off by more than 2/255 (measured: the two-layer spheres at 128 x 96,
about 0.1%; the quad and the skybox views, none; at 64 x 48 the same dozen edge pixels cost the spheres 37 dB).
The dialect test checks that the GLSL ES sources differ from the desktop ones by the documented rewrite
only; the browser test compiles them (a compile error fails it with the info log).
"""

from __future__ import annotations

import base64
import io
import json
import math
import shutil
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from neuras_distill.bake.bundle import Bundle, bake, codes_per_row, load_bundle, wrap_codebook
from neuras_distill.bake.glsl import (GLSL_ES_GATHER, GLSL_ES_GATHER_ARRAY, GLSL_ES_PRECISION,
                                      generate_fragment_shader, to_glsl_es)
from neuras_distill.export.texture_limit import DEFAULT_MAX_TEXTURE_SIZE
from neuras_distill.export.web import DATA_SCRIPT, MARKER, PLAYER_FILES, export_web
from neuras_distill.cli import main
from neuras_distill.errors import BadInputError
from neuras_distill.geometry.mesh import MeshData
from neuras_distill.playback.shaders import VERTEX_SHADER, shader_variant
from neuras_distill.playback.shaders import SILHOUETTE_FRAGMENT_SHADER, SILHOUETTE_VERTEX_SHADER
from neuras_distill.render.cameras import Cameras
from test_bake import make_model, quad_mesh

ORIGIN = np.array([1000.0, -20.0, 3.5])        # away from the world origin: the player must shift like the desktop
MIN_PSNR = 40.0

needs_gl = pytest.mark.gl  # tests/conftest.py: skipped without GL, failed under CI=true
pytestmark = pytest.mark.usefixtures("one_torch_thread")


#: Exact codes in the default demo's bundle: as baked (``bundle.codes_per_row``, 3 per row) a 6 x 11468 codebook
#: texture, taller than the 8192 SwiftShader allows. The demo-sized test bundles have as many.
DEMO_CODES = 34403
#: Codes of the demo-sized skybox codebook: above 8192 rows as baked (a sky codebook is never wrapped), within the
#: desktop's 16384 (the default sky has 4096).
DEMO_SKY_CODES = 12000


def grown(b: Bundle, model, codes: int, sky_codes: int | None = None, seed: int = 0) -> Bundle:
    """``b`` (baked from ``model``) with a codebook of ``codes`` random codes, wrapped and read by a shader as
    ``bundle.bake`` does (``codes_per_row``, ``generate_fragment_shader``), and an index map of distinct codes
    spread over all of it (the last code included); with ``sky_codes`` the same for the skybox codebook (never
    wrapped by the bake). What a distillation with that many codes bakes, without the minutes of k-means."""
    gen = np.random.default_rng(seed)
    dim, c4 = int(b.manifest["feature_dim"]), b.textures["u_codebook"].shape[1]

    def codebook(k: int, c4: int, dim: int) -> np.ndarray:            # (k, c4, 4), zero padded after dim
        cb = np.zeros((k, 4 * c4), np.float32)
        cb[:, :dim] = gen.normal(0.0, 1.0, (k, dim))
        return cb.reshape(k, c4, 4)

    def spread(index: np.ndarray, k: int) -> np.ndarray:              # distinct codes, the last one included
        picked = gen.permutation(k)[:index.size] if index.size <= k else gen.integers(0, k, index.size)
        picked[gen.integers(index.size)] = k - 1
        return picked.reshape(index.shape).astype(np.uint16)

    per_row = codes_per_row(codes)
    textures = dict(b.textures, u_codebook=wrap_codebook(codebook(codes, c4, dim), per_row),
                    u_index=spread(b.textures["u_index"], codes))
    manifest = dict(b.manifest, num_codes=codes, codes_per_row=per_row)
    if sky_codes is not None:
        sky_c4 = b.textures["u_sky_codebook"].shape[1]
        textures.update(u_sky_codebook=codebook(sky_codes, sky_c4, int(b.manifest["skybox"]["feature_dim"])),
                        u_sky_index=spread(b.textures["u_sky_index"], sky_codes))
        manifest["skybox"] = dict(b.manifest["skybox"], num_codes=sky_codes)
    return replace(b, textures=textures, manifest=manifest,
                   fragment_shader=generate_fragment_shader(model, codes_per_row=per_row))


def _looking_at(target: np.ndarray, offsets: list, width: int, height: int) -> Cameras:
    """Cameras at ``target + offset`` looking at ``target`` (z up), 70 degrees wide, ``width`` x ``height``."""
    from neuras_distill.render.cameras import look_at

    c2w = torch.stack([look_at(torch.tensor(target + np.asarray(o)), torch.tensor(target),
                               torch.tensor([0.0, 0.0, 1.0])) for o in offsets]).float()
    f = 0.5 * width / math.tan(math.radians(35))
    return Cameras(c2w, f, f, width / 2, height / 2, width, height)


def _run_folder(root: Path, kind: str) -> tuple[Path, Cameras | None]:
    """runs/<kind>/bundle (+ cameras.json beside it, except for ``single``: the export's default orbit camera)."""
    run = root / kind
    cams = None
    if kind == "demo-size":             # the default demo's codebook on a 128 x 96 atlas of distinct codes
        model, mesh = make_model(h=96, w=128, k=8, use_facing=True), quad_mesh()
        mesh = MeshData(mesh.vertices, mesh.faces, mesh.uvs * 0.8 + 0.1)
        b = grown(bake(model, mesh, (0.1, 0.2, 0.3), origin=ORIGIN, extra_manifest={"silhouette_blend": True}),
                  model, DEMO_CODES)
        assert b.textures["u_codebook"].shape[:2] == (11468, 6)      # as the default demo bakes it
        cams = _looking_at(ORIGIN + [0.5, 0.5, 0.0], [[0.5, -0.6, 1.1], [-0.3, 0.2, 1.3]], 640, 480)
    elif kind == "single":
        model, mesh = make_model(h=6, w=8, k=8, use_facing=True), quad_mesh()
        mesh = MeshData(mesh.vertices, mesh.faces, mesh.uvs * 0.8 + 0.1)
        b = bake(model, mesh, (0.1, 0.2, 0.3), origin=ORIGIN,
                 extra_manifest={"silhouette_blend": True, "cull_back_faces": True})
    elif kind == "paged":               # an atlas in 3 pages: the index map a texture array
        from test_atlas_pages import paged_model

        mesh = quad_mesh()
        b = bake(paged_model(pages=3, side=8), MeshData(mesh.vertices, mesh.faces, mesh.uvs * 0.96 + 0.02),
                 (0.1, 0.2, 0.3), origin=ORIGIN)
        assert b.manifest["atlas_pages"] == 3
    elif kind == "two-layer":
        from test_two_layer import make_model as layered_model, two_spheres

        b = bake(layered_model(mesh_layers=2), two_spheres(), (0.1, 0.2, 0.3), origin=ORIGIN,
                 extra_manifest={"cull_back_faces": True})
        cams = Cameras.orbit(ORIGIN, 2.0, 2, width=128, height=96, elevation_deg=20.0, phase_deg=10.0)
    else:
        from neuras_distill.neural.skybox import SkyboxGround, SkyboxLayers
        from test_skybox import _tiny_mesh_model, _trained_like

        model, mesh = _tiny_mesh_model()
        # the small one lies on a ground below the quad (its floors are constants of the sky shader)
        ground = SkyboxGround([0.0, 0.1, 1.0], [-0.3, -0.8]) if kind == "skybox" else None
        b = bake(model, mesh, (0, 0, 0), skybox=_trained_like(SkyboxLayers(ORIGIN, [2.0, 5.0], 4, ground)),
                 origin=ORIGIN, extra_manifest={"silhouette_blend": True})
        if kind == "demo-size-skybox":  # the demo's codebook and a sky codebook taller than SwiftShader's limit
            b = grown(b, model, DEMO_CODES, DEMO_SKY_CODES)
            assert b.textures["u_sky_codebook"].shape[0] == DEMO_SKY_CODES > 8192
        cams = _looking_at(ORIGIN, [[0.3, -0.5, 0.6], [-0.4, 0.2, 0.5]], 80, 45)   # the quad and the sky around it
    b.save(run / "bundle")
    if cams is not None:
        (run / "cameras.json").write_text(json.dumps({"train": cams.to_json(), "test": cams.to_json()}))
    return run / "bundle", cams


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    return {kind: _run_folder(root, kind) for kind in ("single", "two-layer", "skybox", "paged", "demo-size",
                                                        "demo-size-skybox")}


# ------------------------------------------------------------------------------------------ the dialect
def _desktop_sources(runs) -> list[str]:
    out = [VERTEX_SHADER, SILHOUETTE_VERTEX_SHADER, SILHOUETTE_FRAGMENT_SHADER]
    from neuras_distill.bake.glsl_sky import SKY_VERTEX_SHADER

    out.append(SKY_VERTEX_SHADER)
    for bundle, _ in runs.values():
        b = load_bundle(bundle)
        out.append(b.fragment_shader)
        if b.sky_fragment_shader:
            out.append(b.sky_fragment_shader)
    return out


def test_the_es_dialect_differs_only_by_the_documented_rewrite(runs):
    sources = _desktop_sources(runs)
    assert sum("textureGather(" in s for s in sources) == 8          # the six mesh shaders and the two skies'
    for src in sources:
        es = to_glsl_es(src)
        assert to_glsl_es(src) == es                                   # deterministic
        lines = es.split("\n")
        assert lines[0] == "#version 300 es" and tuple(lines[1:5]) == GLSL_ES_PRECISION
        arrays = "usampler2DArray" in src                              # an atlas in pages
        if arrays:
            assert lines[5] == "precision highp usampler2DArray;"
        rest = "\n".join(lines[5 + arrays:])
        gather = GLSL_ES_GATHER_ARRAY if arrays else GLSL_ES_GATHER
        if "textureGather(" in src:
            assert rest.startswith(gather + "\n") and "textureGather(" not in es
            rest = rest[len(gather) + 1:].replace("neurasGather(", "textureGather(")
        else:
            assert "neurasGather" not in es
        assert rest == src.split("\n", 1)[1]                           # undoing the rewrite gives the source back
    with pytest.raises(ValueError, match="#version"):
        to_glsl_es("void main() {}\n")


def test_export_writes_the_documented_folder(runs, tmp_path):
    bundle, cams = runs["two-layer"]
    out = export_web(bundle, tmp_path / "web")
    b = load_bundle(bundle)
    scene = json.loads((out / "scene.json").read_text())
    assert (out / MARKER).is_file() and (out / "index.html").is_file() and (out / "player.js").is_file()
    assert (out / "cameras.json").read_bytes() == (bundle.parent / "cameras.json").read_bytes()
    for layer in (0, 1):
        assert (out / f"shaders/mesh{layer}.frag").read_text() == shader_variant(to_glsl_es(b.fragment_shader), layer)
    assert (out / "shaders/mesh.vert").read_text() == to_glsl_es(VERTEX_SHADER)
    assert scene["mesh"]["layers"] == [[0.0, 0, b.mesh.core_faces], [1.0, b.mesh.core_faces,
                                                                    b.mesh.num_faces - b.mesh.core_faces]]
    assert scene["cull_back_faces"] is True and scene["sky"] is None and scene["silhouette"] is None
    assert scene["origin"] == ORIGIN.tolist()
    vbo = np.frombuffer((out / "mesh.bin").read_bytes(), "<f4").reshape(-1, 8)
    assert np.array_equal(vbo[:, :3], b.mesh.vertices) and np.array_equal(vbo[:, 3:5], b.mesh.uvs)
    assert np.array_equal(vbo[:, 5:], b.mesh.vertex_normals().astype(np.float32))
    assert np.array_equal(np.frombuffer((out / "faces.bin").read_bytes(), "<u4").reshape(-1, 3), b.mesh.faces)
    for t in scene["textures"]:
        arr = b.textures[t["name"]]
        raw = np.frombuffer((out / t["file"]).read_bytes(), "<u2" if t["type"] == "uint16" else "<f4")
        assert np.array_equal(raw.reshape(arr.shape), arr) and (t["height"], t["width"]) == arr.shape[:2]
    # data.js: every data file, base64, for file:// pages; nothing else
    text = (out / DATA_SCRIPT).read_text("ascii")
    prefix = "window.NEURAS_WEB_DATA = "
    body = text[text.index(prefix) + len(prefix):].rstrip()
    assert body.endswith(";")
    embedded = json.loads(body[:-1])["files"]
    on_disk = {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()}
    assert set(embedded) == on_disk - {DATA_SCRIPT, MARKER, *PLAYER_FILES} and "tex_u_index.bin" in embedded
    for name, b64 in embedded.items():
        assert base64.b64decode(b64) == (out / name).read_bytes(), name
    # exported again over our own folder: replaced, nothing left beside it
    export_web(bundle, out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["web"]


def test_without_cameras_json_a_default_orbit_camera_is_written(runs, tmp_path):
    bundle, _ = runs["single"]
    out = export_web(bundle, tmp_path / "web")
    data = json.loads((out / "cameras.json").read_text())
    assert data["default_orbit"] is True
    cams = Cameras.from_json(data["test"])
    assert len(cams) == 1 and (cams.width, cams.height) == (640, 480)
    centre = load_bundle(bundle).origin + 0.5                       # the quad's centre (x, y), world frame
    forward = -cams.c2w[0, :3, 2].double().numpy()
    to_centre = np.array([centre[0], centre[1], ORIGIN[2]]) - cams.c2w[0, :3, 3].double().numpy()
    assert np.dot(forward, to_centre / np.linalg.norm(to_centre)) > 0.999       # looks at the mesh


# ------------------------------------------------------------------------------------------ bad input
def _exit_and_stderr(capsys, argv) -> tuple[int, str]:
    code = main(argv)
    return code, capsys.readouterr().err


def test_bad_input_exits_2_with_one_line_and_writes_nothing(runs, tmp_path, capsys):
    bundle, _ = runs["single"]
    not_a_bundle = tmp_path / "empty"
    not_a_bundle.mkdir()
    corrupt = tmp_path / "corrupt"
    shutil.copytree(bundle, corrupt)
    data = bytearray((corrupt / "codebook.npy").read_bytes())
    data[-1] ^= 0xFF
    (corrupt / "codebook.npy").write_bytes(bytes(data))
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "notes.txt").write_text("keep me")
    bad_cams = tmp_path / "badrun"
    shutil.copytree(bundle, bad_cams / "bundle")
    (bad_cams / "cameras.json").write_text("{\"test\": 3}")
    cases = [(not_a_bundle, tmp_path / "out1", "missing"), (corrupt, tmp_path / "out2", "corrupt"),
             (tmp_path / "nowhere", tmp_path / "out3", "does not exist"), (bundle, theirs, "not a web folder"),
             (bad_cams / "bundle", tmp_path / "out4", "cameras.json")]
    before = sorted(p.name for p in tmp_path.iterdir())
    for src, out, words in cases:
        code, err = _exit_and_stderr(capsys, ["export", str(src), "--format", "web", "--out", str(out)])
        assert code == 2, err
        assert len(err.strip().splitlines()) == 1 and words in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == before             # no output, no temporary folder
    assert sorted(p.name for p in theirs.iterdir()) == ["notes.txt"]
    with pytest.raises(BadInputError, match="not a web folder"):
        export_web(bundle, theirs / "notes.txt")


def test_a_texture_that_cannot_fit_the_limit_exits_2_naming_it_and_writes_nothing(runs, tmp_path, capsys):
    cases = [("single", "4", "texture u_index is 8x6, above the export's limit of 4 texels per side: bake it with "
                             "texture.page_size 4 or less, or export with --max-texture-size 8 "),
             ("paged", "6", "texture u_codebook is 2x64 (64 codes of 2 texels; at most 18 fit 6x6), above the "
                            "export's limit of 6 texels per side: bake it with fewer texture.num_codes, or export "
                            "with --max-texture-size 12 "),
             ("skybox", "12", "texture u_sky_index is 12x16, above the export's limit of 12 texels per side: bake it "
                              "with a smaller skybox.resolution or fewer skybox.layers"),
             ("demo-size", "64", "texture u_codebook is 6x11468 (34403 codes of 2 texels; at most 2048 fit 64x64)"),
             ("single", "0", "--max-texture-size must be at least 1 texel"),
             ("single", "big", "--max-texture-size must be an integer")]
    for kind, limit, words in cases:
        code, err = _exit_and_stderr(capsys, ["export", str(runs[kind][0]), "--format", "web", "--out",
                                              str(tmp_path / "web"), "--max-texture-size", limit])
        assert code == 2 and len(err.strip().splitlines()) == 1 and words in err, err
        assert "--max-texture-size" in err
    assert not any(tmp_path.iterdir())                                  # no output, no temporary folder


# ------------------------------------------------------------------------------------------ the browser
# the browser and the HTTP server are tests/conftest.py's fixtures ``browser`` (one Chromium for the whole run)
# and ``http_root``
@pytest.fixture(scope="module")
def server(http_root):
    return http_root


def _play(browser, url: str, timeout: float = 120.0) -> np.ndarray:
    """(H, W, 3) uint8 canvas of the page at ``url`` once ``window.neurasReady``; fails with the player's error."""
    browser.get(url)
    return wait_for_player(browser, timeout)


def wait_for_player(browser, timeout: float = 120.0) -> np.ndarray:
    """(H, W, 3) uint8 canvas of the player in the current browsing context (page or frame) once
    ``window.neurasReady``; fails with the player's error."""
    deadline = time.monotonic() + timeout
    while True:
        state = browser.execute_script("return [window.neurasReady === true, window.neurasError || null];")
        if state[1]:
            pytest.fail(f"the web player failed: {state[1]}")
        if state[0]:
            break
        if time.monotonic() > deadline:
            pytest.fail(f"the web player was not ready after {timeout} s")
        time.sleep(0.1)
    url_data = browser.execute_script("return document.getElementById('view').toDataURL('image/png');")
    png = base64.b64decode(url_data.split(",", 1)[1])
    return np.array(Image.open(io.BytesIO(png)).convert("RGB"))


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(255.0 ** 2 / mse)


@needs_gl
@pytest.mark.parametrize("kind, camera", [("single", 0), ("two-layer", 1), ("skybox", 1), ("paged", 0),
                                          ("demo-size", 0), ("demo-size-skybox", 0), ("demo-size-skybox", 1)])
def test_browser_plays_the_held_out_camera_like_the_desktop_player(runs, browser, server, kind, camera):
    from neuras_distill.playback.renderer import BundleRenderer

    bundle, _ = runs[kind]
    root, base = server
    out = root / f"{kind}-{camera}"
    assert main(["export", str(bundle), "--format", "web", "--out", str(out)]) == 0
    largest = assert_textures_fit(out, DEFAULT_MAX_TEXTURE_SIZE)
    baked = max(max(a.shape[:2]) for a in load_bundle(bundle).textures.values())
    print(f"{kind}: largest texture side {largest} (the bundle's: {baked})")
    cams = Cameras.from_json(json.loads((out / "cameras.json").read_text())["test"])
    with BundleRenderer(load_bundle(bundle)) as player:
        want = np.round(player.render(cams, camera) * 255.0).astype(np.uint8)
    got = _play(browser, f"{base}/{out.name}/index.html?camera={camera}")
    assert got.shape == (cams.height, cams.width, 3)
    bg = np.round(np.asarray(load_bundle(bundle).background_color) * 255.0)
    assert np.mean(np.abs(want.astype(float) - bg).sum(-1) > 3) > 0.05        # the view shows the scene
    with BundleRenderer(load_bundle(bundle)) as player:                        # ... the mesh included
        assert np.mean(np.abs(player.render(cams, camera, skybox=False) * 255.0 - bg).sum(-1) > 3) > 0.05
    assert_matches_desktop(got, want, f"{kind} camera {camera}")


def assert_textures_fit(out: Path, limit: int) -> int:
    """Every texture of the web folder ``out`` has sides of at most ``limit`` texels (a texture array's pages
    counted one by one); returns the largest side."""
    scene = json.loads((out / "scene.json").read_text())
    assert scene["max_texture_size"] == limit
    sides = {t["name"]: (t["width"], t["height"] // t.get("layers", 1)) for t in scene["textures"]}
    assert max(max(s) for s in sides.values()) <= limit, sides
    return max(max(s) for s in sides.values())


def assert_matches_desktop(got: np.ndarray, want: np.ndarray, what: str) -> None:
    """The web player's frame ``got`` is BundleRenderer's ``want`` up to rasterization rules (module docstring)."""
    assert got.shape == want.shape, what
    db = psnr(got, want)
    off = float(np.mean(np.abs(got.astype(int) - want.astype(int)).max(-1) > 2))
    print(f"web player vs BundleRenderer, {what}: {db:.2f} dB, {100 * off:.2f}% of pixels off")
    assert db >= MIN_PSNR, f"{what}: {db:.2f} dB < {MIN_PSNR} dB"
    assert off <= 0.003, f"{what}: {100 * off:.2f}% of the pixels differ by more than 2/255"


@needs_gl
def test_an_exported_folder_plays_from_a_file_url(runs, browser, tmp_path):
    """No server: from file:// the player reads data.js (fetch cannot read files) and draws the same frame."""
    from neuras_distill.playback.renderer import BundleRenderer

    bundle, cams = runs["two-layer"]
    out = export_web(bundle, tmp_path / "web")
    with BundleRenderer(load_bundle(bundle)) as player:
        want = np.round(player.render(cams, 1) * 255.0).astype(np.uint8)
    got = _play(browser, (out / "index.html").as_uri() + "?camera=1")
    assert_matches_desktop(got, want, "two-layer camera 1 from file://")
    (out / DATA_SCRIPT).unlink()                                    # an older export: says what to do
    browser.get((out / "index.html").as_uri())
    deadline = time.monotonic() + 60.0
    error = None
    while error is None and time.monotonic() < deadline:
        error = browser.execute_script("return window.neurasError || null;")
        time.sleep(0.1)
    assert error is not None and "data.js is missing" in error and "neuras-distill serve" in error, error


@needs_gl
def test_a_shader_that_does_not_compile_fails_with_its_info_log(runs, browser, server):
    bundle, _ = runs["two-layer"]
    root, base = server
    out = root / "broken"
    export_web(bundle, out)
    frag = out / "shaders" / "mesh1.frag"
    frag.write_text(frag.read_text().replace("f_color = vec4(rgb, ", "f_color = vec4(rgb, undefined_name + "))
    browser.get(f"{base}/broken/index.html?camera=0")
    deadline = time.monotonic() + 60.0
    error = None
    while error is None and time.monotonic() < deadline:
        error = browser.execute_script("return window.neurasError || null;")
        time.sleep(0.1)
    assert error is not None and "mesh1.frag (fragment) does not compile" in error and "undefined_name" in error, error
    assert browser.execute_script("return window.neurasReady === true;") is False


@needs_gl
def test_orbit_controls_move_the_view_and_the_fps_counter_counts(runs, browser, server):
    bundle, _ = runs["single"]
    root, base = server
    export_web(bundle, root / "orbit")
    before = _play(browser, f"{base}/orbit/index.html")
    browser.execute_script("""
        const c = document.getElementById('view');
        const ev = (type, x, y) => c.dispatchEvent(new PointerEvent(type, {clientX: x, clientY: y, pointerId: 1}));
        ev('pointerdown', 100, 100); ev('pointermove', 140, 90); ev('pointerup', 140, 90);
        c.dispatchEvent(new WheelEvent('wheel', {deltaY: 300}));""")
    time.sleep(1.5)                                      # a few frames, and the counter's first second
    after = browser.execute_script("return document.getElementById('view').toDataURL('image/png');")
    after = np.array(Image.open(io.BytesIO(base64.b64decode(after.split(",", 1)[1]))).convert("RGB"))
    assert browser.execute_script("return window.neurasError || null;") is None
    assert after.shape == before.shape and np.mean(np.abs(after.astype(int) - before.astype(int)).max(-1) > 8) > 0.02
    assert "fps" in browser.execute_script("return document.getElementById('fps').textContent;")
