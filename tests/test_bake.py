"""Tests of neuras_distill.bake: bundle round trip and validation, GLSL parity with the torch forward pass."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from neuras_distill.bake.bundle import bake, load_bundle
from neuras_distill.bake.glsl import generate_fragment_shader, glsl_float
from neuras_distill.neural.model import NeuralTextureModel, reflected_directions
from neuras_distill.errors import BadInputError
from neuras_distill.geometry.mesh import MeshData


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def make_model(use_viewdir=True, dim=8, h=12, w=20, k=32, seed=0, use_facing=False, mesh_layers=1,
               core_viewdir=None, shell_hidden=None, output_layers=2, view_reflect=False):
    torch.manual_seed(seed)
    m = NeuralTextureModel(h, w, feature_dim=dim, num_codes=k, use_viewdir=use_viewdir, use_facing=use_facing,
                           mesh_layers=mesh_layers, core_viewdir=core_viewdir, shell_hidden=shell_hidden,
                           output_layers=output_layers, view_reflect=view_reflect)
    with torch.no_grad():
        m.texture.data.normal_(0.0, 1.0)
        for layer in (layer for shader in m.shaders for layer in shader.layers):
            layer.weight.mul_(2.0)
            layer.bias.normal_(0.0, 0.3)
    m.start_vq()
    m.eval()
    return m


def b_header(model) -> str:
    """The first comment line of the model's generated fragment shader (what it says about the MLP)."""
    return generate_fragment_shader(model).splitlines()[1]


def quad_mesh():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
    return MeshData(v, np.array([[0, 1, 2], [0, 2, 3]]), v[:, :2].copy())


def test_glsl_float_is_exact():
    for x in [0.1, -1e-8, 3.0, 123456.789, 1 / 3, -0.0, 1e-30]:
        s = glsl_float(x)
        assert "." in s or "e" in s
        assert np.float32(float(s)) == np.float32(x)


def test_bundle_round_trip_exact(tmp_path):
    m = make_model()
    b = bake(m, quad_mesh(), (0.1, 0.2, 0.3), extra_manifest={"scene": "test"})
    assert b.textures["u_index"].dtype == np.uint16 and b.textures["u_codebook"].dtype == np.float32
    assert b.textures["u_codebook"].shape[1:] == (2, 4)
    assert b.manifest["num_codes"] == b.textures["u_codebook"].shape[0] <= 32
    b.save(tmp_path / "bundle")
    c = load_bundle(tmp_path / "bundle")
    assert np.array_equal(c.textures["u_index"], b.textures["u_index"])
    assert c.textures["u_index"].dtype == np.uint16
    assert np.array_equal(c.textures["u_codebook"], b.textures["u_codebook"])
    assert np.array_equal(c.mesh.vertices, b.mesh.vertices) and np.array_equal(c.mesh.faces, b.mesh.faces)
    assert np.array_equal(c.mesh.uvs, b.mesh.uvs)
    assert c.fragment_shader == b.fragment_shader
    assert np.array_equal(c.background_color, np.float32([0.1, 0.2, 0.3]))
    assert c.manifest == b.manifest and c.manifest["scene"] == "test"
    on_disk = sum(p.stat().st_size for p in (tmp_path / "bundle").iterdir())
    assert b.nbytes_on_disk() == on_disk
    assert b.float16_nbytes() == 12 * 20 * 8 * 2


def test_bundle_is_encoded_once_until_it_changes(tmp_path, monkeypatch):
    """save, nbytes_on_disk and feature_nbytes share one encoding; any change (an attribute set, an array
    changed in place, the manifest edited) encodes afresh, and the bytes always equal a fresh encoding's."""
    from neuras_distill.bake.bundle import Bundle

    encodes = []
    encode_files = Bundle._encode_files

    def counting(self):
        encodes.append(1)
        return encode_files(self)

    monkeypatch.setattr(Bundle, "_encode_files", counting)
    b = bake(make_model(), quad_mesh(), (0.1, 0.2, 0.3), extra_manifest={"scene": "test"})
    b.save(tmp_path / "one")
    total, features = b.nbytes_on_disk(), b.feature_nbytes()
    assert len(encodes) == 1
    assert total == sum(p.stat().st_size for p in (tmp_path / "one").iterdir())
    assert features == sum((tmp_path / "one" / n).stat().st_size
                           for n in ("feature_index.png", "codebook.npy"))

    def fresh(bundle):                  # what an encoding without the kept bytes gives
        return encode_files(bundle)

    changes = [lambda: setattr(b, "plain_rgb", np.full((12, 20, 3), 7, np.uint8)),  # an attribute set
               lambda: b.plain_rgb.__setitem__((0, 0, 0), 200),                      # changed in place
               lambda: b.textures["u_index"].__setitem__((0, 0), (b.textures["u_index"][0, 0] + 1) % 8),
               lambda: b.mesh.vertices.__setitem__((0, 0), 0.5),
               lambda: b.manifest.update(scene="other"),                               # the manifest edited
               lambda: setattr(b, "fragment_shader", b.fragment_shader + "\n")]
    for i, change in enumerate(changes):
        before = b._encode()
        change()
        after = b._encode()
        assert len(encodes) == 2 + i, f"change {i} was not noticed"
        assert after != before and after == fresh(b)
        b.nbytes_on_disk()
        b.save(tmp_path / f"c{i}")
        assert len(encodes) == 2 + i, f"change {i}: encoded again without a change"
        assert {p.name: p.read_bytes() for p in (tmp_path / f"c{i}").iterdir()} == after


def test_load_bundle_missing_or_corrupt(tmp_path):
    with pytest.raises(BadInputError, match="does not exist"):
        load_bundle(tmp_path / "nothing")
    d = make_model_bundle(tmp_path)
    (d / "codebook.npy").unlink()
    with pytest.raises(BadInputError, match="codebook.npy"):
        load_bundle(d)
    d = make_model_bundle(tmp_path, "b2")
    raw = bytearray((d / "feature_index.png").read_bytes())
    raw[-20] ^= 0xFF
    (d / "feature_index.png").write_bytes(bytes(raw))
    with pytest.raises(BadInputError, match="feature_index.png"):
        load_bundle(d)
    d = make_model_bundle(tmp_path, "b3")
    (d / "manifest.json").write_text("{not json")
    with pytest.raises(BadInputError, match="manifest.json"):
        load_bundle(d)
    d = make_model_bundle(tmp_path, "b4")
    man = json.loads((d / "manifest.json").read_text())
    man["texture_width"] = 7
    (d / "manifest.json").write_text(json.dumps(man))
    with pytest.raises(BadInputError, match="feature_index.png"):
        load_bundle(d)


def make_model_bundle(tmp_path, name="b1"):
    return bake(make_model(k=8, h=4, w=5), quad_mesh(), (0, 0, 0)).save(tmp_path / name)


def test_bake_needs_uvs_and_vq_for_big_atlas():
    m = make_model()
    with pytest.raises(BadInputError, match="UVs"):
        bake(m, MeshData(np.zeros((3, 3)), np.array([[0, 1, 2]])), (0, 0, 0))
    big = NeuralTextureModel(300, 300, feature_dim=4, use_vq=False)
    with pytest.raises(BadInputError, match="65535"):
        big.baked_features()


def test_the_reflected_view_input_mirrors_the_direction_about_the_normal_on_covered_pixels_only():
    from neuras_distill.neural.model import view_inputs

    d = np.float32([[[0.6, 0.0, -0.8], [0.6, 0.0, -0.8]]])
    n = np.float32([[[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]])
    out = view_inputs(d, np.array([[3, -1]]), n, use_facing=True, reflect=True)
    assert np.allclose(out[0, 0], [0.6, 0.0, 0.8, 0.8])        # reflected, facing |n . d| unchanged
    assert np.allclose(out[0, 1], [0.6, 0.0, -0.8, 0.0])       # no face: the ray's own direction (skyboxes)
    assert np.allclose(view_inputs(d, np.array([[3, -1]]), n, use_facing=False), d)


def test_shader_has_no_viewdir_code_when_unused():
    src = generate_fragment_shader(make_model(use_viewdir=False))
    assert "u_cam_pos" not in src and "v_world" not in src and "normalize" not in src
    src = generate_fragment_shader(make_model(use_viewdir=True))
    assert "uniform vec3 u_cam_pos;" in src and "normalize(v_world - u_cam_pos)" in src


# ------------------------------------------------------------------------------------------ GL parity
VERT = """
#version 330 core
in vec2 in_pos;
uniform vec2 u_uv0;
uniform vec2 u_uv_scale;
out vec2 v_uv;
out vec3 v_world;
out vec3 v_normal;
void main() {
    vec2 t = in_pos * 0.5 + 0.5;
    v_uv = u_uv0 + t * u_uv_scale;
    v_world = vec3(2.0 * t.x - 1.0, 0.0, 2.0 * t.y - 1.0);
    v_normal = vec3(0.3 * (2.0 * t.x - 1.0), 1.0, 0.2 * (2.0 * t.y - 1.0));  // linear: interpolated exactly
    gl_Position = vec4(in_pos, 0.0, 1.0);
}
"""


def quad_uvs(uv0, uv_scale, res: int):
    """The uvs :data:`VERT` interpolates at the pixel centres of a res x res :func:`draw_fullscreen`: ((res, res,
    2) float32 uv, (res, res) t.x, (res, res) t.y)."""
    t = (np.arange(res, dtype=np.float32) + 0.5) / res
    ty, tx = np.meshgrid(t, t, indexing="ij")
    return np.stack([uv0[0] + tx * uv_scale[0], uv0[1] + ty * uv_scale[1]], -1).astype(np.float32), tx, ty


def quad_view_dirs(uv0, uv_scale, res: int, cam) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`quad_uvs` and the unit directions from ``cam`` to :data:`VERT`'s world points at the same pixel
    centres: ((res, res, 2) uv, (res, res, 3) float32 dirs, t.x, t.y)."""
    uv, tx, ty = quad_uvs(uv0, uv_scale, res)
    d = np.stack([2 * tx - 1, np.zeros_like(tx), 2 * ty - 1], -1) - cam
    return uv, (d / np.linalg.norm(d, axis=-1, keepdims=True)).astype(np.float32), tx, ty


def draw_with_features(moderngl, ctx, prog, t_idx, codebook: np.ndarray, res: int) -> np.ndarray:
    """Bind ``t_idx`` (the index texture, or texture array) to unit 0 and ``codebook`` (rows, C, 4) float32 to
    unit 1 as the shader's ``u_index`` / ``u_codebook`` (nearest, clamped), then :func:`draw_fullscreen`."""
    t_cb = ctx.texture((codebook.shape[1], codebook.shape[0]), 4, data=codebook.tobytes(), dtype="f4")
    for t in (t_idx, t_cb):
        t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        t.repeat_x = t.repeat_y = False
    prog["u_index"].value, prog["u_codebook"].value = 0, 1
    t_idx.use(0)
    t_cb.use(1)
    return draw_fullscreen(moderngl, ctx, prog, res)


def draw_fullscreen(moderngl, ctx, prog, res: int) -> np.ndarray:
    """Draw ``prog`` (vertex stage :data:`VERT`) over a res x res float framebuffer: (res, res, 3) float32,
    row r is t.y = (r + 0.5) / res."""
    quad = ctx.buffer(np.float32([-1, -1, 1, -1, -1, 1, 1, 1]).tobytes())
    vao = ctx.vertex_array(prog, [(quad, "2f", "in_pos")])
    color = ctx.texture((res, res), 4, dtype="f4")
    fbo = ctx.framebuffer(color_attachments=[color])
    fbo.use()
    ctx.viewport = (0, 0, res, res)
    fbo.clear(0.0, 0.0, 0.0, 0.0)
    vao.render(moderngl.TRIANGLE_STRIP)
    return np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(res, res, 4)[..., :3]


def gl_context():
    """A fresh headless EGL context. Its callers are marked ``gl``: tests/conftest.py's require_gl skips them
    (fails them under CI=true) before they run when no context can be made."""
    import moderngl

    return moderngl, moderngl.create_context(standalone=True, backend="egl")


@pytest.mark.parametrize("use_viewdir,dim,use_facing,max_rows,output_layers,reflect",
                         [(True, 8, False, None, 2, False), (False, 6, False, None, 2, False),
                          (True, 8, True, None, 2, False), (False, 5, True, None, 2, False),
                          (True, 8, False, 7, 2, False), (False, 5, True, 3, 2, False),
                          (True, 8, False, None, 1, False), (True, 8, True, None, 3, False),
                          (True, 8, False, None, 3, True), (True, 8, True, None, 2, True)])
@pytest.mark.gl
def test_glsl_parity_with_torch(use_viewdir, dim, use_facing, max_rows, output_layers, reflect, monkeypatch,
                                tmp_path):
    moderngl, ctx = gl_context()
    m = make_model(use_viewdir=use_viewdir, dim=dim, use_facing=use_facing, output_layers=output_layers,
                   view_reflect=reflect)
    assert (f"({output_layers} layers composited)" in b_header(m)) == (output_layers > 1)
    if max_rows is not None:          # a codebook taller than the largest texture side: several codes per row
        import neuras_distill.bake.bundle as bundle_module

        monkeypatch.setattr(bundle_module, "CODEBOOK_MAX_ROWS", max_rows)
    b = bake(m, quad_mesh(), (0, 0, 0))
    if max_rows is not None:
        per_row = b.manifest["codes_per_row"]
        assert per_row > 1 and b.textures["u_codebook"].shape[0] <= max_rows
        assert b.textures["u_codebook"].shape[1] == per_row * ((dim + 3) // 4)
        assert f"% {per_row})" in b.fragment_shader
        again = load_bundle(b.save(tmp_path / "wrapped"))
        assert np.array_equal(again.textures["u_codebook"], b.textures["u_codebook"])
    else:
        assert "codes_per_row" not in b.manifest
    res = 96
    uv0, uv_scale = np.float32([-0.1, -0.05]), np.float32([1.2, 1.1])    # a border of clamped lookups
    cam = np.float32([0.3, -2.5, 0.4])
    try:
        prog = ctx.program(vertex_shader=VERT, fragment_shader=b.fragment_shader)
        prog["u_uv0"].value = tuple(uv0)
        prog["u_uv_scale"].value = tuple(uv_scale)
        if use_viewdir or use_facing:
            prog["u_cam_pos"].value = tuple(cam)
        else:
            assert "u_cam_pos" not in prog
        idx = b.textures["u_index"]
        t_idx = ctx.texture((idx.shape[1], idx.shape[0]), 1, data=idx.tobytes(), dtype="u2")
        gl = draw_with_features(moderngl, ctx, prog, t_idx, b.textures["u_codebook"], res)
    finally:
        ctx.release()
    # torch reference on the same uv / dirs (row r of the readback is t.y = (r + 0.5) / res)
    uv, dirs, tx, ty = quad_view_dirs(uv0, uv_scale, res, cam)
    # the shading normal varies over the quad (VERT's v_normal, normalized per pixel)
    n = np.stack([0.3 * (2 * tx - 1), np.ones_like(tx), 0.2 * (2 * ty - 1)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    unreflected = dirs
    if reflect:
        assert "reflect(dir, nrm)" in b.fragment_shader and b.manifest["view_input"] == "reflection"
        dirs = reflected_directions(dirs, n, np.ones((res, res), bool))
    if use_facing:
        facing = np.abs((n * dirs).sum(-1, keepdims=True))
        dirs, unreflected = (np.concatenate([d, facing], axis=-1).astype(np.float32) for d in (dirs, unreflected))
        no_facing = m.render_gbuffer(uv, np.ones((res, res), bool), np.concatenate([dirs[..., :3], 0 * dirs[..., 3:]], -1),
                                     np.zeros(3))
        assert np.abs(no_facing - gl).max() > 1e-2       # the facing input changes the picture
    if reflect:                 # the reflected direction changes the picture
        assert np.abs(m.render_gbuffer(uv, np.ones((res, res), bool), unreflected, np.zeros(3)) - gl).max() > 1e-2
    ref = m.render_gbuffer(uv, np.ones((res, res), bool), dirs, np.zeros(3))
    diff = np.abs(gl - ref)
    mse = float((diff ** 2).mean())
    psnr = 10 * np.log10(1.0 / max(mse, 1e-20))
    assert ref.std() > 0.05          # the test image is not flat
    assert diff.max() <= 1e-3 and psnr >= 60.0, (diff.max(), psnr)
    print(f"parity use_viewdir={use_viewdir} use_facing={use_facing}: max abs diff {diff.max():.2e}, PSNR {psnr:.1f} dB")
