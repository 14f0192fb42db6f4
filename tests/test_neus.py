"""NeuS-family loading: safe checkpoint reading, NeuS (MLP) and instant-nsr-pl (hash grid) fields, the
cameras_sphere.npz reader, the adapter, and the committed fixtures (tests/data/sdf, made by
scripts/make_sdf_fixtures.py)."""

from __future__ import annotations

import json
import math
import os
import random
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch

from neuras_distill.components.tcnn import HashGridConfig, HashGridEncoding, TcnnMLP, mlp_param_count
from neuras_distill.errors import BadInputError
from neuras_distill.fields.base import check_field
from neuras_distill.fields.checkpoint import check_finite, load_torch_checkpoint
from neuras_distill_adapters.neus import NeuSAdapter
from neuras_distill_adapters.neus.cameras import cameras_from_neus_npz, decompose_projection
from neuras_distill_adapters.neus.hashgrid_field import HashGridNeuSField
from neuras_distill_adapters.neus.loader import load_neus_checkpoint
from neuras_distill_adapters.neus.mlp_field import NeuSField, infer_neus_architecture

DATA = Path(__file__).parent / "data" / "sdf"


@pytest.fixture(autouse=True)
def _one_thread(one_torch_thread):
    yield


# ---------------------------------------------------------------------------------------------- builders
def _wn_layer(out: int, inp: int, gen: torch.Generator) -> dict:
    v = torch.randn(out, inp, generator=gen) / math.sqrt(inp)
    g = v.norm(dim=1, keepdim=True) * (0.8 + 0.4 * torch.rand(out, 1, generator=gen))
    return {"weight_g": g, "weight_v": v, "bias": 0.2 * torch.randn(out, generator=gen)}


def _net(dims: list[int], skip=(), seed: int = 0, style: str = "legacy") -> dict:
    gen = torch.Generator().manual_seed(seed)
    sd = {}
    for k in range(len(dims) - 1):
        out = dims[k + 1] - (dims[0] if (k + 1) in skip else 0)
        layer = _wn_layer(out, dims[k], gen)
        if style == "legacy":
            names = {"weight_g": "weight_g", "weight_v": "weight_v", "bias": "bias"}
        elif style == "param":
            names = {"weight_g": "parametrizations.weight.original0",
                     "weight_v": "parametrizations.weight.original1", "bias": "bias"}
        else:  # plain
            layer = {"weight": layer["weight_g"] * layer["weight_v"] / layer["weight_v"].norm(dim=1, keepdim=True),
                     "bias": layer["bias"]}
            names = {"weight": "weight", "bias": "bias"}
        for n, t in layer.items():
            sd[f"lin{k}.{names[n]}"] = t
    return sd


def neus_ckpt(multires=6, d_hidden=48, n_layers=4, skip=(2,), d_feature=16, multires_view=4, color_hidden=32,
              color_layers=2, variance=0.3, style="legacy", seed=0) -> dict:
    d0 = 3 + 6 * multires
    sdf = _net([d0] + [d_hidden] * n_layers + [1 + d_feature], skip, seed, style)
    col = _net([9 + 6 * multires_view + d_feature] + [color_hidden] * color_layers + [3], (), seed + 1, style)
    return {"nerf": {}, "sdf_network_fine": sdf, "variance_network_fine": {"variance": torch.tensor(variance)},
            "color_network_fine": col, "optimizer": {}, "iter_step": 1000}


def _pe64(x: torch.Tensor, m: int) -> torch.Tensor:
    feats = [x]
    for k in range(m):
        feats += [torch.sin(x * 2.0**k), torch.cos(x * 2.0**k)]
    return torch.cat(feats, -1)


def _w64(sd: dict, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    g, v = sd[f"lin{k}.weight_g"].double(), sd[f"lin{k}.weight_v"].double()
    return g * v / torch.sqrt((v * v).sum(1, keepdim=True)), sd[f"lin{k}.bias"].double()


def reference_neus(ckpt: dict, p: torch.Tensor, d: torch.Tensor, multires: int, skip, multires_view: int):
    """Direct float64 NeuS evaluation (network frame): (sdf (N,), rgb (N, 3)), normal by autograd."""
    sdf_sd, col_sd = ckpt["sdf_network_fine"], ckpt["color_network_fine"]
    n_sdf = len({k.split(".")[0] for k in sdf_sd})
    n_col = len({k.split(".")[0] for k in col_sd})
    p = p.double().requires_grad_(True)
    inp = _pe64(p, multires)
    h = inp
    for k in range(n_sdf):
        if k in skip:
            h = torch.cat([h, inp], -1) / math.sqrt(2)
        w, b = _w64(sdf_sd, k)
        h = h @ w.T + b
        if k < n_sdf - 1:
            h = torch.logaddexp(100 * h, torch.zeros_like(h)) / 100
    sdf = h[:, 0]
    (n,) = torch.autograd.grad(sdf.sum(), p)
    c = torch.cat([p.detach(), _pe64(d.double(), multires_view), n, h[:, 1:].detach()], -1)
    for k in range(n_col):
        w, b = _w64(col_sd, k)
        c = c @ w.T + b
        if k < n_col - 1:
            c = c.clamp(min=0)
    return sdf.detach(), torch.sigmoid(c).detach()


def _unit(n: int, seed: int) -> torch.Tensor:
    return torch.nn.functional.normalize(torch.randn(n, 3, generator=torch.Generator().manual_seed(seed)), dim=-1)


def _points(n: int, seed: int, scale: float = 0.8) -> torch.Tensor:
    return (torch.rand(n, 3, generator=torch.Generator().manual_seed(seed)) * 2 - 1) * scale


# ---------------------------------------------------------------------------------------------- NeuS MLP
@pytest.mark.parametrize("style", ["legacy", "param", "plain"])
def test_neus_field_matches_direct_evaluation(tmp_path, style):
    ckpt = neus_ckpt(style=style)
    torch.save(ckpt, tmp_path / "ckpt_001000.pth")
    field = load_neus_checkpoint(tmp_path / "ckpt_001000.pth", bound="none")
    ref_ckpt = neus_ckpt(style="legacy")
    p, d = _points(200, 1), _unit(200, 2)
    sdf_ref, rgb_ref = reference_neus(ref_ckpt, p, d, 6, {2}, 4)
    with torch.no_grad():  # radiance must enable grad itself for the normal
        sdf, rgb = field.geometry(p), field.radiance(p, d)
    assert sdf.dtype == torch.float32 and rgb.shape == (200, 3)
    torch.testing.assert_close(sdf.double(), sdf_ref, atol=2e-5, rtol=1e-4)
    torch.testing.assert_close(rgb.double(), rgb_ref, atol=2e-5, rtol=1e-4)
    assert field.kind == "sdf" and field.inv_s == pytest.approx(math.exp(3.0), rel=1e-6)
    torch.testing.assert_close(field.aabb, torch.tensor([[-1.0, -1, -1], [1, 1, 1]]))
    check_field(field)


@pytest.mark.parametrize("arch", [
    dict(multires=6, d_hidden=48, n_layers=4, skip=(2,), d_feature=16, multires_view=4, color_hidden=32,
         color_layers=2),
    dict(multires=0, d_hidden=24, n_layers=3, skip=(), d_feature=0, multires_view=0, color_hidden=16,
         color_layers=1),
    dict(multires=10, d_hidden=80, n_layers=8, skip=(2, 6), d_feature=47, multires_view=2, color_hidden=24,
         color_layers=4),
    dict(multires=6, d_hidden=256, n_layers=8, skip=(4,), d_feature=256, multires_view=4, color_hidden=256,
         color_layers=4),  # NeuS's shipped confs (wmask/womask)
])
def test_neus_architecture_inference(arch):
    ckpt = neus_ckpt(**arch)
    got = infer_neus_architecture(ckpt["sdf_network_fine"], ckpt["color_network_fine"])
    assert got == {"multires": arch["multires"], "d_in": 3, "d_hidden": arch["d_hidden"],
                   "n_layers": arch["n_layers"], "skip_in": list(arch["skip"]), "d_feature": arch["d_feature"],
                   "multires_view": arch["multires_view"], "color_d_hidden": arch["color_hidden"],
                   "color_n_layers": arch["color_layers"]}


def test_neus_inv_s_from_variance_and_clipping():
    assert NeuSField(neus_ckpt(variance=0.3)).inv_s == pytest.approx(math.exp(3.0), rel=1e-6)
    assert NeuSField(neus_ckpt(variance=2.0)).inv_s == pytest.approx(1e6)       # exp(20) clipped to 1e6
    assert NeuSField(neus_ckpt(variance=-3.0)).inv_s == pytest.approx(1e-6)     # exp(-30) clipped to 1e-6
    scale_mat = np.diag([2.5, 2.5, 2.5, 1.0])
    assert NeuSField(neus_ckpt(variance=0.5), scale_mat=scale_mat).inv_s == pytest.approx(math.exp(5.0) / 2.5)


def _rotation(seed: int) -> np.ndarray:
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


@pytest.mark.parametrize("rotate", [False, True])
def test_neus_frame_mapping_with_scale_mat(rotate):
    ckpt = neus_ckpt()
    s, t = 2.5, np.array([1.0, -2.0, 0.5])
    q = _rotation(3) if rotate else np.eye(3)
    scale_mat = np.eye(4)
    scale_mat[:3, :3] = s * q
    scale_mat[:3, 3] = t
    local = NeuSField(ckpt, bound="none")
    world = NeuSField(ckpt, scale_mat=scale_mat, bound="none")
    p, d_local = _points(100, 4), _unit(100, 5)
    qt = torch.tensor(q, dtype=torch.float32)
    x = p @ qt.T * s + torch.tensor(t, dtype=torch.float32)  # p_world = s Q p + t
    d_world = d_local @ qt.T
    with torch.no_grad():
        torch.testing.assert_close(world.geometry(x), s * local.geometry(p), atol=2e-5, rtol=1e-4)
        torch.testing.assert_close(world.radiance(x, d_world), local.radiance(p, d_local), atol=2e-5, rtol=1e-4)
    assert world.inv_s == pytest.approx(local.inv_s / s)
    corners = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)]) @ (s * q).T + t
    np.testing.assert_allclose(world.aabb.numpy(), np.stack([corners.min(0), corners.max(0)]), atol=1e-5)


def test_neus_sphere_bound():
    field = NeuSField(neus_ckpt())
    free = NeuSField(neus_ckpt(), bound="none")
    x = torch.tensor([[0.1, 0.2, 0.3], [1.5, 0.0, 0.0], [1.0, 1.0, 1.0]])
    with torch.no_grad():
        got, raw = field.geometry(x), free.geometry(x)
    torch.testing.assert_close(got, torch.maximum(raw, x.norm(dim=-1) - 1.0))
    assert float(got[1]) >= 0.5 - 1e-6


def test_neus_autograd_normal_matches_finite_differences():
    field = NeuSField(neus_ckpt(), scale_mat=np.diag([1.7, 1.7, 1.7, 1.0]), bound="none").to(dtype=torch.float64)
    x = _points(50, 6).double()
    f, g = field.sdf_and_gradient(x)
    h = 1e-6
    fd = torch.stack([(field.geometry(x + h * e) - field.geometry(x - h * e)) / (2 * h)
                      for e in torch.eye(3, dtype=torch.float64)], dim=-1)
    torch.testing.assert_close(g, fd, atol=1e-6, rtol=1e-5)  # world-unit SDF over world x = network gradient
    torch.testing.assert_close(f * 1.7, field.geometry(x), atol=1e-12, rtol=1e-12)


# ---------------------------------------------------------------------------------------------- instant-nsr-pl
SMALL_GRID = dict(otype="HashGrid", n_levels=4, n_features_per_level=2, log2_hashmap_size=10, base_resolution=4,
                  per_level_scale=2.0, include_xyz=True)


def _small_config(radius: float = 1.2, **grid) -> dict:
    return {"model": {"radius": radius, "geometry": {"feature_dim": 7, "xyz_encoding_config": {**SMALL_GRID, **grid},
                                                     "mlp_network_config": {"n_neurons": 16, "n_hidden_layers": 2}},
                      "texture": {"mlp_network_config": {"otype": "FullyFusedMLP", "n_neurons": 16,
                                                         "n_hidden_layers": 1}}},
            "dataset": {"img_wh": [64, 48]}}


def nsr_parts(seed: int = 0, radius: float = 1.2):
    """(checkpoint dict, reference modules) of a small instant-nsr-pl model."""
    gen = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    grid = HashGridEncoding(HashGridConfig(4, 2, 10, 4, 2.0))
    with torch.no_grad():
        grid.params.uniform_(-0.5, 0.5)
    layers = [_wn_layer(16, 3 + 8, gen), _wn_layer(16, 16, gen), _wn_layer(7, 16, gen)]
    tex = TcnnMLP(7 + 16 + 3, 16, 1, 3, pad_value=1.0)
    sd = {"model.geometry.encoding.encoding.params": grid.flat_params().clone(),
          "model.texture.encoding.encoding.params": torch.zeros(0),
          "model.texture.network.params": tex.flat_params().clone(),
          "model.variance.variance": torch.tensor(0.45),
          "model.scene_aabb": torch.tensor([-radius] * 3 + [radius] * 3)}
    for i, layer in enumerate(layers):
        for n, t in layer.items():
            sd[f"model.geometry.network.layers.{2 * i}.{n}"] = t
    ckpt = {"epoch": 3, "global_step": 2000, "pytorch-lightning_version": "1.9.5", "state_dict": sd}
    return ckpt, (grid, layers, tex)


def reference_nsr(parts, p: torch.Tensor, d: torch.Tensor, radius: float):
    grid, layers, tex = parts
    from neuras_distill.components.tcnn import sh_encode_deg4

    p = p.clone().requires_grad_(True)
    x = (p + radius) / (2 * radius)
    h = torch.cat([2 * x - 1, grid(x)], -1)
    for i, layer in enumerate(layers):
        g, v, b = layer["weight_g"], layer["weight_v"], layer["bias"]
        h = h @ (g * v / v.norm(dim=1, keepdim=True)).T + b
        if i < len(layers) - 1:
            h = torch.nn.functional.softplus(h, beta=100)
    (n,) = torch.autograd.grad(h[:, 0].sum(), p)
    n = torch.nn.functional.normalize(n, dim=-1)
    rgb = torch.sigmoid(tex(torch.cat([h, sh_encode_deg4(d), n], -1)))
    return h[:, 0].detach(), rgb.detach()


def test_hash_grid_neus_round_trip(tmp_path):
    ckpt, parts = nsr_parts()
    torch.save(ckpt, tmp_path / "epoch=3-step=2000.ckpt")
    cfg = tmp_path / "parsed.yaml"
    cfg.write_text(json.dumps(_small_config()))
    field = load_neus_checkpoint(tmp_path / "epoch=3-step=2000.ckpt", config=cfg)
    assert isinstance(field, HashGridNeuSField) and field.radius == pytest.approx(1.2)
    p, d = _points(300, 7, 1.1), _unit(300, 8)
    sdf_ref, rgb_ref = reference_nsr(parts, p, d, 1.2)
    with torch.no_grad():
        torch.testing.assert_close(field.geometry(p), sdf_ref, atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(field.radiance(p, d), rgb_ref, atol=1e-5, rtol=1e-5)
    assert field.inv_s == pytest.approx(math.exp(4.5), rel=1e-6)
    torch.testing.assert_close(field.aabb, torch.tensor([[-1.2] * 3, [1.2] * 3]))
    outside = torch.tensor([[2.0, 0.0, 0.0]])
    inside = torch.tensor([[1.2, 0.0, 0.0]])
    assert float(field.geometry(outside)) == pytest.approx(float(field.geometry(inside)) + 0.8, abs=1e-5)
    check_field(field)
    assert NeuSAdapter().sniff(tmp_path / "epoch=3-step=2000.ckpt")


def test_hash_grid_neus_vanilla_texture_and_scale_mat():
    """A VanillaMLP colour net (texture.network.layers.*) and a DTU-style scale matrix."""
    ckpt, (grid, layers, _) = nsr_parts(radius=1.0)
    sd = {k: v for k, v in ckpt["state_dict"].items() if not k.startswith("model.texture.network")}
    gen = torch.Generator().manual_seed(5)
    tex_layers = [_wn_layer(16, 26, gen), _wn_layer(3, 16, gen)]
    for i, layer in enumerate(tex_layers):
        for n, t in layer.items():
            sd[f"model.texture.network.layers.{2 * i}.{n}"] = t
    cfg = _small_config(radius=1.0)
    cfg["model"]["texture"]["mlp_network_config"] = {"otype": "VanillaMLP", "n_neurons": 16, "n_hidden_layers": 1}
    scale_mat = np.diag([2.0, 2.0, 2.0, 1.0])
    scale_mat[:3, 3] = [0.5, 0.0, -1.0]
    field = HashGridNeuSField(sd, cfg, scale_mat=scale_mat)
    p, d = _points(100, 11, 0.9), _unit(100, 12)
    x = p * 2.0 + torch.tensor([0.5, 0.0, -1.0])
    with torch.no_grad():
        sdf, rgb = field.geometry(x), field.radiance(x, d)
    ref = HashGridNeuSField(sd, cfg)
    with torch.no_grad():
        torch.testing.assert_close(sdf, 2.0 * ref.geometry(p), atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(rgb, ref.radiance(p, d), atol=1e-6, rtol=1e-6)
    # the colour net by hand: [feature, SH(d), n] -> Linear, ReLU, Linear -> sigmoid
    from neuras_distill.components.tcnn import sh_encode_deg4

    pr = p.clone().requires_grad_(True)
    out = ref.sdf_network(pr)
    (g,) = torch.autograd.grad(out[:, 0].sum(), pr)
    h = torch.cat([out.detach(), sh_encode_deg4(d), torch.nn.functional.normalize(g, dim=-1)], -1)
    for i, layer in enumerate(tex_layers):
        h = h @ (layer["weight_g"] * layer["weight_v"] / layer["weight_v"].norm(dim=1, keepdim=True)).T + layer["bias"]
        h = torch.relu(h) if i == 0 else torch.sigmoid(h)
    torch.testing.assert_close(rgb, h.detach(), atol=1e-5, rtol=1e-5)
    assert field.inv_s == pytest.approx(math.exp(4.5) / 2.0, rel=1e-6)


def test_hash_grid_neus_param_count_mismatch(tmp_path):
    ckpt, _ = nsr_parts()
    with pytest.raises(BadInputError) as info:  # defaults (L16, T2^19) do not match a 4-level grid
        HashGridNeuSField(ckpt["state_dict"])
    msg = str(info.value)
    n = HashGridConfig(4, 2, 10, 4, 2.0).n_params()
    assert "hash grid" in msg and f"has {n:,} parameters" in msg and "pass config=" in msg
    with pytest.raises(BadInputError) as info:
        HashGridNeuSField(ckpt["state_dict"], _small_config(n_levels=5))
    assert "n_levels=4, n_features_per_level=2, log2_hashmap_size=10" in str(info.value)  # the fix is suggested
    bad_tex = dict(ckpt["state_dict"])
    bad_tex["model.texture.network.params"] = torch.zeros(mlp_param_count(26, 16, 1, 3) + 16)
    with pytest.raises(BadInputError, match="texture.network.params.*parameters"):
        HashGridNeuSField(bad_tex, _small_config())
    with pytest.raises(BadInputError, match="scene_aabb has radius 1.2.*model.radius = 1.5"):
        HashGridNeuSField(ckpt["state_dict"], _small_config(radius=1.5))


# ---------------------------------------------------------------------------------------------- cameras
def _png(path: Path, w: int, h: int) -> None:
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + struct.pack(">I", len(ihdr)) + chunk
                     + struct.pack(">I", zlib.crc32(chunk)))


def test_cameras_sphere_round_trip(tmp_path):
    w, h = 40, 30
    ks, rs, ts, arrays = [], [], [], {}
    scale_mat = np.diag([1.3, 1.3, 1.3, 1.0])
    scale_mat[:3, 3] = [0.2, -0.1, 0.4]
    for i in range(3):
        k = np.array([[50.0 + i, 0.0, 19.3], [0.0, 48.0 - i, 14.1], [0.0, 0.0, 1.0]])
        r = _rotation(10 + i)
        t = np.array([0.1 * i, -0.2, 3.0 + i])
        p = np.eye(4)
        p[:3, :4] = (-2.5 if i == 1 else 0.7) * (k @ np.hstack([r, t[:, None]]))  # P is only defined up to scale
        arrays[f"world_mat_{i}"] = p
        arrays[f"scale_mat_{i}"] = scale_mat
        ks.append(k), rs.append(r), ts.append(t)
    np.savez(tmp_path / "cameras_sphere.npz", **arrays)
    cams, sm = cameras_from_neus_npz(tmp_path / "cameras_sphere.npz", w, h)
    np.testing.assert_allclose(sm, scale_mat)
    assert (cams.width, cams.height, len(cams)) == (w, h, 3)
    for i in range(3):
        k_got, r_got, t_got = decompose_projection(arrays[f"world_mat_{i}"])
        np.testing.assert_allclose(k_got, ks[i], atol=1e-9)
        np.testing.assert_allclose(r_got, rs[i], atol=1e-9)
        np.testing.assert_allclose(t_got, ts[i], atol=1e-9)
        # NeuS's ray of pixel (u, v) (integer coordinates): R^T K^-1 [u, v, 1] from C = -R^T t
        v_px, u_px = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
        pix = np.stack([u_px, v_px, np.ones_like(u_px)], -1).reshape(-1, 3).astype(np.float64)
        dirs = pix @ np.linalg.inv(ks[i]).T @ rs[i]
        dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
        o, d = cams.rays(i)
        np.testing.assert_allclose(o.reshape(-1, 3).numpy(), np.broadcast_to(-rs[i].T @ ts[i], (w * h, 3)), atol=1e-5)
        np.testing.assert_allclose(d.reshape(-1, 3).numpy(), dirs, atol=1e-5)
    with pytest.raises(BadInputError, match=r"--image-size WxH"):
        cameras_from_neus_npz(tmp_path / "cameras_sphere.npz")
    (tmp_path / "image").mkdir()
    _png(tmp_path / "image" / "000.png", w, h)
    assert cameras_from_neus_npz(tmp_path / "cameras_sphere.npz")[0].width == w  # NeuS layout: size from PNG


def test_cameras_sphere_bad_input(tmp_path):
    (tmp_path / "rand.npz").write_bytes(random.Random(0).randbytes(300))
    with pytest.raises(BadInputError, match="not a readable NeuS cameras"):
        cameras_from_neus_npz(tmp_path / "rand.npz", 10, 10)
    np.savez(tmp_path / "none.npz", foo=np.eye(4))
    with pytest.raises(BadInputError, match="no world_mat"):
        cameras_from_neus_npz(tmp_path / "none.npz", 10, 10)
    np.savez(tmp_path / "obj.npz", world_mat_0=np.array([{"a": 1}], dtype=object))
    with pytest.raises(BadInputError, match="not a readable NeuS cameras"):  # allow_pickle=False
        cameras_from_neus_npz(tmp_path / "obj.npz", 10, 10)
    np.savez(tmp_path / "shape.npz", world_mat_0=np.eye(3))
    with pytest.raises(BadInputError, match=r"world_mat_0 has shape \(3, 3\)"):
        cameras_from_neus_npz(tmp_path / "shape.npz", 10, 10)
    np.savez(tmp_path / "aniso.npz", world_mat_0=np.eye(4), scale_mat_0=np.diag([1.0, 2.0, 1.0, 1.0]))
    with pytest.raises(BadInputError, match="uniform scale"):
        cameras_from_neus_npz(tmp_path / "aniso.npz", 10, 10)
    with pytest.raises(BadInputError, match="does not exist"):
        cameras_from_neus_npz(tmp_path / "missing.npz", 10, 10)


# ---------------------------------------------------------------------------------------------- bad input
class _Evil:
    marker = ""

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_code_executing_pickle_is_refused_and_never_runs(tmp_path):
    marker = tmp_path / "PWNED"
    evil = _Evil()
    evil.marker = str(marker)
    ckpt = neus_ckpt()
    ckpt["iter_step"] = evil
    torch.save(ckpt, tmp_path / "evil.pth")
    for call in (lambda: load_torch_checkpoint(tmp_path / "evil.pth"),
                 lambda: load_neus_checkpoint(tmp_path / "evil.pth"),
                 lambda: NeuSAdapter().load(tmp_path / "evil.pth")):
        with pytest.raises(BadInputError, match=r"needs more than tensors and plain containers \(found \w+\.system"):
            call()
    assert not marker.exists()
    assert NeuSAdapter().sniff(tmp_path / "evil.pth")  # sniffing reads bytes only, never unpickles
    assert not marker.exists()


def _bad_files(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    torch.save(neus_ckpt(), tmp_path / "good.pth")
    data = (tmp_path / "good.pth").read_bytes()
    (tmp_path / "trunc.pth").write_bytes(data[: len(data) // 2])
    (tmp_path / "rand.pth").write_bytes(random.Random(0).randbytes(2000))
    (tmp_path / "empty.pth").write_bytes(b"")
    (tmp_path / "dir.pth").mkdir()
    torch.save({"a": 1}, tmp_path / "legacy.pth", _use_new_zipfile_serialization=False)
    torch.save([torch.zeros(2)], tmp_path / "list.pth")
    return {"truncated": (tmp_path / "trunc.pth", "truncated or damaged"),
            "random": (tmp_path / "rand.pth", "not a PyTorch checkpoint"),
            "empty": (tmp_path / "empty.pth", "is empty (0 bytes)"),
            "missing": (tmp_path / "nope.pth", "does not exist"),
            "directory": (tmp_path / "dir.pth", "is a directory"),
            "legacy": (tmp_path / "legacy.pth", "legacy serialization"),
            "list": (tmp_path / "list.pth", "not a dict")}


def test_bad_files_raise_one_clear_error(tmp_path):
    for name, (path, words) in _bad_files(tmp_path).items():
        with pytest.raises(BadInputError) as info:
            load_neus_checkpoint(path)
        assert words in str(info.value), (name, str(info.value))
        assert "\n" not in str(info.value)
        assert not NeuSAdapter().sniff(path), name


def _save_and_load(tmp_path, ckpt, **kw):
    torch.save(ckpt, tmp_path / "c.pth")
    return load_neus_checkpoint(tmp_path / "c.pth", **kw)


def test_bad_checkpoint_contents(tmp_path):
    ckpt = neus_ckpt()
    del ckpt["color_network_fine"]
    with pytest.raises(BadInputError, match="missing 'color_network_fine'"):
        _save_and_load(tmp_path, ckpt)

    with pytest.raises(BadInputError, match=r"not a NeuS checkpoint.*top-level keys: a, b"):
        _save_and_load(tmp_path, {"a": torch.zeros(1), "b": 2})

    ckpt = neus_ckpt()
    ckpt["sdf_network_fine"]["lin3.weight_v"] = torch.zeros(48, 47) + 1.0
    with pytest.raises(BadInputError) as info:
        _save_and_load(tmp_path, ckpt)
    assert "'lin3' weight has shape (48, 47), expected input width 48" in str(info.value)

    ckpt = neus_ckpt()
    ckpt["sdf_network_fine"]["lin1.weight_g"] = torch.ones(5, 1)
    with pytest.raises(BadInputError, match=r"'lin1.weight_g' has shape \(5, 1\), expected \(9, 1\)"):
        _save_and_load(tmp_path, ckpt)

    ckpt = neus_ckpt()
    ckpt["sdf_network_fine"]["lin0.bias"] = torch.zeros(3)
    with pytest.raises(BadInputError, match=r"'lin0.bias' has shape \(3,\), expected \(48,\)"):
        _save_and_load(tmp_path, ckpt)

    ckpt = neus_ckpt()
    ckpt["color_network_fine"]["lin0.weight_v"] = torch.ones(32, 50)
    ckpt["color_network_fine"]["lin0.weight_g"] = torch.ones(32, 1)
    with pytest.raises(BadInputError, match="input width 50 does not match NeuS's 'idr' colour input"):
        _save_and_load(tmp_path, ckpt)

    ckpt = neus_ckpt()
    ckpt["sdf_network_fine"]["lin2.weight_v"][3, 4] = float("nan")
    with pytest.raises(BadInputError, match=r"'sdf_network_fine.lin2.weight_v' contain NaN or Inf \(1 of"):
        _save_and_load(tmp_path, ckpt)

    ckpt = neus_ckpt()
    ckpt["variance_network_fine"] = {"variance": torch.tensor(float("inf"))}
    with pytest.raises(BadInputError, match="variance_network_fine.variance' contain NaN or Inf"):
        _save_and_load(tmp_path, ckpt)

    with pytest.raises(BadInputError, match="config= is for instant-nsr-pl"):
        _save_and_load(tmp_path, neus_ckpt(), config={"model": {}})
    with pytest.raises(BadInputError, match="density must be 'neus' or 'laplace'"):
        _save_and_load(tmp_path, neus_ckpt(), density="volsdf")
    with pytest.raises(BadInputError, match="unknown option"):
        NeuSAdapter().load(tmp_path / "c.pth", colour="red")


def test_check_finite_names_nested_key():
    check_finite({"a": {"b": torch.ones(3)}, "n": 3})
    with pytest.raises(BadInputError, match=r"'a.b.1' contain NaN or Inf"):
        check_finite({"a": {"b": [torch.ones(2), torch.tensor([0.0, float("-inf")])]}})


def test_laplace_density_option(tmp_path):
    field = _save_and_load(tmp_path, neus_ckpt(variance=0.5), density="laplace")
    assert field.kind == "density" and field.beta == pytest.approx(math.exp(-5.0))
    assert getattr(field, "inv_s", None) is None and field.background_color.tolist() == [1.0, 1.0, 1.0]
    field = _save_and_load(tmp_path, neus_ckpt(), density="laplace", beta=0.01, background_color=(0, 0, 0))
    x = _points(20, 9)
    sdf_field = _save_and_load(tmp_path, neus_ckpt())
    with torch.no_grad():
        from neuras_distill.fields.wrappers import laplace_density

        torch.testing.assert_close(field.geometry(x), laplace_density(sdf_field.geometry(x), 0.01))
    check_field(field)


# ---------------------------------------------------------------------------------------------- fixtures
def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    return 10 * math.log10(1.0 / max(float(np.mean((a.astype(np.float64) - b) ** 2)), 1e-12))


@pytest.fixture(scope="module")
def bunny_views():
    from neuras_distill.render.volume import VolumeRenderer
    from neuras_distill.scenes.synthetic import make_scene

    scene = make_scene("bunny", kind="sdf")
    cams = scene.default_cameras(48, 40, 40)
    render = VolumeRenderer(scene, num_steps=96, occupancy_resolution=32)
    return cams, {i: render.render(cams, i)["rgb"] for i in (5, 29)}


def _check_fixture_render(field, bunny_views) -> None:
    from neuras_distill.render.volume import VolumeRenderer

    cams, truth = bunny_views
    render = VolumeRenderer(field, num_steps=96, occupancy_resolution=32)
    for i, want in truth.items():
        out = render.render(cams, i)
        assert 0.2 < float(out["opacity"].mean()) < 0.8  # not blank, not full
        assert _psnr(out["rgb"], want) > 20.0, i


def test_neus_fixture_loads_and_resembles_the_scene(bunny_views):
    path = DATA / "neus_bunny.pth"
    assert NeuSAdapter().sniff(path)
    field = NeuSAdapter().load(path, cameras=DATA / "cameras_sphere.npz", width=400, height=400)
    assert isinstance(field, NeuSField) and field.arch["d_hidden"] == 64 and field.arch["skip_in"] == [3]
    assert field.frame.scale == pytest.approx(1.1) and len(field.cameras) == 48
    cams, _ = bunny_views
    np.testing.assert_allclose(field.cameras.resized(40).c2w.numpy(), cams.c2w.numpy(), atol=1e-4)
    check_field(field)
    _check_fixture_render(field, bunny_views)


def test_nsr_fixture_loads_and_resembles_the_scene(bunny_views):
    path = DATA / "nsr_bunny.ckpt"
    assert NeuSAdapter().sniff(path)
    field = NeuSAdapter().load(path, config=DATA / "nsr_bunny.parsed.yaml", cameras=DATA / "transforms_bunny.json")
    assert isinstance(field, HashGridNeuSField) and field.grid_config.n_levels == 12
    assert field.radius == pytest.approx(1.1) and len(field.cameras) == 48
    check_field(field)
    _check_fixture_render(field, bunny_views)


def test_registry_picks_the_neus_adapter_by_content(tmp_path):
    from neuras_distill.registry import available_adapters, load_field

    assert "neus" in available_adapters(), "the neus entry point is not installed (pip install -e .)"
    renamed = tmp_path / "model.bin"  # the extension plays no part
    renamed.write_bytes((DATA / "neus_bunny.pth").read_bytes())
    field = load_field(renamed, cameras=DATA / "cameras_sphere.npz", width=400, height=400)
    assert isinstance(field, NeuSField)
