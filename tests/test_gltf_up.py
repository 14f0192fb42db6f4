"""An upright glTF: ``export --up`` turns the capture's up onto glTF's +Y (``export/gltf_up.py``).

The bunny scene (z up, its base a disc under it) meshed by marching cubes and baked with a random model and a grey
plain texture on magenta; its ``cameras.json`` (the scene's own orbit cameras) beside the bundle, as a run writes
it. The glb read back as any engine reads it (node transforms composed) must stand the bunny on its base: the
base's flat bottom, the largest flat region of the mesh, faces -Y and the bunny lies above it. Google's
``<model-viewer>`` (headless Chromium, its own +Y-up orbit camera, nothing turned) must show the bunny's silhouette
as our player draws the upright bunny (the camera's orbit mapped into the bundle's frame, z up); the glb exported
with the wrong up (``--up +y``: the bunny lying) must not.
"""

from __future__ import annotations

import io
import json
import shutil
import struct
import time
from pathlib import Path

import numpy as np
import pytest

from neuras_distill.cli import main
from neuras_distill.errors import BadInputError
from neuras_distill.export.gltf_up import (UP_CHOICES, axis_vector, parse_up, quaternion_xyzw, rotation_onto_y,
                                           snapped_up)

ROOT = Path(__file__).resolve().parents[1]
MODEL_VIEWER = ROOT / ".tools" / "model-viewer" / "node_modules" / "@google" / "model-viewer" / "dist"
MAGENTA = (1.0, 0.0, 1.0)


def read_glb(path) -> tuple[dict, bytes]:
    data = path.read_bytes()
    (json_len,) = struct.unpack_from("<I", data, 12)
    doc = json.loads(data[20:20 + json_len])
    return doc, data[20 + json_len + 8:]


def quaternion_matrix(q) -> np.ndarray:
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def scene_mesh(doc: dict, body: bytes) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) in the glTF scene's frame, faces (F, 3)) of the glb's plain mesh, its node transforms
    composed as an engine composes them (root rotation, then the bundle node's translation)."""
    (root,) = doc["scenes"][doc["scene"]]["nodes"]
    up = doc["nodes"][root]
    (child,) = up["children"]
    node = doc["nodes"][child]
    rotation = quaternion_matrix(up.get("rotation", [0, 0, 0, 1]))
    prim = doc["meshes"][node["mesh"]]["primitives"][0]

    def array(accessor, dtype, width):
        acc = doc["accessors"][accessor]
        view = doc["bufferViews"][acc["bufferView"]]
        raw = body[view["byteOffset"]:view["byteOffset"] + view["byteLength"]]
        return np.frombuffer(raw, dtype).reshape(-1, width)

    local = array(prim["attributes"]["POSITION"], np.float32, 3).astype(np.float64)
    index_type = np.uint16 if doc["accessors"][prim["indices"]]["componentType"] == 5123 else np.uint32
    faces = array(prim["indices"], index_type, 3).astype(np.int64)
    return (local + node.get("translation", [0, 0, 0])) @ rotation.T, faces


@pytest.fixture(scope="session")   # one build: its file is one xdist group (conftest.py)
def bunny_run(tmp_path_factory):
    """A run folder (bundle/ + cameras.json) of the bunny scene's marching-cubes mesh."""
    import neuras_distill as nd
    from neuras_distill.bake.bundle import bake
    from neuras_distill.geometry.marching import marching_cubes_field
    from neuras_distill.geometry.mesh import MeshData
    from test_bake import make_model

    field = nd.make_scene("bunny")
    mesh = marching_cubes_field(field, 40)
    uvs = np.random.default_rng(0).uniform(0.1, 0.9, (len(mesh.vertices), 2)).astype(np.float32)
    run = tmp_path_factory.mktemp("bunny-up") / "run"
    b = bake(make_model(h=8, w=8, k=8), MeshData(mesh.vertices, mesh.faces, uvs), MAGENTA)
    b.plain_rgb = np.full((8, 8, 3), 128, np.uint8)      # grey on magenta: its silhouette is what is compared
    b.save(run / "bundle")
    cams = field.default_cameras(12, 32, 32)
    (run / "cameras.json").write_text(json.dumps({"train": cams.to_json(), "test": cams.to_json()}))
    return run


def test_each_axis_turns_onto_plus_y_by_a_proper_rotation():
    for name in UP_CHOICES[1:]:
        r = rotation_onto_y(axis_vector(name))
        np.testing.assert_allclose(r @ axis_vector(name), [0, 1, 0], atol=1e-12)
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(r) == pytest.approx(1.0)
        np.testing.assert_allclose(quaternion_matrix(quaternion_xyzw(r)), r, atol=1e-12)
    # +z up: (x, y, z) -> (x, z, -y), the inverse of Blender's importer
    np.testing.assert_allclose(rotation_onto_y(axis_vector("+z")) @ [1, 2, 3], [1, 3, -2], atol=1e-12)
    tilted = np.array([0.0, np.sin(np.radians(30)), np.cos(np.radians(30))])
    r = rotation_onto_y(tilted)
    np.testing.assert_allclose(r @ tilted, [0, 1, 0], atol=1e-12)


def test_a_mean_up_snaps_to_an_axis_within_15_degrees_only():
    near = [0.0, np.sin(np.radians(10)), np.cos(np.radians(10))]
    far = [0.0, np.sin(np.radians(20)), np.cos(np.radians(20))]
    assert snapped_up(near)[1] == "+z" and np.array_equal(snapped_up(near)[0], [0, 0, 1])
    assert snapped_up(far)[1].startswith("(") and np.allclose(snapped_up(far)[0], far)
    assert snapped_up([0, -3, 0])[1] == "-y"
    for bad in ("up", "z", "+w", "1,0,0", ""):
        with pytest.raises(BadInputError, match="not an axis"):
            parse_up(bad)


def test_the_bunnys_base_faces_plus_y_in_the_exported_glb(bunny_run, tmp_path, capsys):
    glb = tmp_path / "bunny.glb"
    assert main(["export", str(bunny_run / "bundle"), "--format", "gltf", "--out", str(glb)]) == 0
    assert "up +z (the mean up of 24 cameras" in capsys.readouterr().out
    vertices, faces = scene_mesh(*read_glb(glb))
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    cross = np.cross(b - a, c - a)                       # marching cubes winds its faces outward
    area = np.linalg.norm(cross, axis=1)
    normal = cross / np.maximum(area, 1e-30)[:, None]
    # the largest flat region: area-weighted face normals binned by the axis they point along
    directions = np.concatenate([np.eye(3), -np.eye(3)])
    nearest = np.argmax(normal @ directions.T, axis=1)
    flat = np.array([area[(nearest == i) & (normal @ d > 0.999)].sum() for i, d in enumerate(directions)]) / 2
    bottom = directions[int(np.argmax(flat))]
    np.testing.assert_allclose(-bottom, [0, 1, 0])       # the base's normal (into the bunny) is +Y
    assert flat[[0, 2, 3, 5]].max() < 0.05 * flat.max()  # the disc's top and bottom are the only flat faces
    height = vertices[:, 1] - vertices[:, 1].min()
    assert 1.0 <= height.max() <= 1.15                     # the bunny (1 unit) on its disc stands along +Y
    assert np.ptp(vertices[:, 0]) < 1.4 and np.ptp(vertices[:, 2]) < 1.4


def test_up_can_be_given_and_is_checked(bunny_run, tmp_path, capsys):
    glb = tmp_path / "sideways.glb"
    assert main(["export", str(bunny_run / "bundle"), "--format", "gltf", "--out", str(glb), "--up", "+y"]) == 0
    doc, body = read_glb(glb)
    assert "rotation" not in doc["nodes"][1] and doc["nodes"][1]["extras"]["neuras_up"] == [0.0, 1.0, 0.0]
    vertices, _ = scene_mesh(doc, body)
    assert 1.0 <= np.ptp(vertices[:, 2]) <= 1.15              # as asked: the bunny lies along z
    capsys.readouterr()
    bad = tmp_path / "bad.glb"
    assert main(["export", str(bunny_run / "bundle"), "--format", "gltf", "--out", str(bad), "--up", "north"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--up 'north' is not an axis" in err and "Traceback" not in err
    assert not bad.exists() and not list(tmp_path.glob(".bad*"))


def test_the_turned_glb_carries_the_bundle_in_its_own_frame(bunny_run, tmp_path):
    """The neural payload stays node-local: the bundle's files travel unchanged, so load_bundle plays the glb
    exactly as the folder, and the extension's positions are the bundle's, not turned."""
    from neuras_distill.bake.bundle import load_bundle, read_bundle_file_bytes
    from neuras_distill.bake.glb_reader import read_bundle_files

    glb = tmp_path / "bunny.glb"
    assert main(["export", str(bunny_run / "bundle"), "--format", "gltf", "--out", str(glb)]) == 0
    assert read_bundle_files(glb) == read_bundle_file_bytes(bunny_run / "bundle")
    doc, _ = read_glb(glb)
    position = doc["accessors"][doc["nodes"][0]["extensions"]["NEURAS_neural_material"]["geometry"]["POSITION"]]
    mesh = load_bundle(glb).mesh
    np.testing.assert_allclose(position["max"], mesh.vertices.max(0), atol=1e-6)


def _model_viewer_frame(glb: Path, http_root, browser, name: str, orbit, fov: float, size: int) -> np.ndarray:
    """<model-viewer>'s picture (uint8 (size, size, 3)) of ``glb``, its camera at ``orbit`` (theta, phi degrees,
    radius) around the centre of the glb's box in the glTF scene's frame."""
    root, base = http_root
    site = root / name
    site.mkdir()
    shutil.copy(ROOT / "scripts" / "gltf_model_viewer.html", site / "index.html")
    (site / "model-viewer.min.js").symlink_to(MODEL_VIEWER / "model-viewer.min.js")
    shutil.copy(glb, site / "scene.glb")
    vertices, _ = scene_mesh(*read_glb(glb))
    target = (vertices.min(0) + vertices.max(0)) / 2
    query = (f"orbit={orbit[0]},{orbit[1]},{orbit[2]}&target={','.join(f'{v:.6f}' for v in target)}"
             f"&fov={fov}&size={size}")
    browser.get(f"{base}/{name}/index.html?{query}")
    deadline = time.monotonic() + 120.0
    while True:
        ready, error = browser.execute_script("return [window.viewerReady === true, window.viewerError || null];")
        assert error is None, f"model-viewer failed: {error}"
        if ready:
            break
        assert time.monotonic() < deadline, "model-viewer did not show the glb within 120 s"
        time.sleep(0.2)
    from PIL import Image

    image = Image.open(io.BytesIO(browser.get_screenshot_as_png())).convert("RGB")     # what the page shows
    return np.asarray(image)[:size, :size]


def _silhouette(image: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels that are not the magenta background."""
    return np.abs(image.astype(np.int64) - [255, 0, 255]).sum(-1) > 120


@pytest.mark.gl
def test_model_viewer_shows_the_bunny_upright(bunny_run, require_tool, http_root, request, tmp_path):
    import torch

    from neuras_distill.bake.bundle import load_bundle
    from neuras_distill.playback.renderer import BundleRenderer
    from neuras_distill.playback.view_modes import mode_bundle
    from neuras_distill.render.cameras import Cameras, look_at

    require_tool(None if (MODEL_VIEWER / "model-viewer.min.js").is_file() else
                 f"model-viewer is not installed in {MODEL_VIEWER} (npm install --prefix .tools/model-viewer "
                 "@google/model-viewer; scripts/setup.sh does)")
    browser = request.getfixturevalue("browser")
    size, fov, orbit = 192, 30.0, (35.0, 70.0, 3.2)
    upright, lying = tmp_path / "upright.glb", tmp_path / "lying.glb"
    assert main(["export", str(bunny_run / "bundle"), "--format", "gltf", "--out", str(upright)]) == 0
    assert main(["export", str(bunny_run / "bundle"), "--format", "gltf", "--out", str(lying), "--up", "+y"]) == 0
    shots = {name: _model_viewer_frame(glb, http_root, browser, f"model-viewer-{name}", orbit, fov, size)
             for name, glb in (("upright", upright), ("lying", lying))}
    # what the user expects: the bunny in its own z-up frame, seen from the same orbit (glTF (X, Y, Z) is the
    # bundle's (X, -Z, Y) for a z-up capture)
    bundle = load_bundle(bunny_run / "bundle")
    world = bundle.mesh.vertices.astype(np.float64) + bundle.origin
    centre = (world.min(0) + world.max(0)) / 2
    theta, phi, radius = np.radians(orbit[0]), np.radians(orbit[1]), orbit[2]
    offset_gltf = radius * np.array([np.sin(phi) * np.sin(theta), np.cos(phi), np.sin(phi) * np.cos(theta)])
    eye = centre + [offset_gltf[0], -offset_gltf[2], offset_gltf[1]]
    c2w = look_at(torch.tensor(eye), torch.tensor(centre), torch.tensor([0.0, 0.0, 1.0])).float()[None]
    focal = torch.tensor([size / 2 / np.tan(np.radians(fov) / 2)], dtype=torch.float32)
    half = torch.tensor([size / 2], dtype=torch.float32)
    cams = Cameras(c2w, focal, focal, half, half, size, size)
    with BundleRenderer(mode_bundle(bundle, "plain")) as player:
        want = np.round(player.render(cams, 0) * 255.0).astype(np.uint8)

    def iou(image):
        a, b = _silhouette(image), _silhouette(want)
        return float((a & b).sum() / max((a | b).sum(), 1))

    from PIL import Image

    Image.fromarray(np.concatenate([want, shots["upright"], shots["lying"]], axis=1)).save(tmp_path / "viewers.png")
    scores = {name: iou(image) for name, image in shots.items()}
    print(f"model-viewer silhouette against BundleRenderer's upright bunny: IoU {scores} ({tmp_path / 'viewers.png'})")
    assert _silhouette(want).mean() > 0.1
    assert scores["upright"] >= 0.9 and scores["lying"] < 0.75
