"""The pure-PyTorch tiny-cuda-nn pieces (neuras_distill.components.tcnn) against slow, literal references.

The hash-grid reference below is a plain-Python loop over points, levels and corners that follows
docs/formats.md §1.5 word by word (python ints, ``& 0xFFFFFFFF``, float32 via numpy / libm); the MLP
reference builds the padded matrices by hand; SH is checked term by term and for orthonormality.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import itertools
import math

import numpy as np
import pytest
import torch

from neuras_distill.components.tcnn import (
    HashGridConfig,
    HashGridEncoding,
    TcnnMLP,
    mlp_param_count,
    next_multiple,
    ngp_per_level_scale,
    sh_encode_deg4,
)
from neuras_distill.errors import BadInputError

f32 = np.float32


def _libm():
    """glibc's float32 log2f/exp2f (what TCNN's host code calls), or None where there is no libm."""
    name = ctypes.util.find_library("m")
    if name is None:
        return None
    try:
        lib = ctypes.CDLL(name)
        for fn in ("log2f", "exp2f"):
            getattr(lib, fn).restype = ctypes.c_float
            getattr(lib, fn).argtypes = [ctypes.c_float]
        return lib
    except (OSError, AttributeError):
        return None


LIBM = _libm()


def _log2f(v):
    return f32(LIBM.log2f(f32(v))) if LIBM is not None else np.log2(f32(v))


def _exp2f(v):
    return f32(LIBM.exp2f(f32(v))) if LIBM is not None else np.exp2(f32(v))


def tcnn_grid_index_is_dense(r: int, t: int) -> bool:
    """TCNN common_device.h grid_index, literally: uint32 stride loop, then "if (T < stride) hash"."""
    stride = 1
    dim = 0
    while dim < 3 and stride <= t:
        stride = (stride * r) & 0xFFFFFFFF
        dim += 1
    return not t < stride


def ref_levels(L, n_min, b, log2_t, tcnn_rule=False):
    """[(s_l, R_l, T_l, dense)] literally as §1.5 items 2, 3, 6 say (or with TCNN's uint32 stride rule)."""
    out = []
    log2b = _log2f(b)
    for lv in range(L):
        s = f32(f32(_exp2f(f32(f32(lv) * log2b)) * f32(n_min)) - f32(1.0))
        r = math.ceil(float(s)) + 1
        t = min(next_multiple(min(r**3, 2**31 - 1), 8), 2**log2_t)
        out.append((s, r, t, tcnn_grid_index_is_dense(r, t) if tcnn_rule else r**3 <= t))
    return out


def ref_encode(cfg: HashGridConfig, params: np.ndarray, pts: np.ndarray,
               stats: dict | None = None, tcnn_rule: bool = False) -> np.ndarray:
    """Slow reference hash encoding: pts (N, 3) float32 -> (N, L*F) float64."""
    L, F = cfg.n_levels, cfg.n_features_per_level
    levels = ref_levels(L, cfg.base_resolution, cfg.per_level_scale, cfg.log2_hashmap_size, tcnn_rule)
    out = np.zeros((len(pts), L * F))
    primes = (1, 2654435761, 805459861)
    off = 0
    for lv, (s, r, t, dense) in enumerate(levels):
        for i, p in enumerate(pts):
            g, w = [], []
            for d in range(3):
                pos = f32(float(s) * float(f32(p[d])) + 0.5)  # fmaf: exact product, one rounding
                gd = math.floor(float(pos))
                wd = float(pos) - gd
                if cfg.interpolation == "Smoothstep":
                    wd = wd * wd * (3.0 - 2.0 * wd)
                g.append(gd)
                w.append(wd)
            if stats is not None and w == [0.0, 0.0, 0.0]:
                stats["on_vertex"] = stats.get("on_vertex", 0) + 1
            for c in itertools.product((0, 1), repeat=3):
                weight = 1.0
                for d in range(3):
                    weight *= w[d] if c[d] else 1.0 - w[d]
                v = [(g[d] + c[d]) & 0xFFFFFFFF for d in range(3)]
                if dense:
                    raw = (v[0] + v[1] * r + v[2] * r * r) & 0xFFFFFFFF
                    if stats is not None and raw >= t:
                        stats["wrapped"] = stats.get("wrapped", 0) + 1
                    idx = raw % t
                else:
                    idx = ((v[0] * primes[0]) ^ (v[1] * primes[1]) ^ (v[2] * primes[2])) & 0xFFFFFFFF
                    idx %= t
                for f in range(F):
                    out[i, lv * F + f] += weight * float(params[(off + idx) * F + f])
        if stats is not None:
            stats.setdefault("dense", []).append(dense)
        off += t
    assert off * F == len(params)
    return out


def hard_points(n_random: int, scales) -> np.ndarray:
    """Random points plus the hard ones: corners of the cube, near 0 and 1, and exact grid vertices."""
    rng = np.random.default_rng(0)
    one_minus = float(np.nextafter(f32(1.0), f32(0.0)))
    special = [[0, 0, 0], [1, 1, 1], [1, 0, 1], [one_minus] * 3, [1e-7, one_minus, 0.5], [0.5, 0.5, 0.5],
               [1e-30, 0.999, 1.0]]
    for s in scales[:4]:  # vertices: s * x + 0.5 integral (as exactly as float32 allows)
        k = np.arange(1, int(s) + 1, max(1, int(s) // 3))
        vx = ((k - 0.5) / float(s)).astype(np.float32)
        special += [[a, b, c] for a, b, c in zip(vx, vx[::-1], np.roll(vx, 1))]
    pts = np.concatenate([np.asarray(special, dtype=np.float32), rng.random((n_random, 3), dtype=np.float32),
                          (1.0 - rng.random((4, 3)) * 1e-4).astype(np.float32),
                          (rng.random((4, 3)) * 1e-4).astype(np.float32)])
    return np.clip(pts, 0.0, 1.0).astype(np.float32)


def _check_against_reference(cfg: HashGridConfig, n_random: int = 40, seed: int = 0) -> dict:
    gen = torch.Generator().manual_seed(seed)
    params = torch.rand(cfg.n_params(), generator=gen) * 2 - 1
    enc = HashGridEncoding(cfg, params)
    pts = hard_points(n_random, cfg.level_scales())
    stats: dict = {}
    want = ref_encode(cfg, params.numpy(), pts, stats)
    with torch.no_grad():
        got = enc(torch.from_numpy(pts)).double().numpy()
    assert got.shape == (len(pts), cfg.n_output_dims())
    np.testing.assert_allclose(got, want, atol=1e-5, rtol=0)
    return stats


@pytest.mark.usefixtures("one_torch_thread")
class TestHashGridAgainstReference:
    def test_l16_f2_dense_and_hashed_levels(self):
        cfg = HashGridConfig(n_levels=16, n_features_per_level=2, log2_hashmap_size=11, base_resolution=4,
                             per_level_scale=1.5)
        stats = _check_against_reference(cfg, n_random=10)
        assert any(stats["dense"]) and not all(stats["dense"])

    def test_l8_f4(self):
        cfg = HashGridConfig(n_levels=8, n_features_per_level=4, log2_hashmap_size=12, base_resolution=4,
                             per_level_scale=2.0)
        stats = _check_against_reference(cfg, n_random=30)
        assert any(stats["dense"]) and not all(stats["dense"])
        assert stats["on_vertex"] > 0  # exactly on grid vertices (weight 1 on one corner)

    def test_smoothstep(self):
        cfg = HashGridConfig(n_levels=6, n_features_per_level=2, log2_hashmap_size=10, base_resolution=3,
                             per_level_scale=1.7, interpolation="Smoothstep")
        stats = _check_against_reference(cfg, n_random=30)
        assert any(stats["dense"]) and not all(stats["dense"])

    def test_half_offset_wraps_dense_index(self):
        # b = 2, N = 4: s = 3, 7, 15 are integers, so points near 1 reach vertex R and the dense index wraps.
        cfg = HashGridConfig(n_levels=3, n_features_per_level=1, log2_hashmap_size=12, base_resolution=4,
                             per_level_scale=2.0)
        assert cfg.level_resolutions() == [4, 8, 16] and not any(cfg.level_is_hashed())
        stats = _check_against_reference(cfg, n_random=30)
        assert stats.get("wrapped", 0) > 0

    @pytest.mark.parametrize("aabb_scale", [1, 4, 16, 128])
    def test_ngp_per_level_scale(self, aabb_scale):
        b = ngp_per_level_scale(aabb_scale, 4, 6)
        cfg = HashGridConfig(n_levels=6, n_features_per_level=2, log2_hashmap_size=10, base_resolution=4,
                             per_level_scale=b)
        # The finest level has about 2048 * aabb_scale cells (here with N_min = 4).
        assert abs(cfg.level_scales()[-1] + 1 - 2048 * aabb_scale) <= 2e-3 * 2048 * aabb_scale
        _check_against_reference(cfg, n_random=8)

    def test_level_math_matches_literal_reference(self):
        cases = [(16, 16, ngp_per_level_scale(1, 16, 16), 19), (8, 16, ngp_per_level_scale(4, 16, 8), 19),
                 (16, 16, ngp_per_level_scale(16, 16, 16), 21), (8, 32, 1.26, 15), (12, 2, 1.9, 12)]
        for L, n_min, b, t in cases:
            cfg = HashGridConfig(L, 2, t, n_min, b)
            ref = ref_levels(L, n_min, b, t)
            assert cfg.level_scales() == [float(s) for s, *_ in ref]
            assert cfg.level_resolutions() == [r for _, r, _, _ in ref]
            assert cfg.level_sizes() == [t_ for _, _, t_, _ in ref]
            assert cfg.level_is_hashed() == [not dense for *_, dense in ref]
            assert cfg.level_offsets() == list(np.cumsum([0] + cfg.level_sizes()))

    def test_points_outside_the_cube_wrap_like_tcnn(self):
        # Outside [0, 1]^3 the dense levels take the exact uint32 path (negative cells wrap mod 2^32).
        cfg = HashGridConfig(n_levels=5, n_features_per_level=2, log2_hashmap_size=10, base_resolution=4,
                             per_level_scale=1.5)
        assert cfg.level_sizes()[:3] == [64, 216, 736]  # dense tables that do not divide 2^32
        params = torch.randn(cfg.n_params(), generator=torch.Generator().manual_seed(2))
        enc = HashGridEncoding(cfg, params)
        pts = (np.random.default_rng(1).random((40, 3)) * 2.2 - 0.6).astype(np.float32)
        stats: dict = {}
        want = ref_encode(cfg, params.numpy(), pts, stats)
        assert any(stats["dense"]) and not all(stats["dense"])
        with torch.no_grad():
            got = enc(torch.from_numpy(pts)).double().numpy()
            inside = enc(torch.from_numpy(np.clip(pts, 0, 1))).double().numpy()
        np.testing.assert_allclose(got, want, atol=1e-5, rtol=0)
        want_inside = ref_encode(cfg, params.numpy(), np.clip(pts, 0, 1))
        np.testing.assert_allclose(inside, want_inside, atol=1e-5, rtol=0)
        with torch.no_grad():  # NaN / Inf never index out of the table
            bad = enc(torch.tensor([[float("nan"), 0.5, 0.5], [float("inf"), -float("inf"), 0.2]]))
        assert bad.shape == (2, 10)

    def test_chunking_does_not_change_the_result(self):
        cfg = HashGridConfig(n_levels=4, n_features_per_level=2, log2_hashmap_size=8, base_resolution=4,
                             per_level_scale=2.0)
        enc = HashGridEncoding(cfg, torch.randn(cfg.n_params()), chunk_size=64)
        x = torch.rand(1000, 3)
        with torch.no_grad():
            a = enc(x)
            enc.chunk_size = 2**16
            b = enc(x)
        assert torch.equal(a, b)
        assert enc(torch.zeros(0, 3)).shape == (0, 8)


@pytest.mark.usefixtures("one_torch_thread")
def test_tcnn_uint32_stride_quirk():
    # TCNN's uint32 stride wraps when R^3 >= 2^32 but R^2 <= T (R = 2048, T = 2^22): grid_index then takes the
    # dense index mod 2^32 (z drops out) instead of hashing. §1.5's "R^3 <= T" rule misses this; we follow
    # TCNN. Levels here: R = 1024 hashed, 2048 "dense" by the quirk, 4096 hashed.
    from neuras_distill.components.tcnn import _level_is_hashed

    assert _level_is_hashed(2048, 2**22) is False and tcnn_grid_index_is_dense(2048, 2**22)
    assert _level_is_hashed(2048, 2**21) is True
    assert _level_is_hashed(59, next_multiple(59**3, 8)) is False
    assert _level_is_hashed(60, 2**15) is True
    cfg = HashGridConfig(n_levels=3, n_features_per_level=1, log2_hashmap_size=22, base_resolution=1024,
                         per_level_scale=2.0)
    assert cfg.level_resolutions() == [1024, 2048, 4096] and cfg.level_sizes() == [2**22] * 3
    assert cfg.level_is_hashed() == [True, False, True]
    params = torch.randn(cfg.n_params(), generator=torch.Generator().manual_seed(4))
    enc = HashGridEncoding(cfg, params)
    pts = hard_points(12, [])
    with torch.no_grad():
        got = enc(torch.from_numpy(pts)).double().numpy()
    want = ref_encode(cfg, params.numpy(), pts, tcnn_rule=True)
    np.testing.assert_allclose(got, want, atol=1e-5, rtol=0)
    assert np.abs(got[:, 1] - ref_encode(cfg, params.numpy(), pts)[:, 1]).max() > 1e-3  # the rule matters


# -- sizes of §1.4 / §1.5 ------------------------------------------------------------------------------------

PARAM_TABLE = [  # L, F, aabb_scale, per_level_scale, grid params, total n_params
    (16, 2, 1, 1.381913, 12_196_240, 12_206_480),
    (16, 2, 4, 1.515717, 13_074_912, 13_085_152),
    (16, 2, 16, 1.662476, 13_623_184, 13_633_424),
    (8, 4, 1, 2.000000, 11_681_792, 11_692_032),
    (8, 4, 4, 2.438027, 12_855_296, 12_865_536),
    (8, 4, 16, 2.971989, 13_041_664, 13_051_904),
]


@pytest.mark.parametrize("L,F,aabb,b_doc,grid,total", PARAM_TABLE)
def test_param_count_table(L, F, aabb, b_doc, grid, total):
    b = ngp_per_level_scale(aabb, 16, L)
    # The doc rounds the float32 value 2.97198844 to 2.971989; equal to the 6 digits within one unit.
    assert abs(b - b_doc) <= 1.0e-6 + 1e-9
    cfg = HashGridConfig.from_json({"otype": "HashGrid", "n_levels": L, "n_features_per_level": F,
                                    "log2_hashmap_size": 19, "base_resolution": 16}, aabb_scale=aabb)
    assert cfg.per_level_scale == b
    assert cfg.n_params() == grid
    density = mlp_param_count(next_multiple(L * F, 16), 64, 1, 16)
    rgb = mlp_param_count(16 + 16, 64, 2, 16)
    assert (density, rgb) == (3_072, 7_168)
    assert density + rgb + cfg.n_params() == total


def test_dense_levels_of_the_defaults():
    c16 = HashGridConfig(16, 2, 19, 16, ngp_per_level_scale(1, 16, 16))
    hashed = c16.level_is_hashed()
    assert hashed == [False] * 5 + [True] * 11
    assert c16.level_resolutions()[:5] == [16, 23, 31, 43, 59]
    s = c16.level_scales()
    assert 2046.99 < s[15] <= 2047.0 and c16.level_resolutions()[15] == 2048  # float32: 2046.9987 -> R 2048
    c8 = HashGridConfig(8, 4, 19, 16, ngp_per_level_scale(4, 16, 8))
    assert c8.level_is_hashed() == [False] * 2 + [True] * 6
    assert c8.level_resolutions()[:2] == [16, 40]
    c8a1 = HashGridConfig(8, 4, 19, 16, ngp_per_level_scale(1, 16, 8))
    assert c8a1.level_scales()[7] == 2047.0 and c8a1.level_resolutions()[7] == 2048
    assert c16.level_offsets()[-1] * 2 == c16.n_params() and c16.n_output_dims() == 32


# -- from_json -----------------------------------------------------------------------------------------------


def test_from_json_defaults():
    cfg = HashGridConfig.from_json({"otype": "HashGrid"}, aabb_scale=4)
    assert (cfg.n_levels, cfg.n_features_per_level, cfg.log2_hashmap_size) == (16, 2, 19)
    assert cfg.base_resolution == 32  # INGP: 1 << (15 // 3) when log2_hashmap_size is absent too
    assert cfg.per_level_scale == ngp_per_level_scale(4, 32, 16)
    assert cfg.interpolation == "Linear"
    cfg = HashGridConfig.from_json({"otype": "Grid", "type": "Hash", "log2_hashmap_size": 21, "n_levels": 8,
                                    "interpolation": "smoothstep", "hash": "CoherentPrime"})
    assert cfg.base_resolution == 128 and cfg.interpolation == "Smoothstep"
    assert cfg.per_level_scale == ngp_per_level_scale(1, 128, 8)
    cfg = HashGridConfig.from_json({"otype": "HashGrid", "per_level_scale": 1.5, "base_resolution": 16.0})
    assert cfg.per_level_scale == 1.5 and cfg.base_resolution == 16 and isinstance(cfg.base_resolution, int)
    assert HashGridConfig.from_json({"otype": "HashGrid", "n_levels": 1}).per_level_scale == 1.0


@pytest.mark.parametrize("enc,words", [
    ({"otype": "Frequency"}, ["Frequency"]),
    ({"otype": "DenseGrid"}, ["DenseGrid"]),
    ({"otype": "TiledGrid"}, ["TiledGrid"]),
    ({"otype": "Grid", "type": "Dense"}, ["Dense"]),
    ({}, ["otype"]),
    ({"otype": "HashGrid", "hash": "Prime"}, ["hash", "Prime"]),
    ({"otype": "HashGrid", "interpolation": "Nearest"}, ["interpolation", "Nearest"]),
    ({"otype": "HashGrid", "n_levels": 0}, ["n_levels", "0"]),
    ({"otype": "HashGrid", "n_levels": 33}, ["n_levels", "33"]),
    ({"otype": "HashGrid", "n_features_per_level": 3}, ["n_features_per_level", "3"]),
    ({"otype": "HashGrid", "log2_hashmap_size": 31}, ["log2_hashmap_size", "31"]),
    ({"otype": "HashGrid", "log2_hashmap_size": 0}, ["log2_hashmap_size", "0"]),
    ({"otype": "HashGrid", "base_resolution": -2}, ["base_resolution", "-2"]),
    ({"otype": "HashGrid", "base_resolution": 2.5}, ["base_resolution", "2.5"]),
    ({"otype": "HashGrid", "per_level_scale": 0.5}, ["per_level_scale", "0.5"]),
    ({"otype": "HashGrid", "per_level_scale": float("inf")}, ["per_level_scale", "inf"]),
    ({"otype": "HashGrid", "per_level_scale": float("nan")}, ["per_level_scale", "nan"]),
    ({"otype": "HashGrid", "n_levels": True}, ["n_levels"]),
])
def test_from_json_rejects(enc, words):
    with pytest.raises(BadInputError) as e:
        HashGridConfig.from_json(enc)
    for w in words:
        assert w in str(e.value)


def test_from_json_validates_before_allocating(monkeypatch):
    # log2_hashmap_size 40 would be a 2^40-entry table; it must fail on the value, not in torch.empty.
    with pytest.raises(BadInputError, match="log2_hashmap_size"):
        HashGridConfig.from_json({"otype": "HashGrid", "log2_hashmap_size": 40})
    with pytest.raises(BadInputError, match="aabb_scale"):
        HashGridConfig.from_json({"otype": "HashGrid"}, aabb_scale=0)


def test_encoding_rejects_bad_params_and_inputs():
    cfg = HashGridConfig(2, 2, 6, 2, 2.0)
    with pytest.raises(BadInputError, match=str(cfg.n_params())):
        HashGridEncoding(cfg, torch.zeros(cfg.n_params() + 1))
    enc = HashGridEncoding(cfg)
    assert enc.params.dtype == torch.float32 and float(enc.flat_params().abs().max()) <= 1e-4
    with pytest.raises(BadInputError, match=r"\(N, 3\)"):
        enc(torch.zeros(4, 2))
    p = torch.randn(cfg.n_params(), dtype=torch.float64)
    enc = HashGridEncoding(cfg, p.half())
    assert enc.params.dtype == torch.float32 and torch.equal(enc.flat_params(), p.half().float())
    assert not enc.flat_params().requires_grad


# -- gradients -----------------------------------------------------------------------------------------------


@pytest.mark.usefixtures("one_torch_thread")
def test_gradcheck_params_and_x():
    cfg = HashGridConfig(n_levels=3, n_features_per_level=2, log2_hashmap_size=6, base_resolution=3,
                         per_level_scale=1.8, interpolation="Smoothstep")
    assert cfg.level_is_hashed() == [False, True, True]
    enc = HashGridEncoding(cfg, torch.randn(cfg.n_params())).double()
    gen = torch.Generator().manual_seed(1)
    x = (0.05 + 0.9 * torch.rand(6, 3, generator=gen, dtype=torch.float64)).requires_grad_(True)

    def f(params, xx):
        return torch.func.functional_call(enc, {"params": params}, (xx,))

    p = enc.params.detach().clone().requires_grad_(True)
    assert torch.autograd.gradcheck(f, (p, x), eps=1e-6, atol=1e-6, fast_mode=True)


@pytest.mark.usefixtures("one_torch_thread")
def test_fp32_gradient_reaches_the_touched_entries():
    cfg = HashGridConfig(n_levels=2, n_features_per_level=2, log2_hashmap_size=8, base_resolution=4,
                         per_level_scale=3.0)
    enc = HashGridEncoding(cfg, torch.randn(cfg.n_params()))
    x = torch.tensor([[0.3, 0.6, 0.2]])
    out = enc(x)
    out[0, 1].backward()  # level 0, feature 1
    g = enc.params.grad.view(-1, 2)
    nz = g.nonzero()
    assert (nz[:, 1] == 1).all() and 1 <= len(nz) <= 8
    assert nz[:, 0].max() < cfg.level_offsets()[1]
    assert torch.allclose(g[:, 1].sum(), torch.tensor(1.0))  # trilinear weights sum to 1


# -- MLP -----------------------------------------------------------------------------------------------------


def _manual_mlp(params, n_in, width, n_hidden, n_out, out_align=16, in_align=16, pad_value=0.0):
    in_pad = next_multiple(n_in, in_align)
    out_pad = next_multiple(n_out, out_align)
    shapes = [(width, in_pad)] + [(width, width)] * (n_hidden - 1) + [(out_pad, width)]
    mats, at = [], 0
    for o, i in shapes:
        mats.append(np.asarray(params[at:at + o * i], dtype=np.float64).reshape(o, i))  # row-major [out, in]
        at += o * i
    assert at == len(params)

    def fwd(x):
        h = np.concatenate([x, np.full((len(x), in_pad - n_in), pad_value)], axis=1)
        for k, w in enumerate(mats):
            h = h @ w.T
            if k < len(mats) - 1:
                h = np.maximum(h, 0)
        return h[:, :n_out]

    return fwd


@pytest.mark.parametrize("n_in,width,n_hidden,n_out,out_align,pad", [
    (32, 64, 1, 16, 16, 0.0),   # INGP density
    (32, 64, 2, 3, 16, 0.0),    # INGP rgb (only 3 of the 16 rows read)
    (32, 64, 2, 3, 8, 0.0),     # old CutlassMLP alignment
    (3, 16, 3, 1, 16, 1.0),     # Identity input padded with ones
    (19, 32, 1, 17, 16, 0.0),
])
def test_mlp_layout(n_in, width, n_hidden, n_out, out_align, pad):
    n = mlp_param_count(n_in, width, n_hidden, n_out, output_alignment=out_align)
    in_pad, out_pad = next_multiple(n_in, 16), next_multiple(n_out, out_align)
    assert n == width * in_pad + (n_hidden - 1) * width * width + out_pad * width
    gen = torch.Generator().manual_seed(3)
    params = torch.randn(n, generator=gen) * 0.3
    mlp = TcnnMLP(n_in, width, n_hidden, n_out, params, output_alignment=out_align, pad_value=pad)
    assert mlp.n_params == n and torch.equal(mlp.flat_params(), params)
    x = torch.randn(50, n_in, generator=gen)
    ref = _manual_mlp(params.numpy(), n_in, width, n_hidden, n_out, out_align, 16, pad)(x.double().numpy())
    with torch.no_grad():
        got = mlp(x)
    assert got.shape == (50, n_out)
    np.testing.assert_allclose(got.double().numpy(), ref, rtol=1e-4, atol=1e-4)
    if pad == 0.0 and in_pad > n_in:  # columns of the padding never matter with zero padding
        p2 = params.clone()
        p2[:width * in_pad].view(width, in_pad)[:, n_in:] = 1e3
        with torch.no_grad():
            assert torch.equal(TcnnMLP(n_in, width, n_hidden, n_out, p2, output_alignment=out_align)(x), got)
    if out_pad > n_out:  # padded output rows are ignored
        p3 = params.clone()
        p3[n - out_pad * width:].view(out_pad, width)[n_out:] = 1e3
        with torch.no_grad():
            got3 = TcnnMLP(n_in, width, n_hidden, n_out, p3, output_alignment=out_align, pad_value=pad)(x)
        assert torch.equal(got3, got)


def test_mlp_alignment_8_sizes_and_errors():
    assert mlp_param_count(32, 64, 2, 3, output_alignment=8) == 7_168 - 8 * 64
    assert mlp_param_count(32, 64, 2, 16, output_alignment=8) == 7_168
    with pytest.raises(BadInputError, match="7,168"):
        TcnnMLP(32, 64, 2, 16, torch.zeros(7_000))
    mlp = TcnnMLP(32, 64, 2, 16)
    assert mlp.n_params == 7_168 and mlp.params.dtype == torch.float32
    with pytest.raises(BadInputError, match=r"\(N, 32\)"):
        mlp(torch.zeros(3, 31))
    with pytest.raises(BadInputError, match="width"):
        TcnnMLP(32, 0, 2, 16)
    # gradient reaches the weights
    mlp(torch.randn(4, 32)).sum().backward()
    assert mlp.params.grad is not None and mlp.params.grad.abs().sum() > 0


# -- spherical harmonics -------------------------------------------------------------------------------------


def test_sh_components():
    d = torch.nn.functional.normalize(torch.randn(64, 3, generator=torch.Generator().manual_seed(5),
                                                  dtype=torch.float64), dim=-1)
    x, y, z = d.unbind(-1)
    want = [
        torch.full_like(x, 0.28209479177), -0.48860251190 * y, 0.48860251190 * z, -0.48860251190 * x,
        1.09254843059 * x * y, -1.09254843059 * y * z, 0.94617469576 * z * z - 0.31539156525,
        -1.09254843059 * x * z, 0.54627421530 * (x * x - y * y), 0.59004358993 * y * (-3 * x * x + y * y),
        2.89061144264 * x * y * z, 0.45704579946 * y * (1 - 5 * z * z), 0.37317633259 * z * (5 * z * z - 3),
        0.45704579946 * x * (1 - 5 * z * z), 1.44530572132 * z * (x * x - y * y),
        0.59004358993 * x * (-x * x + 3 * y * y),
    ]
    got = sh_encode_deg4(d)
    assert got.shape == (64, 16) and got.dtype == torch.float64
    for k in range(16):
        torch.testing.assert_close(got[:, k], want[k], atol=1e-10, rtol=1e-10, msg=f"SH component {k}")
    assert sh_encode_deg4(d.float()).dtype == torch.float32
    with pytest.raises(BadInputError):
        sh_encode_deg4(torch.zeros(3))


def test_sh_orthonormal_on_the_sphere():
    # Gauss-Legendre in z times uniform in phi: exact for these polynomials (degree <= 8).
    zs, wz = np.polynomial.legendre.leggauss(12)
    phis = np.arange(24) * (2 * np.pi / 24)
    z = np.repeat(zs, len(phis))
    w = np.repeat(wz, len(phis)) * (2 * np.pi / len(phis))
    phi = np.tile(phis, len(zs))
    r = np.sqrt(1 - z * z)
    d = torch.from_numpy(np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1))
    y = sh_encode_deg4(d)
    gram = (y * torch.from_numpy(w)[:, None]).T @ y
    torch.testing.assert_close(gram, torch.eye(16, dtype=torch.float64), atol=1e-9, rtol=0)
