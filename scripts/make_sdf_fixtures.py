"""Train the small NeuS-family checkpoints under tests/data/sdf/ on the embedded bunny scene.

Writes, in the exact original file formats:

* ``neus_bunny.pth``: a Totoro97/NeuS checkpoint ``{"nerf", "sdf_network_fine", "variance_network_fine",
  "color_network_fine", "iter_step"}`` (legacy weight-norm keys ``lin{k}.weight_g/weight_v/bias``): SDF MLP
  d_hidden 64, 6 hidden layers, skip at lin3, multires 6, 65 outputs; colour MLP 64 wide, 4 hidden layers,
  multires_view 4. Trained in NeuS's unit-sphere frame given by ``cameras_sphere.npz``'s scale matrix.
* ``cameras_sphere.npz``: 48 views of the scene's default orbit as ``world_mat_i`` / ``scale_mat_i``
  (images 400x400, not stored: pass width/height when loading).
* ``nsr_bunny.ckpt``: an instant-nsr-pl Lightning checkpoint (``state_dict`` with ``model.`` keys: TCNN hash grid
  L12 F2 T2^13 N_min 16 (finest 256), weight-norm VanillaMLP 23 -> 64 -> 13 with Softplus(100), TCNN
  FullyFusedMLP colour net 32 -> 64 -> 64 -> 3, ``variance.variance``, ``scene_aabb``); trained in the world
  frame with radius 1.1 (nerfacc's occupancy-grid buffers are left out to keep it small).
* ``nsr_bunny.parsed.yaml``: that run's config (JSON syntax, which is valid YAML) and ``transforms_bunny.json``
  (the same 48 cameras as a NeRF transforms file, for the world-frame checkpoint).

Fitting is supervised on the synthetic scene: L1 regression of the SDF near the surface and in the volume plus
an eikonal term, and colour regression at near-surface points with random front-facing view directions
(targets from the scene's ``radiance``, view-dependent highlight included). The networks are then loaded with
the real loaders (:mod:`neuras_distill_adapters.neus`) and rendered against the scene; the PSNR is printed.

Usage: ``python scripts/make_sdf_fixtures.py [--which neus|nsr|all] [--iters N] [--out tests/data/sdf]``.
One CPU thread; each fixture takes a few minutes.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from torch.nn.utils.parametrizations import weight_norm

from neuras_distill.components.tcnn import HashGridConfig, HashGridEncoding, TcnnMLP, sh_encode_deg4
from neuras_distill.scenes.synthetic import make_scene
from neuras_distill_adapters.neus.cameras import write_neus_npz
from neuras_distill_adapters.neus.layers import positional_encoding

OUT = Path(__file__).resolve().parent.parent / "tests" / "data" / "sdf"
IMAGE_SIZE = 400
N_VIEWS = 48
NEUS_SCALE = 1.1          # scale_mat[0, 0]: the unit sphere is 1.1 world units in radius
NEUS_INV_S = 660.0        # network-frame sharpness (world: 600)
NSR_RADIUS = 1.1
NSR_INV_S = 600.0
NSR_GRID = dict(n_levels=12, n_features_per_level=2, log2_hashmap_size=13, base_resolution=16,
                per_level_scale=float(np.float32(16.0 ** (1.0 / 11.0))))


# ---------------------------------------------------------------------------------------------- data
class SceneSampler:
    """Training samples from the bunny scene in a network frame ``p = (x - centre) / scale``."""

    def __init__(self, scene, centre: torch.Tensor, scale: float, box: float, seed: int = 0):
        self.scene, self.centre, self.scale, self.box = scene, centre, float(scale), float(box)
        self.gen = torch.Generator().manual_seed(seed)
        lo, hi = scene.aabb[0], scene.aabb[1]
        pool = lo + torch.rand(3_000_000, 3, generator=self.gen) * (hi - lo)
        f = scene.exact_sdf(pool)
        self.near = pool[f.abs() < 0.04]
        self.skin = pool[f.abs() < 0.012]
        print(f"  samples: {self.near.shape[0]} near the surface, {self.skin.shape[0]} on its skin")

    def to_local(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.centre) / self.scale

    def _pick(self, pool: torch.Tensor, n: int) -> torch.Tensor:
        return pool[torch.randint(0, pool.shape[0], (n,), generator=self.gen)]

    def geometry_batch(self, n_near: int, n_volume: int, sphere: bool) -> tuple[torch.Tensor, torch.Tensor]:
        """(local points (N, 3), local signed distances (N,))."""
        near = self._pick(self.near, n_near)
        near = near + 0.004 * torch.randn(near.shape, generator=self.gen)
        vol = (torch.rand(n_volume, 3, generator=self.gen) * 2.0 - 1.0) * self.box
        if sphere:
            vol = vol[vol.norm(dim=-1) < self.box]
        x = torch.cat([near, vol * self.scale + self.centre])
        return self.to_local(x), self.scene.exact_sdf(x) / self.scale

    def colour_batch(self, n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(local points, unit travel directions (front-facing), target colours)."""
        x = self._pick(self.skin, n)
        normal = self.scene.normal(x)
        d = F.normalize(torch.randn(n, 3, generator=self.gen), dim=-1)
        d = torch.where(((d * normal).sum(-1, keepdim=True) > 0), -d, d)  # travel into the surface
        d = F.normalize(d - 0.3 * normal, dim=-1)
        return self.to_local(x), d, self.scene.radiance(x, d)


def cosine_lr(opt, it: int, total: int, warmup: int = 200) -> None:
    f = min(1.0, (it + 1) / warmup) * (0.05 + 0.95 * 0.5 * (1.0 + math.cos(math.pi * it / total)))
    for g in opt.param_groups:
        g["lr"] = g["base_lr"] * f


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return 10.0 * math.log10(1.0 / max(mse, 1e-12))


def evaluate(field, scene, views=(0, 12, 24, 36), size: int = 96, steps: int = 256) -> float:
    from neuras_distill.render.volume import VolumeRenderer

    cams = scene.default_cameras(N_VIEWS, size, size)
    r_field = VolumeRenderer(field, num_steps=steps, occupancy_resolution=48)
    r_scene = VolumeRenderer(scene, num_steps=steps, occupancy_resolution=48)
    values = [psnr(r_field.render(cams, i)["rgb"], r_scene.render(cams, i)["rgb"]) for i in views]
    print(f"  PSNR vs the scene at {size}x{size}, views {list(views)}: "
          f"{', '.join(f'{v:.2f}' for v in values)} dB (mean {np.mean(values):.2f})")
    return float(np.mean(values))


# ---------------------------------------------------------------------------------------------- NeuS (MLP)
class NeuSSDFNet(nn.Module):
    """NeuS's SDF network with geometric initialisation (IDR / SAL): a sphere of radius 0.5 at start."""

    def __init__(self, multires=6, d_hidden=64, n_layers=6, skip_in=(3,), d_out=65, bias=0.5):
        super().__init__()
        self.multires, self.skip_in = multires, set(skip_in)
        d0 = 3 + 6 * multires
        dims = [d0] + [d_hidden] * n_layers + [d_out]
        self.lins = nn.ModuleList()
        for k in range(len(dims) - 1):
            out = dims[k + 1] - (d0 if k + 1 in self.skip_in else 0)
            lin = nn.Linear(dims[k], out)
            with torch.no_grad():
                if k == len(dims) - 2:
                    lin.weight.normal_(math.sqrt(math.pi) / math.sqrt(dims[k]), 1e-4)
                    lin.bias.fill_(-bias)
                else:
                    lin.bias.zero_()
                    lin.weight.normal_(0.0, math.sqrt(2.0) / math.sqrt(out))
                    if k == 0:
                        lin.weight[:, 3:] = 0.0
                    elif k in self.skip_in:
                        lin.weight[:, -(d0 - 3):] = 0.0
            self.lins.append(weight_norm(lin))

    def forward(self, p: torch.Tensor) -> torch.Tensor:
        inputs = positional_encoding(p, self.multires)
        h = inputs
        for k, lin in enumerate(self.lins):
            if k in self.skip_in:
                h = torch.cat([h, inputs], -1) / math.sqrt(2.0)
            h = lin(h)
            if k < len(self.lins) - 1:
                h = F.softplus(h, beta=100.0)
        return h


class NeuSColourNet(nn.Module):
    def __init__(self, d_feature=64, multires_view=4, d_hidden=64, n_layers=4):
        super().__init__()
        self.multires_view = multires_view
        dims = [9 + 6 * multires_view + d_feature] + [d_hidden] * n_layers + [3]
        self.lins = nn.ModuleList(weight_norm(nn.Linear(dims[k], dims[k + 1])) for k in range(len(dims) - 1))

    def forward(self, p, normals, dirs, features):
        h = torch.cat([p, positional_encoding(dirs, self.multires_view), normals, features], -1)
        for k, lin in enumerate(self.lins):
            h = lin(h)
            if k < len(self.lins) - 1:
                h = torch.relu(h)
        return torch.sigmoid(h)


def _gradient(f: torch.Tensor, p: torch.Tensor, create_graph: bool) -> torch.Tensor:
    return torch.autograd.grad(f.sum(), p, create_graph=create_graph, retain_graph=True)[0]


def _step(opt, it: int, iters: int, start: float, loss_sdf, loss_eik, loss_rgb) -> None:
    """One optimiser step on 10 L1(sdf) + 0.1 eikonal + L2(rgb), with a progress line every 500 steps."""
    loss = 10.0 * loss_sdf + 0.1 * loss_eik + loss_rgb
    opt.zero_grad(set_to_none=True)
    loss.backward()
    opt.step()
    if it % 500 == 0 or it == iters - 1:
        print(f"  it {it:5d}  sdf L1 {loss_sdf.item():.5f}  eik {loss_eik.item():.4f}  "
              f"rgb psnr {-10 * math.log10(max(loss_rgb.item(), 1e-10)):.2f}  ({time.perf_counter() - start:.0f} s)")


def _legacy_wn(module: nn.ModuleList) -> dict:
    """State dict of weight-normed layers in the legacy ``nn.utils.weight_norm`` key names."""
    sd = {}
    for k, lin in enumerate(module):
        sd[f"lin{k}.bias"] = lin.bias.detach().clone()
        sd[f"lin{k}.weight_g"] = lin.parametrizations.weight.original0.detach().clone()
        sd[f"lin{k}.weight_v"] = lin.parametrizations.weight.original1.detach().clone()
    return sd


def make_neus(scene, out: Path, iters: int) -> dict:
    from neuras_distill_adapters.neus.loader import load_neus_checkpoint

    print("NeuS (MLP) fixture")
    lo, hi = scene.aabb
    centre = 0.5 * (lo + hi)
    scale_mat = np.eye(4)
    scale_mat[:3, :3] *= NEUS_SCALE
    scale_mat[:3, 3] = centre.numpy()
    cams = scene.default_cameras(N_VIEWS, IMAGE_SIZE, IMAGE_SIZE)
    write_neus_npz(out / "cameras_sphere.npz", cams, scale_mat)

    torch.manual_seed(0)
    sampler = SceneSampler(scene, centre, NEUS_SCALE, 1.0)
    sdf_net, col_net = NeuSSDFNet(), NeuSColourNet()
    opt = torch.optim.Adam([{"params": sdf_net.parameters(), "base_lr": 1e-3},
                            {"params": col_net.parameters(), "base_lr": 1e-3}])
    start = time.perf_counter()
    for it in range(iters):
        cosine_lr(opt, it, iters)
        p, target = sampler.geometry_batch(3072, 1024, sphere=True)
        p.requires_grad_(True)
        out_g = sdf_net(p)
        grad = _gradient(out_g[:, 0], p, create_graph=True)
        loss_sdf = (out_g[:, 0] - target).abs().mean()
        loss_eik = ((grad.norm(dim=-1) - 1.0) ** 2).mean()
        pc, dc, rgb = sampler.colour_batch(2048)
        pc.requires_grad_(True)
        out_c = sdf_net(pc)
        grad_c = _gradient(out_c[:, 0], pc, create_graph=False)
        pred = col_net(pc.detach(), grad_c.detach(), dc, out_c[:, 1:])
        loss_rgb = ((pred - rgb) ** 2).mean()
        _step(opt, it, iters, start, loss_sdf, loss_eik, loss_rgb)
    ckpt = {"nerf": {}, "sdf_network_fine": _legacy_wn(sdf_net.lins),
            "variance_network_fine": {"variance": torch.tensor(math.log(NEUS_INV_S) / 10.0)},
            "color_network_fine": _legacy_wn(col_net.lins), "iter_step": iters}
    torch.save(ckpt, out / "neus_bunny.pth")
    field = load_neus_checkpoint(out / "neus_bunny.pth", cameras=out / "cameras_sphere.npz", width=IMAGE_SIZE,
                                 height=IMAGE_SIZE)
    print(f"  loaded: {field}")
    return {"file": "neus_bunny.pth", "bytes": (out / "neus_bunny.pth").stat().st_size,
            "seconds": time.perf_counter() - start, "psnr": evaluate(field, scene)}


# ---------------------------------------------------------------------------------------------- instant-nsr-pl
class VanillaMLP(nn.Module):
    """instant-nsr-pl's VanillaMLP with sphere init (radius 0.5), weight norm, Softplus(100)."""

    def __init__(self, dim_in: int, dim_out: int, n_neurons: int = 64, n_hidden_layers: int = 1):
        super().__init__()
        dims = [dim_in] + [n_neurons] * n_hidden_layers + [dim_out]
        layers = []
        for k in range(len(dims) - 1):
            lin = nn.Linear(dims[k], dims[k + 1])
            with torch.no_grad():
                if k == len(dims) - 2:
                    lin.bias.fill_(-0.5)
                    lin.weight.normal_(math.sqrt(math.pi) / math.sqrt(dims[k]), 1e-4)
                else:
                    lin.bias.zero_()
                    lin.weight.normal_(0.0, math.sqrt(2.0) / math.sqrt(dims[k + 1]))
                    if k == 0:
                        lin.weight[:, 3:] = 0.0
            layers.append(weight_norm(lin))
            if k < len(dims) - 2:
                layers.append(nn.Softplus(beta=100.0))
        self.layers = nn.Sequential(*layers)

    def forward(self, x):
        return self.layers(x)


def make_nsr(scene, out: Path, iters: int) -> dict:
    from neuras_distill_adapters.neus.loader import load_neus_checkpoint

    print("instant-nsr-pl (hash grid) fixture")
    torch.manual_seed(1)
    r = NSR_RADIUS
    sampler = SceneSampler(scene, torch.zeros(3), 1.0, r, seed=1)
    grid = HashGridEncoding(HashGridConfig(**NSR_GRID))
    feat_dim = 13
    geo = VanillaMLP(3 + grid.n_output_dims, feat_dim)
    tex = TcnnMLP(feat_dim + 16 + 3, 64, 2, 3, pad_value=1.0)
    opt = torch.optim.Adam([{"params": grid.parameters(), "base_lr": 1e-2},
                            {"params": geo.parameters(), "base_lr": 1e-2},
                            {"params": tex.parameters(), "base_lr": 1e-2}], betas=(0.9, 0.99), eps=1e-15)

    def sdf_out(p):
        x = ((p + r) / (2 * r)).clamp(0.0, 1.0)
        return geo(torch.cat([x * 2 - 1, grid(x)], -1))

    eps = 2e-3
    offs = torch.cat([torch.eye(3), -torch.eye(3)]) * eps
    start = time.perf_counter()
    for it in range(iters):
        cosine_lr(opt, it, iters, warmup=100)
        p, target = sampler.geometry_batch(4096, 1024, sphere=False)
        out_g = sdf_out(p)
        loss_sdf = (out_g[:, 0] - target).abs().mean()
        pe = p[:1536]
        fd = sdf_out((pe[:, None] + offs).reshape(-1, 3))[:, 0].view(-1, 6)
        grad = (fd[:, :3] - fd[:, 3:]) / (2 * eps)
        loss_eik = ((grad.norm(dim=-1) - 1.0) ** 2).mean()
        pc, dc, rgb = sampler.colour_batch(2048)
        pc.requires_grad_(True)
        out_c = sdf_out(pc)
        n = F.normalize(_gradient(out_c[:, 0], pc, create_graph=False), dim=-1).detach()
        pred = torch.sigmoid(tex(torch.cat([out_c, sh_encode_deg4(dc), n], -1)))
        loss_rgb = ((pred - rgb) ** 2).mean()
        _step(opt, it, iters, start, loss_sdf, loss_eik, loss_rgb)

    sd = {"model.geometry.encoding.encoding.params": grid.flat_params().clone()}
    for k, mod in enumerate(geo.layers):
        if isinstance(mod, nn.Linear):
            sd[f"model.geometry.network.layers.{k}.bias"] = mod.bias.detach().clone()
            sd[f"model.geometry.network.layers.{k}.weight_g"] = mod.parametrizations.weight.original0.detach().clone()
            sd[f"model.geometry.network.layers.{k}.weight_v"] = mod.parametrizations.weight.original1.detach().clone()
    sd["model.texture.encoding.encoding.params"] = torch.zeros(0)
    sd["model.texture.network.params"] = tex.flat_params().clone()
    sd["model.variance.variance"] = torch.tensor(math.log(NSR_INV_S) / 10.0)
    sd["model.scene_aabb"] = torch.tensor([-r, -r, -r, r, r, r])
    ckpt = {"epoch": 0, "global_step": iters, "pytorch-lightning_version": "1.9.5", "state_dict": sd}
    torch.save(ckpt, out / "nsr_bunny.ckpt")

    config = {
        "name": "neus-bunny", "tag": "fixture", "seed": 42,
        "dataset": {"name": "blender", "scene": "bunny", "img_wh": [IMAGE_SIZE, IMAGE_SIZE]},
        "model": {
            "name": "neus", "radius": r, "num_samples_per_ray": 1024, "grid_prune": True,
            "background_color": "white", "variance": {"init_val": 0.3, "modulate": False},
            "geometry": {
                "name": "volume-sdf", "radius": r, "feature_dim": feat_dim, "grad_type": "analytic",
                "isosurface": {"method": "mc", "resolution": 512, "chunk": 2097152, "threshold": 0.0},
                "xyz_encoding_config": {"otype": "HashGrid", **NSR_GRID, "include_xyz": True},
                "mlp_network_config": {"otype": "VanillaMLP", "activation": "ReLU", "output_activation": "none",
                                       "n_neurons": 64, "n_hidden_layers": 1, "sphere_init": True,
                                       "sphere_init_radius": 0.5, "weight_norm": True},
            },
            "texture": {
                "name": "volume-radiance", "input_feature_dim": feat_dim + 3,
                "dir_encoding_config": {"otype": "SphericalHarmonics", "degree": 4},
                "mlp_network_config": {"otype": "FullyFusedMLP", "activation": "ReLU", "output_activation": "none",
                                       "n_neurons": 64, "n_hidden_layers": 2},
                "color_activation": "sigmoid",
            },
        },
        "trainer": {"max_steps": iters},
    }
    (out / "nsr_bunny.parsed.yaml").write_text(json.dumps(config, indent=2) + "\n")
    cams = scene.default_cameras(N_VIEWS, IMAGE_SIZE, IMAGE_SIZE)
    (out / "transforms_bunny.json").write_text(json.dumps(cams.to_json()) + "\n")
    field = load_neus_checkpoint(out / "nsr_bunny.ckpt", config=out / "nsr_bunny.parsed.yaml",
                                 cameras=out / "transforms_bunny.json")
    print(f"  loaded: {field}")
    return {"file": "nsr_bunny.ckpt", "bytes": (out / "nsr_bunny.ckpt").stat().st_size,
            "seconds": time.perf_counter() - start, "psnr": evaluate(field, scene)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--which", choices=("neus", "nsr", "all"), default="all")
    parser.add_argument("--iters", type=int, default=None, help="training iterations (default 4000 / 1500)")
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    args.out.mkdir(parents=True, exist_ok=True)
    scene = make_scene("bunny", kind="sdf")
    results = []
    if args.which in ("neus", "all"):
        results.append(make_neus(scene, args.out, args.iters or 4000))
    if args.which in ("nsr", "all"):
        results.append(make_nsr(scene, args.out, args.iters or 1500))
    for r in results:
        print(f"{r['file']}: {r['bytes']:,} bytes, {r['seconds']:.0f} s, PSNR {r['psnr']:.2f} dB")


if __name__ == "__main__":
    main()
