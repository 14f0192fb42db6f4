"""glTF export (export/gltf.py, ``neuras-distill export --format gltf``) and the stored plain texture it carries.

The GLB passes the Khronos glTF-Validator (npm ``gltf-validator`` in .tools/, installed by scripts/setup.sh), opens
in trimesh at world positions with its texture, and ``load_bundle`` restores the bundle from it byte for byte,
playing the same pixels as the folder.
"""

from __future__ import annotations

import io
import json
import math
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import neuras_distill as nd
from neuras_distill.bake.bundle import bake, load_bundle, read_bundle_file_bytes
from neuras_distill.bake.glb_reader import read_bundle_files
from neuras_distill.export.gltf import export_gltf
from neuras_distill.bake.plain_texture import chart_mask, pad_gutters, plain_texture, plain_texture_rgb8
from neuras_distill.cli import main
from neuras_distill.errors import BadInputError
from neuras_distill.geometry.mesh import MeshData
from neuras_distill.render.cameras import Cameras
from test_bake import make_model, quad_mesh

ROOT = Path(__file__).resolve().parents[1]
NODE = shutil.which("node") or "/usr/bin/node"
VALIDATOR = ROOT / ".tools" / "node_modules" / "gltf-validator"
ORIGIN = np.array([1000.0, -20.0, 3.5])             # a scene away from the world origin: export must add it back

needs_gl = pytest.mark.gl  # tests/conftest.py: skipped without GL, failed under CI=true
pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _random_gbuffer(n=2, size=10, seed=0):
    gen = np.random.default_rng(seed)
    dirs = gen.normal(size=(n, size, size, 3)).astype(np.float32)
    return (gen.random((n, size, size, 2), dtype=np.float32), np.ones((n, size, size), bool),
            dirs / np.linalg.norm(dirs, axis=-1, keepdims=True))


def small_bundle(tmp_path, kind="single", name="b"):
    """A saved bundle folder with a plain texture: ``single`` (a quad, texture from plain_texture_rgb8),
    ``two-layer`` (core + shell spheres, two MLPs) or ``skybox`` (a quad with skybox layers)."""
    if kind == "single":
        model, mesh = make_model(h=6, w=8, k=8), quad_mesh()
        mesh = MeshData(mesh.vertices, mesh.faces, mesh.uvs * 0.8 + 0.1)       # a gutter around the chart
        b = bake(model, mesh, (0.1, 0.2, 0.3), origin=ORIGIN)
        b.plain_rgb = plain_texture_rgb8(model, b.mesh, *_random_gbuffer())
    elif kind == "two-layer":
        from test_two_layer import two_spheres

        b = bake(make_model(h=6, w=8, k=8, mesh_layers=2), two_spheres(), (0.1, 0.2, 0.3), origin=ORIGIN)
        b.plain_rgb = np.random.default_rng(1).integers(0, 256, (6, 8, 3), dtype=np.uint8)
    elif kind == "paged":              # an atlas in 2 pages of 8 x 8: a quad on each page
        from test_atlas_pages import paged_model

        v = np.float32([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
        uv = np.float32([[0, 0], [1, 0], [1, 1], [0, 1]]) * 0.8 + 0.1
        mesh = MeshData(np.concatenate([v, v + [1.2, 0, 0]]), np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]]),
                        np.concatenate([uv * [1, 0.5], uv * [1, 0.5] + [0, 0.5]]).astype(np.float32))
        b = bake(paged_model(pages=2, side=8), mesh, (0.1, 0.2, 0.3), origin=ORIGIN)
        b.plain_rgb = np.random.default_rng(3).integers(0, 256, (16, 8, 3), dtype=np.uint8)
    else:
        from neuras_distill.neural.skybox import SkyboxLayers
        from test_skybox import _tiny_mesh_model, _trained_like

        model, mesh = _tiny_mesh_model()
        b = bake(model, mesh, (0, 0, 0), skybox=_trained_like(SkyboxLayers(ORIGIN, [2.0, 5.0], 4)), origin=ORIGIN)
        b.plain_rgb = np.random.default_rng(2).integers(0, 256, (8, 8, 3), dtype=np.uint8)
    return b.save(tmp_path / name)


def _glb_json(path: Path) -> tuple[dict, bytes]:
    data = path.read_bytes()
    n = struct.unpack_from("<I", data, 12)[0]
    m = struct.unpack_from("<I", data, 20 + n)[0]
    return json.loads(data[20:20 + n]), data[28 + n:28 + n + m]


# ------------------------------------------------------------------------------------------ the texture
def test_gutters_take_the_nearest_chart_colour_and_chart_texels_keep_theirs():
    mask = np.zeros((12, 12), bool)
    mask[3:6, 2:5] = True
    rgb = np.random.default_rng(0).random((12, 12, 3)).astype(np.float32)
    out = pad_gutters(rgb, mask, margin=2)
    keep = np.zeros_like(mask)
    keep[1:8, 0:7] = True                                  # the chart dilated by two texels (8-neighbourhood)
    assert np.array_equal(out[keep], rgb[keep])
    assert np.array_equal(out[11, 11], rgb[7, 6]) and np.array_equal(out[0, 11], rgb[1, 6])
    assert np.array_equal(out[11, 0], rgb[7, 0])
    assert len(np.unique(out[~keep].reshape(-1, 3), axis=0)) < (~keep).sum()   # copies, not new colours


def test_chart_mask_covers_the_uv_triangles_only():
    uvs = np.float32([[0.0, 0.0], [0.5, 0.0], [0.0, 0.5]])
    mask = chart_mask(uvs, np.array([[0, 1, 2]]), 16, 16)
    assert mask[0, 0] and mask[3, 3] and mask[0, 7] and mask[7, 0]
    assert not mask[9:, :].any() and not mask[:, 9:].any() and not mask[6, 6]


def test_stored_plain_texture_is_the_model_rounded_with_padded_gutters(tmp_path):
    model, mesh = make_model(h=6, w=8, k=8), quad_mesh()
    mesh = MeshData(mesh.vertices, mesh.faces, mesh.uvs * 0.23 + 0.01)  # texels [0, 2) x [0, 2) of the atlas
    gbuffer = _random_gbuffer()
    rgb8 = plain_texture_rgb8(model, mesh, *gbuffer)
    exact = np.clip(np.rint(plain_texture(model, *gbuffer) * 255), 0, 255).astype(np.uint8)
    assert rgb8.dtype == np.uint8 and rgb8.shape == (6, 8, 3)
    assert np.array_equal(rgb8[:4, :4], exact[:4, :4])                # the chart (2 x 2 texels) + two texels
    assert np.array_equal(rgb8[5, 7], exact[3, 3]) and not np.array_equal(exact[5, 7], exact[3, 3])
    b = bake(model, mesh, (0, 0, 0))
    b.plain_rgb = rgb8
    loaded = load_bundle(b.save(tmp_path / "b"))
    assert np.array_equal(loaded.plain_rgb, rgb8) and "plain_rgb.png" in json.loads(
        (tmp_path / "b" / "manifest.json").read_text())["files"]
    assert "u_plain_rgb" not in loaded.textures and "plain_rgb" not in loaded.textures


# ------------------------------------------------------------------------------------------ the GLB
@pytest.mark.parametrize("kind", ["single", "two-layer", "skybox", "paged"])
def test_the_khronos_validator_finds_no_errors(tmp_path, kind):
    if not Path(NODE).exists():
        pytest.skip("no node to run the glTF validator")
    if not VALIDATOR.is_dir():
        pytest.skip("gltf-validator is not installed in .tools/ (scripts/setup.sh installs it when npm exists)")
    glb = export_gltf(small_bundle(tmp_path, kind), tmp_path / "scene.glb")
    run = subprocess.run([NODE, str(ROOT / "scripts" / "gltf_validate.mjs"), str(glb)], capture_output=True,
                         text=True, timeout=120)
    report = json.loads(run.stdout)
    issues = report["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]
    assert run.returncode == 0
    assert report["info"]["extensionsUsed"] == ["KHR_materials_unlit", "NEURAS_bundle", "NEURAS_neural_material"]
    assert "extensionsRequired" not in json.loads(glb.read_bytes()[20:20 + struct.unpack_from("<I", glb.read_bytes(),
                                                                                              12)[0]])
    assert all(m["severity"] >= 2 for m in issues["messages"])         # infos: e.g. our extensions, unknown to it
    assert report["info"]["resources"][1]["image"]["format"] == "rgb"


@pytest.mark.parametrize("kind", ["single", "two-layer", "skybox", "paged"])
def test_load_bundle_restores_every_file_byte_for_byte(tmp_path, kind):
    folder = small_bundle(tmp_path, kind)
    glb = export_gltf(folder, tmp_path / "scene.glb")
    files = read_bundle_files(glb)
    assert files == read_bundle_file_bytes(folder)
    assert set(files) == {p.name for p in folder.iterdir()}
    a, b = load_bundle(folder), nd.load_bundle(glb)
    assert a.manifest == b.manifest and a.fragment_shader == b.fragment_shader
    assert a.vertex_shader == b.vertex_shader and a.sky_fragment_shader == b.sky_fragment_shader
    assert np.array_equal(a.plain_rgb, b.plain_rgb) and np.array_equal(a.mesh.vertices, b.mesh.vertices)
    assert a.mesh.core_faces == b.mesh.core_faces
    for name in a.textures:
        assert np.array_equal(a.textures[name], b.textures[name]), name
    doc, _ = _glb_json(glb)
    assert "NEURAS_bundle" in doc["extensionsUsed"] and "NEURAS_bundle" not in doc.get("extensionsRequired", [])


@needs_gl
@pytest.mark.gl
@pytest.mark.parametrize("kind", ["single", "two-layer", "skybox", "paged"])
def test_the_glb_plays_like_the_folder(tmp_path, kind):
    from neuras_distill.playback.renderer import BundleRenderer

    folder = small_bundle(tmp_path, kind)
    glb = export_gltf(folder, tmp_path / "scene.glb")
    centre = ORIGIN + ([0.5, 0.5, 0.0] if kind == "single" else [1.1, 0.5, 0.0] if kind == "paged" else 0.0)
    cams = Cameras.orbit(centre, 2.0, 2, width=48, height=40, elevation_deg=55.0, phase_deg=20.0)
    images = []
    for path in (folder, glb):
        with BundleRenderer(load_bundle(path)) as player:
            images.append([player.render(cams, i) for i in range(len(cams))])
    for a, b in zip(*images):
        assert (np.abs(a - a.mean((0, 1))) > 1e-3).any()                       # something is drawn
        mse = float(np.mean((a - b) ** 2))
        assert 10 * math.log10(1.0 / max(mse, 1e-12)) >= 59.0
        assert np.array_equal(a, b)


@pytest.mark.parametrize("kind", ["single", "two-layer"])
def test_trimesh_opens_it_in_world_units_with_the_texture(tmp_path, kind):
    trimesh = pytest.importorskip("trimesh")
    folder = small_bundle(tmp_path, kind)
    bundle = load_bundle(folder)
    glb = export_gltf(folder, tmp_path / "scene.glb")
    scene = trimesh.load(glb, process=False)
    (geom,) = scene.geometry.values()
    faces = bundle.mesh.faces[:bundle.mesh.core_faces] if bundle.mesh.core_faces else bundle.mesh.faces
    used = np.unique(faces)
    world = bundle.mesh.vertices[used].astype(np.float64) + ORIGIN
    upright = world[:, [0, 2, 1]] * [1, 1, -1]        # no cameras beside the bundle: +z up, (x, y, z) -> (x, z, -y)
    assert len(geom.vertices) == len(used) and len(geom.faces) == len(faces)
    np.testing.assert_allclose(scene.bounds, [upright.min(0), upright.max(0)], rtol=0, atol=1e-4)
    np.testing.assert_allclose(geom.visual.uv, np.c_[bundle.mesh.uvs[used, 0], 1 - bundle.mesh.uvs[used, 1]],
                               atol=1e-6)                                     # trimesh flips v to GL's
    image = np.asarray(geom.visual.material.baseColorTexture.convert("RGB"))
    assert np.array_equal(image, bundle.plain_rgb)


def test_an_atlas_in_pages_is_one_material_per_page(tmp_path):
    """Each page's faces are their own primitive with their own material and image (that page of the plain
    texture), and TEXCOORD_0 is the uv within the page."""
    trimesh = pytest.importorskip("trimesh")
    folder = small_bundle(tmp_path, "paged")
    bundle = load_bundle(folder)
    doc, body = _glb_json(export_gltf(folder, tmp_path / "scene.glb"))
    primitives = doc["meshes"][0]["primitives"]
    assert len(doc["materials"]) == len(doc["images"]) == len(doc["textures"]) == len(primitives) == 2
    uv_view = doc["bufferViews"][doc["accessors"][primitives[0]["attributes"]["TEXCOORD_0"]]["bufferView"]]
    uvs = np.frombuffer(body[uv_view["byteOffset"]:uv_view["byteOffset"] + uv_view["byteLength"]], np.float32)
    np.testing.assert_allclose(uvs.reshape(-1, 2), np.c_[bundle.mesh.uvs[:, 0], (bundle.mesh.uvs[:, 1] * 2) % 1.0],
                               atol=1e-6)
    for page, primitive in enumerate(primitives):
        assert primitive["material"] == page
        index_view = doc["bufferViews"][doc["accessors"][primitive["indices"]]["bufferView"]]
        faces = np.frombuffer(body[index_view["byteOffset"]:index_view["byteOffset"] + index_view["byteLength"]],
                              np.uint16).reshape(-1, 3)
        assert np.array_equal(faces, bundle.mesh.faces[2 * page:2 * page + 2])
        image = doc["images"][doc["textures"][doc["materials"][page]["pbrMetallicRoughness"]["baseColorTexture"]
                                             ["index"]]["source"]]
        view = doc["bufferViews"][image["bufferView"]]
        png = Image.open(io.BytesIO(body[view["byteOffset"]:view["byteOffset"] + view["byteLength"]]))
        assert np.array_equal(np.asarray(png), bundle.plain_rgb[8 * page:8 * page + 8])
    scene = trimesh.load(tmp_path / "scene.glb", process=False)
    assert len(scene.geometry) == 2


def _image_sizes(glb: Path) -> list[tuple[int, int]]:
    """(width, height) of every image of a GLB."""
    doc, body = _glb_json(glb)
    views = [doc["bufferViews"][image["bufferView"]] for image in doc["images"]]
    return [Image.open(io.BytesIO(body[v["byteOffset"]:v["byteOffset"] + v["byteLength"]])).size for v in views]


def test_every_image_obeys_the_texture_limit_or_nothing_is_written(tmp_path, capsys):
    """Default 4096 texels a side; ``--max-texture-size N`` for other targets, for the images and the neural
    material's textures alike (a codebook is wrapped to fit, as for the web player). A plain texture (or page)
    above the limit cannot be cut without unwrapping again: exit 2 naming it, its size, the limit and the fix."""
    single, paged = small_bundle(tmp_path, "single", "s"), small_bundle(tmp_path, "paged", "p")
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    assert main(["export", str(single), "--format", "gltf", "--out", str(out_dir / "s.glb")]) == 0
    assert _image_sizes(out_dir / "s.glb") == [(8, 6)]                 # within the default 4096
    for folder, limit, words in [
            (single, "7", "texture plain_rgb is 8x6, above the export's limit of 7 texels per side: bake it with "
                          "texture.page_size 7 or less, or export with --max-texture-size 8 "),
            (paged, "7", "texture plain_rgb is 8x8 per page (2 pages), above the export's limit of 7 texels"),
            (paged, "-1", "--max-texture-size must be at least 1")]:
        rc, err = main(["export", str(folder), "--format", "gltf", "--out", str(out_dir / "p.glb"),
                        "--max-texture-size", limit]), capsys.readouterr().err
        assert rc == 2 and words in _one_line(err), err
    assert sorted(p.name for p in out_dir.iterdir()) == ["s.glb"]        # nothing written, no temporary left
    rc, err = main(["export", str(paged), "--format", "gltf", "--out", str(out_dir / "p.glb"),
                    "--max-texture-size", "8"]), capsys.readouterr().err     # the neural codebook: 64 codes x 2
    assert rc == 2 and "texture u_codebook is 2x64" in err and "--max-texture-size 12" in err, err
    assert main(["export", str(paged), "--format", "gltf", "--out", str(out_dir / "p.glb"),
                 "--max-texture-size", "12"]) == 0
    assert _image_sizes(out_dir / "p.glb") == [(8, 8), (8, 8)]          # one image per page, each within it
    doc, _ = _glb_json(out_dir / "p.glb")
    neural = doc["nodes"][0]["extensions"]["NEURAS_neural_material"]["textures"]
    assert max(max(t["width"], t["height"]) for t in neural) <= 12      # the neural material's textures too


def test_the_base_colour_is_the_stored_plain_texture(tmp_path):
    folder = small_bundle(tmp_path)
    glb = export_gltf(folder, tmp_path / "scene.glb")
    doc, body = _glb_json(glb)
    material = doc["materials"][0]
    assert material["extensions"] == {"KHR_materials_unlit": {}}
    texture = doc["textures"][material["pbrMetallicRoughness"]["baseColorTexture"]["index"]]
    view = doc["bufferViews"][doc["images"][texture["source"]]["bufferView"]]
    png = body[view["byteOffset"]:view["byteOffset"] + view["byteLength"]]
    assert png == (folder / "plain_rgb.png").read_bytes()
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(png))), load_bundle(folder).plain_rgb)
    position = doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]
    np.testing.assert_allclose(position["min"], [0.0, 0.0, 0.0], atol=1e-6)      # the quad spans [0, 1]^2 x 0
    np.testing.assert_allclose(position["max"], [1.0, 1.0, 0.0], atol=1e-6)      # relative to the origin ...
    assert doc["nodes"][0]["translation"] == ORIGIN.tolist()                       # ... which the node carries


# ------------------------------------------------------------------------------------------ bad input
def _export(capsys, bundle, out, fmt="gltf"):
    rc = main(["export", str(bundle), "--format", fmt, "--out", str(out)])
    err = capsys.readouterr().err
    return rc, err


def _one_line(err):
    assert err.count("\n") == 1 and err.startswith("neuras-distill: error: ") and "Traceback" not in err, err
    return err


def test_bad_inputs_exit_2_with_one_line_and_write_nothing(tmp_path, capsys):
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    out = out_dir / "scene.glb"
    not_bundle = tmp_path / "photos"
    not_bundle.mkdir()
    (not_bundle / "a.txt").write_text("hello")
    rc, err = _export(capsys, not_bundle, out)
    assert rc == 2 and "missing manifest.json" in _one_line(err)
    rc, err = _export(capsys, tmp_path / "nowhere", out)
    assert rc == 2 and "does not exist" in _one_line(err)

    folder = small_bundle(tmp_path)
    rc, err = _export(capsys, folder, out, fmt="fbx")
    assert rc == 2 and "'fbx'" in _one_line(err) and "gltf" in err

    corrupt = small_bundle(tmp_path, name="corrupt")
    raw = bytearray((corrupt / "codebook.npy").read_bytes())
    raw[-3] ^= 0x40
    (corrupt / "codebook.npy").write_bytes(bytes(raw))
    rc, err = _export(capsys, corrupt, out)
    assert rc == 2 and "codebook.npy is corrupt" in _one_line(err)

    old = small_bundle(tmp_path, name="old")                # a bundle from before plain_rgb.png
    man = json.loads((old / "manifest.json").read_text())
    del man["files"]["plain_rgb.png"]
    (old / "manifest.json").write_text(json.dumps(man))
    (old / "plain_rgb.png").unlink()
    rc, err = _export(capsys, old, out)
    assert rc == 2 and "re-run" in _one_line(err)

    rc, err = _export(capsys, folder, out_dir / "scene.gltf")
    assert rc == 2 and ".glb" in _one_line(err)
    assert list(out_dir.iterdir()) == []                    # nothing written, no temporary left

    out.write_bytes(b"someone else's file")
    rc, err = _export(capsys, folder, out)
    assert rc == 2 and "not written by neuras-distill" in _one_line(err)
    assert out.read_bytes() == b"someone else's file" and list(out_dir.iterdir()) == [out]
    (out_dir / "dir.glb").mkdir()
    rc, err = _export(capsys, folder, out_dir / "dir.glb")
    assert rc == 2 and "folder" in _one_line(err)


def test_export_replaces_its_own_file_and_load_bundle_refuses_other_files(tmp_path, capsys):
    folder = small_bundle(tmp_path)
    out = tmp_path / "scene.glb"
    assert main(["export", str(folder), "--format", "gltf", "--out", str(out)]) == 0
    first = out.read_bytes()
    assert main(["export", str(folder), "--format", "gltf", "--out", str(out)]) == 0
    assert out.read_bytes() == first and sorted(p.name for p in tmp_path.iterdir()) == ["b", "scene.glb"]
    assert "wrote" in capsys.readouterr().out
    text = tmp_path / "notes.glb"
    text.write_text("not a glb")
    with pytest.raises(BadInputError, match="not a glTF binary"):
        load_bundle(text)
    doc, body = _glb_json(out)
    del doc["extensions"]
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    plain = tmp_path / "plain.glb"
    plain.write_bytes(struct.pack("<III", 0x46546C67, 2, 28 + len(js) + len(body))
                      + struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(body), 0x004E4942) + body)
    with pytest.raises(BadInputError, match="without a neuras bundle"):
        load_bundle(plain)
