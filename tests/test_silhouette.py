"""The soft-silhouette pass (playback/silhouette.py): GL and its numpy mirror agree, and only edges change."""

import numpy as np
import pytest

from neuras_distill.bake.bundle import bake
from neuras_distill.geometry.mesh import MeshData
from neuras_distill.playback.shaders import SILHOUETTE_FRAGMENT_SHADER
from neuras_distill.playback.silhouette import (SHELL_COVERAGE, blend_silhouettes,
                                                layer_coverage, silhouette_edges)
from test_two_layer import _sphere, cameras, gl

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_edges_are_the_pixels_on_both_sides_of_the_coverage_boundary():
    cov = np.zeros((8, 10), bool)
    cov[2:6, 3:10] = True                        # touches the right border
    edges = silhouette_edges(cov)
    assert edges[2, 5] and edges[1, 5]           # the boundary row inside and the one outside
    assert not edges[4, 5] and not edges[7, 5]   # deep inside / far outside
    assert not edges[3:5, 9].any()               # the image border is no silhouette
    image = np.zeros((8, 10, 3), np.float32)
    image[cov] = 1.0
    out = blend_silhouettes(image, cov)
    np.testing.assert_allclose(out[2, 5], 0.75)          # tent [1 2 1] / 4 across the edge: 1 + 2 of 4 covered
    np.testing.assert_allclose(out[1, 5], 0.25)
    assert (out[~edges] == image[~edges]).all()


def test_the_seam_between_a_core_and_its_shell_is_an_edge():
    face_id = np.full((12, 14), -1)
    face_id[1:11, 1:13] = 50                     # shell (faces >= 40)
    face_id[4:8, 4:10] = 7                       # core
    cover = layer_coverage(face_id, core_faces=40)
    assert cover[0, 0] == 0.0 and cover[1, 1] == SHELL_COVERAGE and cover[4, 4] == 1.0
    edges = silhouette_edges(cover)
    assert edges[4, 6] and edges[3, 6]           # the core's outer row and the shell row beside it
    assert not edges[5, 6] and not edges[2, 2]   # inside the core; a pixel among shell pixels only
    assert edges[1, 6] and edges[0, 6] and not edges[0, 0]    # the shell's rim as before; outside
    one_layer = silhouette_edges(face_id >= 0)
    assert not one_layer[4, 6] and not one_layer[3, 6] and (one_layer <= edges).all()
    np.testing.assert_array_equal(silhouette_edges(layer_coverage(face_id, None)), one_layer)


def test_the_glsl_test_value_is_the_shell_coverage():
    assert f"abs(m - {SHELL_COVERAGE:.5f})" in SILHOUETTE_FRAGMENT_SHADER


@gl
@pytest.mark.gl
# on the tiles along the edges / over the mesh's box when there are too many edges / over the box (a rasterizing GPU)
# / a two-layer mesh (core and shell: the core's seam inside the shell is blended too)
@pytest.mark.parametrize("max_tiled_edges,tiles,layers", [(6000, True, 1), (0, True, 1), (6000, False, 1),
                                                           (6000, True, 2)])
def test_the_gl_pass_is_its_numpy_mirror_and_changes_only_edges(monkeypatch, max_tiled_edges, tiles, layers):
    from test_bake import make_model
    from test_two_layer import two_spheres

    import neuras_distill.playback.silhouette_strips as strips

    monkeypatch.setattr(strips, "MAX_TILED_EDGES", max_tiled_edges)
    from neuras_distill.playback.rasterize import rasterize_gbuffer
    from neuras_distill.playback.renderer import BundleRenderer

    v, f, uv = _sphere(0.5)
    mesh = MeshData(v, f, uv) if layers == 1 else two_spheres()
    model = make_model(h=16, w=16, mesh_layers=layers, use_facing=layers == 2)
    bundle = bake(model, mesh, (0.9, 0.8, 0.7), extra_manifest={"silhouette_blend": True})
    cams = cameras(2, 72)
    gbuffer = rasterize_gbuffer(mesh, cams)
    coverage = [layer_coverage(gbuffer.face_id[i], mesh.core_faces) for i in range(len(cams))]
    with BundleRenderer(bundle, silhouette_tiles=tiles) as soft, BundleRenderer(bundle, silhouette_blend=False) as hard:
        assert soft.silhouette_blend and not hard.silhouette_blend and (soft.edges is not None) == tiles
        for i in range(len(cams)):
            plain, blended = hard.render(cams, i), soft.render(cams, i)
            edges = silhouette_edges(coverage[i])
            assert edges.sum() > 100
            if layers == 2:                      # the seam: core pixels beside shell pixels are edges too
                seam = edges & (coverage[i] == 1.0) & ~silhouette_edges(gbuffer.coverage[i])
                assert seam.sum() > 50
            diff = np.abs(blended - blend_silhouettes(plain, coverage[i]))
            assert diff.max() <= 2.01 / 255 and diff.mean() < 0.1 / 255     # GL's LINEAR weights: 8-bit fixed point
            assert (blended[~edges] == plain[~edges]).all()
            assert np.abs(blended[edges] - plain[edges]).mean() > 0.02
        assert soft.time_frames(cams, warmup=1, frames=2)["median_ms"] > 0


def test_the_pass_runs_where_the_fields_edges_are_soft_at_the_playing_resolution():
    from types import SimpleNamespace

    from neuras_distill.pipeline.choices import Decisions, silhouette_blend

    train, test = SimpleNamespace(width=640), SimpleNamespace(width=1920, height=1080)
    record = Decisions()
    assert silhouette_blend("auto", 1.5, train, test, record) and not record.left_out()   # 4.5 px at 1080p
    assert record.items[-1].kept and record.items[-1].measured["edge_pixels"] == 4.5
    assert not silhouette_blend("auto", 0.4, train, SimpleNamespace(width=640, height=360), record)
    left_out = record.left_out()
    assert left_out[-1]["component"] == "soft-silhouette pass" and "0.4 pixels" in left_out[-1]["reason"]
    assert not silhouette_blend("off", 9.0, train, test, record)
    assert record.left_out()[-1]["reason"] == "turned off by configuration"
    assert silhouette_blend("on", 0.0, train, test, Decisions())
