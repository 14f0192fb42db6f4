"""The plain RGB texture baseline (bake/plain_texture.py): one shader evaluation per texel, played bilinearly."""

import numpy as np
import pytest
import torch

from neuras_distill.bake.glsl import plain_fragment_shader
from neuras_distill.bake.plain_texture import plain_texture, texel_view_inputs
from neuras_distill.neural.texture import bilinear_corners
from test_bake import VERT, draw_fullscreen, gl_context, make_model, quad_uvs

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_texel_view_inputs_average_the_pixels_of_each_texel():
    # a 2 x 2 atlas; pixels land in texels (0,0) twice, (1,1) once, one pixel is uncovered
    uv = np.float32([[[[0.1, 0.1], [0.2, 0.3], [0.9, 0.9], [0.5, 0.1]]]])
    cov = np.array([[[True, True, True, False]]])
    inputs = np.float32([[[[1, 0, 0, 0.2], [0, 1, 0, 0.4], [0, 0, -1, 1.0], [5, 5, 5, 5]]]])
    mean, count = texel_view_inputs(uv, cov, inputs, 2, 2)
    np.testing.assert_array_equal(count, [2, 0, 0, 1])
    np.testing.assert_allclose(mean[0], [0.5, 0.5, 0, 0.3], atol=1e-6)
    np.testing.assert_allclose(mean[3], [0, 0, -1, 1.0], atol=1e-6)


def test_each_texel_is_the_model_at_its_centre_with_the_mean_view_of_its_pixels():
    m = make_model(use_viewdir=True, h=6, w=8)
    gen = np.random.default_rng(0)
    uv = gen.random((2, 10, 10, 2), dtype=np.float32)
    dirs = gen.normal(size=(2, 10, 10, 3)).astype(np.float32)
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    rgb = plain_texture(m, uv, np.ones((2, 10, 10), bool), dirs)
    assert rgb.shape == (6, 8, 3) and 0 <= rgb.min() and rgb.max() <= 1
    mean, count = texel_view_inputs(uv, np.ones((2, 10, 10), bool), dirs, 6, 8)
    j, i = np.unravel_index(int(np.argmax(count)), (6, 8))
    d = torch.from_numpy(mean[j * 8 + i][None])
    d = d / d.norm()
    with torch.no_grad():
        expected, _ = m(torch.tensor([[(i + 0.5) / 8, (j + 0.5) / 6]]), d)
    np.testing.assert_allclose(rgb[j, i], expected[0].numpy(), atol=1e-6)


@pytest.mark.gl
def test_the_plain_shader_plays_the_texture_bilinearly_like_torch():
    moderngl, ctx = gl_context()
    h, w, res = 5, 7, 64
    rgb = np.random.default_rng(1).random((h, w, 3), dtype=np.float32)
    uv0, uv_scale = np.float32([-0.1, -0.05]), np.float32([1.2, 1.1])        # clamped borders too
    try:
        prog = ctx.program(vertex_shader=VERT, fragment_shader=plain_fragment_shader(w, h))
        prog["u_uv0"].value = tuple(uv0)
        prog["u_uv_scale"].value = tuple(uv_scale)
        tex = ctx.texture((w, h), 3, data=rgb.tobytes(), dtype="f4")
        tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        prog["u_rgb"].value = 0
        tex.use(0)
        gl = draw_fullscreen(moderngl, ctx, prog, res)
    finally:
        ctx.release()
    uv = quad_uvs(uv0, uv_scale, res)[0].reshape(-1, 2)
    idx, wts = bilinear_corners(torch.from_numpy(uv), h, w)
    ref = (wts[..., None] * torch.from_numpy(rgb.reshape(-1, 3))[idx]).sum(1).numpy().reshape(res, res, 3)
    assert np.abs(gl - ref).max() < 1e-5
