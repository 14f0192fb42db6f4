"""Atlas pages (docs/architecture.md "Atlas pages"): an atlas side above ``texture.page_size`` is
packed into square pages stacked along v, trained as one atlas whose bilinear lookups stay within a page, and
played as a texture array by every player."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from neuras_distill.bake.bundle import PAGES_FORMAT_VERSION, bake, load_bundle
from neuras_distill.bake.glsl import to_glsl_es
from neuras_distill.errors import BadInputError
from neuras_distill.geometry.mesh import MeshData
from neuras_distill.geometry.unwrap import atlas_shape, unwrap
from neuras_distill.neural.model import NeuralTextureModel
from neuras_distill.neural.texture import bilinear_corners

from test_bake import VERT, draw_with_features, gl_context, quad_view_dirs

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def sphere_mesh() -> MeshData:
    m = trimesh.creation.icosphere(4)
    return MeshData(m.vertices.astype(np.float32), m.faces.astype(np.int64), None, {})


def test_an_atlas_above_the_page_size_is_unwrapped_into_stacked_pages():
    mesh = sphere_mesh()
    one = unwrap(mesh, resolution=256)
    paged = unwrap(mesh, resolution=256, page_size=128)
    assert atlas_shape(one.stats) == (256, 256, 1) and one.stats["uv_pages"] == 1
    height, side, pages = atlas_shape(paged.stats)
    assert side == 128 and pages >= 2 and height == pages * 128
    # no face crosses a page, and every corner texel of a bilinear lookup inside a face lies on its page
    page = np.floor(paged.uvs[:, 1] * pages)
    face_page = page[paged.faces]
    assert (face_page.min(axis=1) == face_page.max(axis=1)).all()
    local = (paged.uvs[:, 1] * pages - page) * side
    assert local.min() >= 0.5 - 1e-3 and local.max() <= side - 0.5 + 1e-3
    # the same texels per unit as the one-atlas packing: the charts cover as many texels
    texels_one, texels_paged = one.uv_area() * 256 ** 2, paged.uv_area() * height * side
    assert abs(texels_paged / texels_one - 1.0) < 0.05, (texels_one, texels_paged)
    assert paged.stats["uv_padding_texels"] >= 2.0


def test_bilinear_corners_stay_on_the_uvs_page():
    side, pages = 4, 3
    # the top edge of page 0 and the bottom edge of page 1 (rows 3 and 4 of the stacked 12 x 4 atlas)
    uv = torch.tensor([[0.6, (1.0 - 0.01) / pages], [0.6, (1.0 + 0.01) / pages], [0.6, 1.0]])
    idx, w = bilinear_corners(uv, side * pages, side, pages)
    rows = idx // side
    assert (rows[0] <= 3).all() and (rows[1] >= 4).all() and (rows[1] <= 7).all() and (rows[2] >= 8).all()
    assert torch.allclose(w.sum(dim=1), torch.ones(3))
    # one page: exactly the plain lookup
    plain = torch.rand(64, 2)
    a, wa = bilinear_corners(plain, side, side)
    b, wb = bilinear_corners(plain, side, side, 1)
    assert torch.equal(a, b) and torch.equal(wa, wb)


def test_pages_need_a_stacked_height():
    with pytest.raises(ValueError, match="pages"):
        NeuralTextureModel(10, 4, pages=3)


def paged_model(pages: int = 3, side: int = 8, use_viewdir: bool = True) -> NeuralTextureModel:
    torch.manual_seed(0)
    m = NeuralTextureModel(pages * side, side, feature_dim=8, num_codes=64, use_viewdir=use_viewdir, pages=pages)
    with torch.no_grad():
        m.texture.data.normal_(0.0, 1.0)
        for layer in m.shader.layers:
            layer.weight.mul_(2.0)
            layer.bias.normal_(0.0, 0.3)
    m.start_vq()
    m.eval()
    return m


@pytest.mark.gl
def test_the_paged_shader_plays_what_the_torch_model_computes():
    """The baked shader's texture-array lookup (layer from v, corners clamped within the layer) against the
    torch model's stacked lookup, over uvs that cross every page border and the atlas's edges."""
    moderngl, ctx = gl_context()
    m = paged_model()
    quad = MeshData(np.float32([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]), np.array([[0, 1, 2], [0, 2, 3]]),
                    np.float32([[0, 0], [1, 0], [1, 1], [0, 1]]))
    b = bake(m, quad, (0, 0, 0))
    assert b.manifest["atlas_pages"] == 3 and "usampler2DArray u_index" in b.fragment_shader
    res, cam = 96, np.float32([0.3, -2.5, 0.4])
    uv0, uv_scale = np.float32([-0.05, -0.02]), np.float32([1.1, 1.04])
    try:
        prog = ctx.program(vertex_shader=VERT, fragment_shader=b.fragment_shader)
        prog["u_uv0"].value, prog["u_uv_scale"].value = tuple(uv0), tuple(uv_scale)
        prog["u_cam_pos"].value = tuple(cam)
        idx = b.textures["u_index"]
        t_idx = ctx.texture_array((idx.shape[1], idx.shape[0] // 3, 3), 1, data=idx.tobytes(), dtype="u2")
        gl = draw_with_features(moderngl, ctx, prog, t_idx, b.textures["u_codebook"], res)
    finally:
        ctx.release()
    uv, dirs, _, _ = quad_view_dirs(uv0, uv_scale, res, cam)
    ref = m.render_gbuffer(uv, np.ones((res, res), bool), dirs, np.zeros(3))
    diff = np.abs(gl - ref)
    assert ref.std() > 0.05
    assert diff.max() <= 1e-3, diff.max()
    # the stacked lookup is not a plain lookup of the stacked image: at the page borders they differ
    plain = NeuralTextureModel(24, 8, feature_dim=8, num_codes=64, use_viewdir=True)
    plain.load_state_dict(m.state_dict())
    plain.eval()
    assert np.abs(plain.render_gbuffer(uv, np.ones((res, res), bool), dirs, np.zeros(3)) - ref).max() > 1e-2


def test_a_paged_bundle_round_trips_as_format_4(tmp_path):
    m = paged_model()
    mesh = MeshData(np.float32([[0, 0, 0], [1, 0, 0], [1, 1, 0]]), np.array([[0, 1, 2]]),
                    np.float32([[0.1, 0.1], [0.9, 0.1], [0.9, 0.3]]))
    b = bake(m, mesh, (0, 0, 0))
    folder = b.save(tmp_path / "paged")
    again = load_bundle(folder)
    assert again.manifest["atlas_pages"] == 3 and again.textures["u_index"].shape == (24, 8)
    import json

    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["format_version"] == PAGES_FORMAT_VERSION
    manifest["atlas_pages"] = 5                                  # 24 rows are not 5 pages of 8
    (folder / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(BadInputError, match="atlas_pages"):
        load_bundle(folder)


def test_the_web_dialect_of_a_paged_shader_gathers_from_the_layer():
    src = to_glsl_es(bake(paged_model(), MeshData(np.float32([[0, 0, 0], [1, 0, 0], [1, 1, 0]]),
                                                  np.array([[0, 1, 2]]), np.float32([[0, 0], [1, 0], [1, 1]])),
                          (0, 0, 0)).fragment_shader)
    assert "precision highp usampler2DArray;" in src
    assert "uvec4 neurasGather(usampler2DArray s, vec3 p)" in src and "textureGather(" not in src


def quads_on_pages(pages: int) -> MeshData:
    """A unit quad per page, side by side in x, each quad's uvs inside its own page."""
    v = np.float32([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    uv = np.float32([[0, 0], [1, 0], [1, 1], [0, 1]]) * 0.8 + 0.1
    return MeshData(np.concatenate([v + [1.2 * p, 0, 0] for p in range(pages)]).astype(np.float32),
                    np.concatenate([np.array([[0, 1, 2], [0, 2, 3]]) + 4 * p for p in range(pages)]),
                    np.concatenate([uv * [1, 1 / pages] + [0, p / pages] for p in range(pages)]).astype(np.float32))


@pytest.mark.gl
def test_every_view_mode_plays_a_paged_bundle():
    from neuras_distill.playback.renderer import BundleRenderer
    from neuras_distill.playback.view_modes import mode_bundle
    from neuras_distill.render.cameras import Cameras

    b = bake(paged_model(pages=3, side=8), quads_on_pages(3), (0, 0, 0))
    b.plain_rgb = np.random.default_rng(0).integers(0, 256, (24, 8, 3), dtype=np.uint8)
    cams = Cameras.orbit(np.array([1.7, 0.5, 0.0]), 4.0, 1, width=64, height=48, elevation_deg=80.0)
    for mode in ("neural", "plain", "index", "uv"):
        with BundleRenderer(mode_bundle(b, mode)) as player:
            image = player.render(cams, 0)
        assert (np.abs(image).sum(-1) > 1e-3).mean() > 0.1, mode           # the quads are drawn
        assert len(np.unique(image.reshape(-1, 3).round(3), axis=0)) > 8, mode


@pytest.mark.gl
def test_more_pages_than_the_gl_holds_exit_2_with_one_line(tmp_path, capsys):
    from neuras_distill.cli import main
    from neuras_distill.playback.context import get_context

    layers = int(get_context().info.get("GL_MAX_ARRAY_TEXTURE_LAYERS", 0) or 0)
    if not layers:
        pytest.skip("this GL does not report GL_MAX_ARRAY_TEXTURE_LAYERS")
    pages = layers + 1
    torch.manual_seed(0)
    m = NeuralTextureModel(pages, 1, feature_dim=4, num_codes=8, use_viewdir=False, pages=pages)
    m.start_vq()
    bake(m, quads_on_pages(1), (0, 0, 0)).save(tmp_path / "bundle")
    out = tmp_path / "orbit"
    rc = main(["view", str(tmp_path / "bundle"), "--orbit", "--frames", "1", "--width", "16", "--height", "16",
               "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert f"{pages} pages" in err and f"{layers} pages" in err and "texture.page_size" in err, err
    assert not out.exists() or not any(out.iterdir())


def test_a_page_size_out_of_range_is_refused():
    import neuras_distill as nd

    with pytest.raises(BadInputError, match="page_size"):
        nd.load_config("fast", overrides={"texture": {"page_size": 32}})


@pytest.mark.gl
@pytest.mark.slow
def test_a_run_with_a_small_page_size_plays_its_atlas_in_pages(small_run, tmp_path, torch_threads):
    """conftest's small run (a 128² atlas) again with texture.page_size 64: the same charts at the same texels
    per unit in pages of 64², trained, baked and played as a texture array; as good as the one-atlas run."""
    import json

    import neuras_distill as nd
    from neuras_distill.scenes.analytic import SphereSDF

    _, one_out = small_run
    one = json.loads((one_out / "report.json").read_text())
    field = SphereSDF(center=(0.0, 0.0, 0.0), radius=0.5)
    cfg = nd.load_config("fast", overrides={"train": {"steps": 250}, "eval": {"width": 128, "fps_frames": 5},
                                            "texture": {"resolution": 128, "num_codes": 128, "page_size": 64}})
    with torch_threads(2):
        nd.distill(field, field.default_cameras(10, 96, 96), cfg, out=tmp_path / "run", progress=False,
                   log=lambda m: None)
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    assert one["atlas_pages"] == 1 and rep["atlas_pages"] >= 2 and rep["texture_resolution"] == [64, 64]
    assert any(d["component"] == "atlas pages" and d["measured"]["pages"] == rep["atlas_pages"]
               for d in rep["decisions"])
    bundle = load_bundle(tmp_path / "run" / "bundle")
    assert bundle.manifest["atlas_pages"] == rep["atlas_pages"]
    assert bundle.textures["u_index"].shape == (64 * rep["atlas_pages"], 64)
    assert rep["parity_psnr"] >= 50.0                    # the GL texture array plays what torch computes
    assert rep["psnr"] >= one["psnr"] - 0.5, (rep["psnr"], one["psnr"])
    assert rep["plain_texture"]["psnr"] >= one["plain_texture"]["psnr"] - 0.5
    print(f"one atlas {one['psnr']:.2f} dB, {rep['atlas_pages']} pages {rep['psnr']:.2f} dB "
          f"(parity {rep['parity_psnr']:.1f} dB)")

