"""The neural look in three.js: the glTF extension ``NEURAS_neural_material`` (export/gltf_neural.py), its check
when a bundle is loaded from a GLB (bake/glb_reader.py), the plugin (web/neuras-three.js) and the page
``export --format threejs`` writes (export/threejs.py).

The browser tests serve the exported page and open it in headless Chromium (as tests/test_web.py: the system's
chromium, WebGL2 on SwiftShader) with three.js from npm (.tools/node_modules/three, installed by
scripts/setup.sh and .ci/run), on the small bundles of test_web.py given a smooth plain texture: a quad with the
silhouette pass, two spheres in two layers, a quad under skyboxes and an atlas in pages. What may differ from
BundleRenderer is what differs for our web player (SwiftShader's 4 subpixel bits at silhouette edges), so the
same bound holds (``test_web.assert_matches_desktop``: >= 40 dB, at most 0.3% of pixels off by more than 2/255).
The comparison can fail: each mat4 of the MLP transposed (the weight order a loader could get wrong) or the index
atlas flipped in v scores under 30 dB on the pixels the mesh covers.
"""

from __future__ import annotations

import json
import re
import struct
from pathlib import Path

import numpy as np
import pytest
from test_web import _play, _run_folder, assert_matches_desktop, psnr

from neuras_distill.bake.bundle import load_bundle
from neuras_distill.bake.glb_reader import NEURAL_EXTENSION
from neuras_distill.cli import main
from neuras_distill.errors import BadInputError
from neuras_distill.export.gltf import export_gltf
from neuras_distill.export.playable import playable_bundle
from neuras_distill.export.texture_limit import DEFAULT_MAX_TEXTURE_SIZE
from neuras_distill.export.threejs import MARKER, export_threejs
from neuras_distill.render.cameras import Cameras

ROOT = Path(__file__).resolve().parents[1]
THREE = ROOT / ".tools" / "node_modules" / "three"
KINDS = ("single", "two-layer", "skybox", "paged")

needs_gl = pytest.mark.gl  # tests/conftest.py: skipped without GL, failed under CI=true
pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _with_plain(bundle_dir: Path) -> Path:
    """The bundle at ``bundle_dir`` saved beside it as ``bundle-plain`` with a smooth plain texture (the glTF
    export needs one): a colour ramp over the atlas."""
    b = load_bundle(bundle_dir)
    h, w = b.textures["u_index"].shape[:2]
    y, x = np.mgrid[0:h, 0:w]
    b.plain_rgb = np.stack([40 + 180 * x / max(w - 1, 1), 60 + 150 * y / max(h - 1, 1),
                            np.full((h, w), 120.0)], -1).astype(np.uint8)
    return b.save(bundle_dir.parent / "bundle-plain")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """{kind: (bundle folder with a plain texture, held-out cameras beside it)} (test_web.py's bundles)."""
    root = tmp_path_factory.mktemp("three-runs")
    out = {}
    for kind in KINDS:
        bundle, _ = _run_folder(root, kind)
        plain = _with_plain(bundle)
        from neuras_distill.export.web import cameras_json

        out[kind] = (plain, Cameras.from_json(json.loads(cameras_json(load_bundle(plain), plain))["test"]))
    return out


def _glb(path: Path) -> tuple[dict, bytes]:
    data = path.read_bytes()
    n = struct.unpack_from("<I", data, 12)[0]
    m = struct.unpack_from("<I", data, 20 + n)[0]
    return json.loads(data[20:20 + n]), data[28 + n:28 + n + m]


def _write_glb(path: Path, doc: dict, body: bytes) -> None:
    text = json.dumps(doc).encode()
    text += b" " * ((-len(text)) % 4)
    path.write_bytes(b"".join([struct.pack("<III", 0x46546C67, 2, 28 + len(text) + len(body)),
                               struct.pack("<II", len(text), 0x4E4F534A), text,
                               struct.pack("<II", len(body), 0x004E4942), body]))


def _accessor(doc: dict, body: bytes, i: int) -> np.ndarray:
    a = doc["accessors"][i]
    v = doc["bufferViews"][a["bufferView"]]
    dtype = {5123: "<u2", 5125: "<u4", 5126: "<f4"}[a["componentType"]]
    n = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[a["type"]]
    start = v.get("byteOffset", 0) + a.get("byteOffset", 0)
    return np.frombuffer(body, dtype, a["count"] * n, start).reshape(a["count"], n)


def _text(doc: dict, body: bytes, i: int) -> str:
    v = doc["bufferViews"][i]
    return body[v.get("byteOffset", 0):v.get("byteOffset", 0) + v["byteLength"]].decode()


# ------------------------------------------------------------------------------------------ the extension
@pytest.mark.parametrize("kind", ["two-layer", "skybox", "paged"])
def test_the_extension_holds_the_players_geometry_textures_and_shaders(runs, tmp_path, kind):
    bundle_dir, _ = runs[kind]
    glb = export_gltf(bundle_dir, tmp_path / "scene.glb")
    doc, body = _glb(glb)
    assert NEURAL_EXTENSION in doc["extensionsUsed"] and NEURAL_EXTENSION not in doc.get("extensionsRequired", [])
    ext = doc["nodes"][0]["extensions"][NEURAL_EXTENSION]
    want = playable_bundle(load_bundle(bundle_dir), DEFAULT_MAX_TEXTURE_SIZE)
    g = ext["geometry"]
    np.testing.assert_array_equal(_accessor(doc, body, g["POSITION"]), want.vertices[:, :3])
    np.testing.assert_array_equal(_accessor(doc, body, g["TEXCOORD_0"]), want.vertices[:, 3:5])
    np.testing.assert_array_equal(_accessor(doc, body, g["NORMAL"]), want.vertices[:, 5:8])
    np.testing.assert_array_equal(_accessor(doc, body, g["indices"]).reshape(-1, 3), want.faces)
    assert [[c["layer"], c["firstFace"], c["faceCount"]] for c in ext["drawCalls"]] == want.layers
    for call in ext["drawCalls"]:
        assert _text(doc, body, call["fragmentShader"]) == want.programs[str(max(0, int(call["layer"])))]
    assert _text(doc, body, ext["vertexShader"]) == want.vertex_shader
    assert [t["uniform"] for t in ext["textures"]] == [t.name for t in want.textures]
    for desc, tex in zip(ext["textures"], want.textures):
        got = _accessor(doc, body, desc["accessor"])
        assert (desc["width"], desc["height"] * desc["layers"], desc["layers"]) == \
            (tex.data.shape[1], tex.data.shape[0], tex.layers)
        np.testing.assert_array_equal(got.reshape(tex.data.shape), tex.data)
    assert ("sky" in ext) == (want.sky is not None) and ("silhouette" in ext) == (want.silhouette is not None)
    if want.sky is not None:
        assert _text(doc, body, ext["sky"]["fragmentShader"]) == want.sky[1]
        np.testing.assert_array_equal(ext["sky"]["center"], want.sky[2])
    assert ext["cullBackFaces"] == want.cull_back_faces and ext["version"] == 1


@pytest.mark.parametrize("damage, message", [
    ("newer", "version 2 is not supported"),
    ("truncated", "is truncated"),
    ("beyond the chunk", "lies outside the binary chunk"),
    ("oversized", "more than its buffer view holds"),
])
def test_load_bundle_refuses_a_damaged_extension_and_nothing_is_written(runs, tmp_path, capsys, damage, message):
    bundle_dir, _ = runs["skybox"]
    glb = export_gltf(bundle_dir, tmp_path / "scene.glb")
    doc, body = _glb(glb)
    ext = doc["nodes"][0]["extensions"][NEURAL_EXTENSION]
    if damage == "newer":
        ext["version"] = 2
    elif damage == "beyond the chunk":
        doc["bufferViews"][ext["sky"]["fragmentShader"]]["byteOffset"] = len(body) - 8
    elif damage == "oversized":
        doc["accessors"][ext["textures"][0]["accessor"]]["count"] *= 4
    damaged = tmp_path / "damaged.glb"
    _write_glb(damaged, doc, body)
    if damage == "truncated":           # a copy cut short
        damaged.write_bytes(glb.read_bytes()[:-1000])
    with pytest.raises(BadInputError, match=message):
        load_bundle(damaged)
    capsys.readouterr()
    assert main(["export", str(damaged), "--format", "web", "--out", str(tmp_path / "web")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and "again" in err, err
    assert not (tmp_path / "web").exists()


def test_threejs_export_copies_three_and_refuses_what_it_cannot_use(runs, tmp_path, capsys, require_tool):
    require_tool(None if (THREE / "build" / "three.module.js").is_file() else
                 f"three.js is not installed in {THREE.parent} (npm install --prefix .tools three; setup.sh does)")
    bundle_dir, _ = runs["single"]
    out, version = export_threejs(bundle_dir, tmp_path / "page", THREE)
    assert version == json.loads((THREE / "package.json").read_text())["version"]
    names = {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()}
    assert {"index.html", "neuras-three.js", "scene.glb", "cameras.json", MARKER, "three/build/three.module.js",
            "three/build/three.core.js", "three/examples/jsm/loaders/GLTFLoader.js",
            "three/examples/jsm/controls/OrbitControls.js", "three/LICENSE"} <= names
    assert sum((out / n).stat().st_size for n in names if n.startswith("three/")) < 4e6     # not the 24 MB package
    assert load_bundle(out / "scene.glb").mesh.num_faces == load_bundle(bundle_dir).mesh.num_faces
    for args, message in [([], "needs --three"), (["--three", str(tmp_path)], "not a three.js package")]:
        capsys.readouterr()
        code = main(["export", str(bundle_dir), "--format", "threejs", "--out", str(tmp_path / "other"), *args])
        err = capsys.readouterr().err.strip()
        assert code == 2 and len(err.splitlines()) == 1 and message in err, err
        assert not (tmp_path / "other").exists()


# ------------------------------------------------------------------------------------------ in the browser
@pytest.fixture
def page(runs, http_root, require_tool):
    """(export one kind as a three.js page under the test server -> its base URL, the server's folder)."""
    require_tool(None if (THREE / "build" / "three.module.js").is_file() else
                 f"three.js is not installed in {THREE.parent} (npm install --prefix .tools three; setup.sh does)")
    root, base = http_root

    def export(kind: str, name: str, bundle_dir: Path | None = None) -> str:
        export_threejs(bundle_dir or runs[kind][0], root / name, THREE)
        return f"{base}/{name}"
    return export, root


def _want(bundle_dir: Path, cams: Cameras, i: int, mode: str = "neural") -> np.ndarray:
    from neuras_distill.playback.renderer import BundleRenderer
    from neuras_distill.playback.view_modes import mode_bundle

    with BundleRenderer(mode_bundle(load_bundle(bundle_dir), mode)) as player:
        return np.round(player.render(cams, i) * 255.0).astype(np.uint8)


@needs_gl
@pytest.mark.parametrize("kind, camera", [("single", 0), ("two-layer", 1), ("skybox", 1), ("paged", 0)])
def test_the_plugin_plays_the_bundle_like_the_desktop_player(runs, page, browser, kind, camera):
    export, _ = page
    url = export(kind, f"three-{kind}")
    bundle_dir, cams = runs[kind]
    got = _play(browser, f"{url}/index.html?camera={camera}")
    assert got.shape == (cams.height, cams.width, 3)
    assert browser.execute_script("return window.neurasError || null;") is None
    assert_matches_desktop(got, _want(bundle_dir, cams, camera), f"three.js {kind} camera {camera}")


@needs_gl
def test_without_the_plugin_the_page_shows_the_plain_texture(runs, page, browser, kind="single"):
    """``&plain``: GLTFLoader alone draws the glb's own mesh and material, as today's three.js test of the glTF
    export measures (tests/test_gltf_viewers.py): against BundleRenderer playing the plain texture, within what
    three.js's sRGB decoding and mipmaps cost (>= 38 dB on these smooth ramps), and not the neural picture. (A
    two-layer bundle's glb mesh is its core, a glb carries no skyboxes, and the test's paged atlas has a chart
    across its pages, which the glb's per-page materials do not allow: those are not compared.)"""
    export, _ = page
    url = export(kind, f"three-plain-{kind}")
    bundle_dir, cams = runs[kind]
    plain = _play(browser, f"{url}/index.html?camera=0&plain")
    want_plain, want = _want(bundle_dir, cams, 0, "plain"), _want(bundle_dir, cams, 0)
    print(f"three.js without the plugin, {kind}: {psnr(plain, want_plain):.2f} dB against the plain texture, "
          f"{psnr(plain, want):.2f} dB against the neural bundle")
    assert psnr(plain, want_plain) >= 38.0 and psnr(plain, want) < psnr(plain, want_plain) - 3.0


def _transposed_mat4s(source: str) -> str:
    """``source`` with every ``mat4(16 literals)`` transposed: the row/column order a loader could get wrong."""
    def flip(m: re.Match) -> str:
        v = [s.strip() for s in m.group(1).split(",")]
        return "mat4(" + ", ".join(v[4 * r + c] for c in range(4) for r in range(4)) + ")"
    out, n = re.subn(r"mat4\(([^()]*)\)", flip, source)
    assert n > 0
    return out


@needs_gl
@pytest.mark.parametrize("wrong", ["weight order", "flipped atlas"])
def test_a_wrong_weight_order_or_a_flipped_atlas_scores_under_30_db(runs, page, browser, tmp_path, wrong):
    from dataclasses import replace

    export, _ = page
    bundle_dir, cams = runs["single"]
    b = load_bundle(bundle_dir)
    if wrong == "weight order":
        b = replace(b, fragment_shader=_transposed_mat4s(b.fragment_shader))
    else:
        b = replace(b, textures=dict(b.textures, u_index=np.ascontiguousarray(b.textures["u_index"][::-1])))
    wrong_dir = b.save(bundle_dir.parent / f"bundle-{wrong.replace(' ', '-')}")
    got = _play(browser, f"{export('single', 'three-wrong-' + wrong.split()[0], wrong_dir)}/index.html?camera=0")
    want = _want(bundle_dir, cams, 0)
    on_mesh = np.abs(want.astype(int) - np.round(np.asarray(b.background_color) * 255)).sum(-1) > 3
    score = psnr(got[on_mesh], want[on_mesh])
    print(f"three.js with a {wrong}: {score:.2f} dB against the right bundle on the {100 * on_mesh.mean():.0f}% "
          f"of pixels it covers ({psnr(got, want):.2f} dB over the frame)")
    assert on_mesh.mean() > 0.05 and score < 30.0


def _console_errors(browser) -> list[str]:
    return [e["message"] for e in browser.get_log("browser") if e["level"] == "SEVERE"]


@needs_gl
@pytest.mark.parametrize("damage, message", [("newer", "newer than this plugin reads"),
                                             ("truncated", "beyond the file")])
def test_a_damaged_extension_logs_one_error_and_shows_the_plain_texture(runs, page, browser, damage, message):
    export, root = page
    url = export("single", f"three-damaged-{damage}")
    glb = root / f"three-damaged-{damage}" / "scene.glb"
    doc, body = _glb(glb)
    ext = doc["nodes"][0]["extensions"][NEURAL_EXTENSION]
    if damage == "newer":
        ext["version"] = 2
    else:                               # the vertex shader's view declared past the end of the chunk
        doc["bufferViews"][ext["vertexShader"]]["byteOffset"] = len(body) - 4
    _write_glb(glb, doc, body)
    browser.get_log("browser")
    got = _play(browser, f"{url}/index.html?camera=0")
    errors = _console_errors(browser)
    assert any(message in e and "showing the plain texture" in e for e in errors), errors
    plain = _play(browser, f"{url}/index.html?camera=0&plain")
    assert psnr(got, plain) >= 60.0, "the plain-texture mesh is what shows"


#: A page that draws the bundle (``?order=N``: with an opaque three.js plane through its middle, of renderOrder N;
#: ``?linear``: into a linear output colour space).
OCCLUSION_PAGE = """<!DOCTYPE html><html><head><meta charset="utf-8">
<script type="importmap">{"imports": {"three": "./three/build/three.module.js",
                                      "three/addons/": "./three/examples/jsm/"}}</script></head>
<body style="margin:0"><canvas id="view"></canvas><script type="module">
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
import { NeurasNeuralMaterial } from "./neuras-three.js";
const query = new URLSearchParams(location.search), order = Number(query.get("order"));
const gltf = await new GLTFLoader().register((p) => new NeurasNeuralMaterial(p)).loadAsync("scene.glb");
const scene = new THREE.Scene();
scene.add(gltf.scene);
gltf.scene.updateMatrixWorld(true);
const box = new THREE.Box3().expandByObject(gltf.userData.neuras.meshes[0]);
const centre = box.getCenter(new THREE.Vector3()), size = box.getSize(new THREE.Vector3()).length();
const camera = new THREE.PerspectiveCamera(50, 4 / 3, size * 0.01, size * 10);
camera.position.copy(centre).add(new THREE.Vector3(0.9, 0.6, 1.1).multiplyScalar(size));   // three.js's +Y up
camera.lookAt(centre);
camera.updateMatrixWorld();
const plane = new THREE.Mesh(new THREE.PlaneGeometry(size * 4, size * 4),
                             new THREE.MeshBasicMaterial({ color: 0xff0000, side: THREE.DoubleSide }));
plane.position.copy(centre);                    // through the middle, facing the camera
plane.lookAt(camera.position);
plane.renderOrder = order;
if (query.has("order")) scene.add(plane);
const renderer = new THREE.WebGLRenderer({ canvas: document.getElementById("view"), preserveDrawingBuffer: true });
if (query.has("linear")) renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
renderer.setPixelRatio(1);
renderer.setSize(160, 120);
renderer.render(scene, camera);
window.neurasReady = true;
</script></body></html>"""


@needs_gl
def test_the_neural_mesh_writes_depth_and_other_objects_occlude_it(runs, page, browser):
    """An opaque red plane through the middle of the two spheres (two layers), drawn before or after them: the
    same picture either way, with the spheres' near halves in front of the plane and the plane hiding the rest."""
    export, root = page
    url = export("two-layer", "three-occlusion")
    (root / "three-occlusion" / "occlusion.html").write_text(OCCLUSION_PAGE)
    before = _play(browser, f"{url}/occlusion.html?order=-1")
    after = _play(browser, f"{url}/occlusion.html?order=1")
    red = (before[..., 0] > 200) & (before[..., 1] < 40) & (before[..., 2] < 40)
    print(f"occlusion: {100 * red.mean():.1f}% plane, {100 * (~red).mean():.1f}% spheres, "
          f"before vs after {psnr(before, after):.2f} dB")
    assert 0.2 < red.mean() < 0.98 and (~red).mean() > 0.01
    assert psnr(before, after) >= 50.0


@needs_gl
def test_the_page_shows_the_bundle_beside_a_grid(runs, page, browser):
    export, _ = page
    url = export("skybox", "three-grid")
    got = _play(browser, f"{url}/index.html")
    assert browser.execute_script("return window.neurasError || null;") is None
    assert "skyboxes" in browser.execute_script("return document.getElementById('label').textContent;")
    assert got.std() > 5.0


@needs_gl
def test_a_linear_output_colour_space_gets_linear_values(runs, page, browser):
    """renderer.outputColorSpace = LinearSRGBColorSpace: the plugin writes the decoded (linear) values where the
    default sRGB output gets the display values, as three.js's own materials do."""
    export, root = page
    url = export("single", "three-colour")
    (root / "three-colour" / "colour.html").write_text(OCCLUSION_PAGE)
    display = _play(browser, f"{url}/colour.html").astype(np.float64) / 255.0
    linear = _play(browser, f"{url}/colour.html?linear").astype(np.float64) / 255.0
    decoded = np.where(display <= 0.04045, display / 12.92, ((display + 0.055) / 1.055) ** 2.4)
    on_mesh = np.abs(display - decoded).max(-1) > 0.02
    print(f"linear output: {psnr(linear * 255, decoded * 255):.2f} dB against the decoded display values")
    assert on_mesh.mean() > 0.02 and psnr(linear * 255, decoded * 255) >= 40.0
    assert psnr(linear * 255, display * 255) < 30.0

