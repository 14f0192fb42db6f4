"""The exports' texture limit (export/texture_limit.py): codebooks wrapped again to fit, shaders rewritten to match,
every other texture checked, and a texture that cannot fit refused with one line naming it.

The browser side (the default demo's codebook played in Chromium, whose SwiftShader holds 8192 texels a side)
is in test_web.py; the glTF side in test_gltf.py.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from neuras_distill.bake.bundle import bake, codes_per_row, wrap_codebook
from neuras_distill.bake.glsl import generate_fragment_shader, rewrap_codebook_fetches
from neuras_distill.export.texture_limit import check_side, fit_bundle_textures, fit_codebook, smallest_limit
from neuras_distill.errors import BadInputError
from test_bake import make_model, quad_mesh

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _codes(k: int, c4: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(k, c4, 4)).astype(np.float32)


@pytest.mark.parametrize("k, c4, per_row, limit", [(34403, 2, 3, 4096), (34403, 2, 3, 2048), (12000, 2, 1, 4096),
                                                   (4096, 2, 1, 4096), (37, 3, 2, 16)])
def test_a_codebook_is_wrapped_again_to_fit_and_keeps_every_code(k, c4, per_row, limit):
    codes = _codes(k, c4)
    texture = wrap_codebook(codes, per_row)
    fitted, new = fit_codebook("u_codebook", texture, k, per_row, limit)
    assert max(fitted.shape[:2]) <= limit and fitted.shape[1] == new * c4
    if max(texture.shape[:2]) <= limit:
        assert fitted is texture and new == per_row                     # what fits is left as the bake wrote it
    else:
        assert new == codes_per_row(k, limit) > per_row
    # code j is where the shader looks for it: row j // n, columns (j % n) * C4 ..
    j = np.arange(k)
    for c in range(c4):
        assert np.array_equal(fitted[j // new, (j % new) * c4 + c], codes[:, c])


def test_the_default_demo_codebook_fits_4096_with_9_codes_per_row():
    fitted, new = fit_codebook("u_codebook", wrap_codebook(_codes(34403, 2), 3), 34403, 3, 4096)
    assert new == 9 and fitted.shape == (3823, 18, 4)


@pytest.mark.parametrize("kw", [{}, {"use_facing": True, "dim": 5}, {"mesh_layers": 2}, {"dim": 12}])
def test_the_rewritten_shader_is_the_one_the_bake_generates_for_that_wrap(kw):
    model = make_model(**kw)
    c4 = (model.feature_dim + 3) // 4
    for old, new in ((1, 9), (3, 9), (3, 1), (2, 2)):
        got = rewrap_codebook_fetches(generate_fragment_shader(model, codes_per_row=old), "u_codebook", c4, old, new)
        assert got == generate_fragment_shader(model, codes_per_row=new)
    with pytest.raises(ValueError, match="not once"):                 # a shader read with another wrap
        rewrap_codebook_fetches(generate_fragment_shader(model, codes_per_row=2), "u_codebook", c4, 3, 9)


def test_a_bundle_too_tall_for_the_limit_gets_its_codebook_and_shader_rewrapped():
    model = make_model(h=6, w=8, k=32)
    b = bake(model, quad_mesh(), (0, 0, 0))
    k = b.manifest["num_codes"]
    assert b.textures["u_codebook"].shape[:2] == (k, 2) and k > 8
    textures, frag, sky = fit_bundle_textures(b, 8)
    n = codes_per_row(k, 8)
    assert textures["u_codebook"].shape == (-(-k // n), 2 * n, 4) and textures["u_index"] is b.textures["u_index"]
    assert frag == generate_fragment_shader(model, codes_per_row=n) != b.fragment_shader and sky is None
    same = fit_bundle_textures(b, 64)                                   # it fits: nothing changes
    assert same[0]["u_codebook"] is b.textures["u_codebook"] and same[1] == b.fragment_shader


def test_what_cannot_fit_is_named_with_its_size_the_limit_and_the_fix():
    with pytest.raises(BadInputError) as e:
        check_side("u_index", 8192, 8192, 4096)
    assert str(e.value) == ("texture u_index is 8192x8192, above the export's limit of 4096 texels per side: bake it "
                            "with texture.page_size 4096 or less, or export with --max-texture-size 8192 for a "
                            "target that holds it")
    check_side("u_index", 4096, 3 * 4096, 4096, pages=3)               # three pages of 4096: fits
    with pytest.raises(BadInputError, match=r"u_index is 8192x8192 per page \(2 pages\).*texture.page_size"):
        check_side("u_index", 8192, 2 * 8192, 4096, pages=2)
    with pytest.raises(BadInputError, match=r"u_sky_index is 192x1024.*skybox.resolution"):
        check_side("u_sky_index", 192, 1024, 512)
    # 34403 codes of 2 texels: 64 x 32 = 2048 fit 64 x 64 texels; 263 x 131 = 34453 is the smallest that holds them
    with pytest.raises(BadInputError, match=r"u_codebook is 6x11468 \(34403 codes of 2 texels; at most 2048 fit "
                                            r"64x64\).*texture.num_codes.*--max-texture-size 263 "):
        fit_codebook("u_codebook", wrap_codebook(_codes(34403, 2), 3), 34403, 3, 64)
    assert smallest_limit(34403, 2) == 263 and 262 * 131 < 34403 <= 263 * 131
    fit_codebook("u_codebook", wrap_codebook(_codes(34403, 2), 3), 34403, 3, 263)


def test_a_shader_that_does_not_read_its_codebook_as_baked_is_refused():
    b = bake(make_model(h=6, w=8, k=32), quad_mesh(), (0, 0, 0))
    edited = replace(b, fragment_shader=b.fragment_shader.replace("texelFetch(u_codebook, ivec2(0, k00), 0)",
                                                                  "texelFetch(u_codebook, ivec2(0, k00 + 0), 0)"))
    with pytest.raises(BadInputError, match="u_codebook needs wrapping.*bake the bundle again"):
        fit_bundle_textures(edited, 8)
