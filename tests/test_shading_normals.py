"""Smoothed shading normals (``MeshData.normal_smoothing``, ``texture.normal_smoothing``).

The facing input |n . d| of a mesh with a fringe shell reads the interpolated vertex normal; on a surface fused
from a trained NeRF's depths those normals follow bumps (the Instant-NGP ball's: a median 16 degrees off the
sphere's), so the fade they drive is speckled. Here: smoothing brings a bumpy sphere's normals back towards the
sphere's, zero rounds is the plain computation, a bundle keeps its rounds (format version 5) and plays the normals
it was trained with, and bad values are refused.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from neuras_distill.bake.bundle import NORMALS_FORMAT_VERSION, bake, load_bundle
from neuras_distill.config import DistillConfig
from neuras_distill.errors import BadInputError
from neuras_distill.geometry.mesh import MeshData
from test_two_layer import R_CORE, cameras, make_model, two_spheres


def bumpy(mesh: MeshData, amplitude: float = 0.1, seed: int = 0) -> MeshData:
    """``mesh`` with every vertex position moved along its radius by up to ``amplitude`` (relative), the same
    move for vertices at one position."""
    v = mesh.vertices.astype(np.float64)
    _, position = np.unique(mesh.vertices, axis=0, return_inverse=True)
    scale = 1.0 + amplitude * np.random.default_rng(seed).uniform(-1, 1, position.max() + 1)[position.reshape(-1)]
    return MeshData((v * scale[:, None]).astype(np.float32), mesh.faces, mesh.uvs, core_faces=mesh.core_faces)


def angle_to_radius(mesh: MeshData) -> np.ndarray:
    n = mesh.vertex_normals().astype(np.float64)
    r = mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True)
    return np.degrees(np.arccos(np.clip((n * r).sum(1), -1.0, 1.0)))


def test_smoothing_turns_a_bumpy_spheres_normals_back_to_the_sphere():
    mesh = bumpy(two_spheres())
    plain = angle_to_radius(mesh)
    mesh.normal_smoothing = 20
    smooth = angle_to_radius(mesh)
    assert np.median(plain) > 8.0, np.median(plain)
    assert np.median(smooth) < 0.4 * np.median(plain), (np.median(plain), np.median(smooth))
    mesh.normal_smoothing = 0
    assert np.array_equal(mesh.vertex_normals(), MeshData(mesh.vertices, mesh.faces).vertex_normals())


def test_seam_copies_share_the_smoothed_normal():
    mesh = bumpy(two_spheres())
    split = MeshData(np.concatenate([mesh.vertices, mesh.vertices[:1]]),
                     np.where(mesh.faces == 0, mesh.num_vertices, mesh.faces)[:len(mesh.faces) // 2].tolist()
                     + mesh.faces[len(mesh.faces) // 2:].tolist(), normal_smoothing=20)
    n = split.vertex_normals()
    assert np.array_equal(n[0], n[-1]) and np.linalg.norm(n[0]) == pytest.approx(1.0, abs=1e-6)


def test_layers_and_saved_meshes_keep_the_rounds(tmp_path):
    mesh = bumpy(two_spheres())
    mesh.normal_smoothing = 7
    assert all(layer.normal_smoothing == 7 for layer in mesh.layers())
    mesh.save_npz(tmp_path / "m.npz")
    assert MeshData.load_npz(tmp_path / "m.npz").normal_smoothing == 7


@pytest.mark.gl
def test_a_bundle_plays_the_normals_it_was_trained_with(tmp_path):
    from neuras_distill.pipeline.evaluate import gl_torch_parity
    from neuras_distill.playback.rasterize import rasterize_gbuffer
    from neuras_distill.playback.renderer import BundleRenderer

    model, mesh = make_model(mesh_layers=2), bumpy(two_spheres())
    assert model.use_facing
    mesh.normal_smoothing = 20
    bg = np.float32([0.1, 0.2, 0.3])
    folder = bake(model, mesh, bg).save(tmp_path / "b")
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["format_version"] == NORMALS_FORMAT_VERSION and manifest["normal_smoothing"] == 20
    bundle = load_bundle(folder)
    assert bundle.mesh.normal_smoothing == 20
    assert np.array_equal(bundle.mesh.vertex_normals(), mesh.vertex_normals())
    plain_mesh = MeshData(mesh.vertices, mesh.faces, mesh.uvs, core_faces=mesh.core_faces)
    cams = cameras(2, 80)
    with BundleRenderer(bundle) as r:
        for i in range(len(cams)):
            image = r.render(cams, i)
            right = gl_torch_parity(model, mesh, cams[i], image, bg, rasterize_gbuffer)
            wrong = gl_torch_parity(model, plain_mesh, cams[i], image, bg, rasterize_gbuffer)
            assert right > 50.0 and wrong < right - 3.0, (i, right, wrong)
    plain = bake(model, plain_mesh, bg).save(tmp_path / "plain")
    assert "normal_smoothing" not in json.loads((plain / "manifest.json").read_text())


@pytest.mark.parametrize("value", [-1, 2.5, True, "20", 10001])
def test_a_bad_normal_smoothing_in_a_manifest_is_refused(tmp_path, value):
    model, mesh = make_model(mesh_layers=2), two_spheres()
    mesh.normal_smoothing = 3
    folder = bake(model, mesh, np.float32([0, 0, 0])).save(tmp_path / "b")
    path = folder / "manifest.json"
    manifest = json.loads(path.read_text())
    manifest["normal_smoothing"] = value
    path.write_text(json.dumps(manifest))
    with pytest.raises(BadInputError, match="normal_smoothing"):
        load_bundle(folder)


def test_the_setting_is_checked():
    cfg = DistillConfig()
    assert cfg.texture.normal_smoothing == 20 and R_CORE > 0
    with pytest.raises(BadInputError, match="normal_smoothing"):
        cfg.updated({"texture": {"normal_smoothing": -1}})


def test_only_rough_normals_under_a_facing_input_are_smoothed():
    from neuras_distill.pipeline.choices import shading_normals
    from neuras_distill.pipeline.rules import ROUGH_NORMALS_DEG
    from neuras_distill.pipeline.choices import Decisions

    rough, smooth = bumpy(two_spheres()), two_spheres()
    assert rough.normal_roughness_deg(20) > ROUGH_NORMALS_DEG > smooth.normal_roughness_deg(20)
    record = Decisions()
    assert shading_normals(rough, True, 20, record) == 20
    assert shading_normals(smooth, True, 20, record) == 0
    assert shading_normals(rough, False, 20, record) == 0 and shading_normals(rough, True, 0, record) == 0
    entries = [d for d in record.to_json() if d["component"] == "smoothed shading normals"]
    assert [d["kept"] for d in entries] == [True, False]
    assert entries[0]["measured"]["normal_roughness_deg"] > ROUGH_NORMALS_DEG


def test_auto_reflects_the_view_direction_about_smooth_normals_only():
    from neuras_distill.pipeline.choices import Decisions, reflected_view_input

    smooth, rough = two_spheres(core_faces=False), bumpy(two_spheres(core_faces=False), amplitude=0.4)
    cfg = DistillConfig()
    assert cfg.texture.view_input == "auto"
    record = Decisions()
    on, smooth_turn = reflected_view_input(smooth, cfg, True, False, record)
    off, rough_turn = reflected_view_input(rough, cfg, True, False, record)
    assert on and not off, (smooth_turn, rough_turn)
    assert smooth_turn < 20.0 < rough_turn
    assert [d.kept for d in record.items] == [True, False]
    assert reflected_view_input(smooth, cfg, True, True, record) == (False, None)       # a fringe shell
    assert reflected_view_input(smooth, cfg, False, False, record) == (False, None)     # no direction input
    cfg = cfg.updated({"texture": {"view_input": "direction"}})
    assert reflected_view_input(smooth, cfg, True, False, record) == (False, None)
    cfg = cfg.updated({"texture": {"view_input": "reflection"}})
    assert reflected_view_input(rough, cfg, True, False, record) == (True, None)
