"""Field throughput on a device: the pure-PyTorch Instant-NGP pieces (neuras_distill.components.tcnn) and the
NeuS SDF MLP, forward only, beside the bound that memory bandwidth puts on the hash-table reads.

For the two Instant-NGP default grids (L16 F2 T19 and L8 F4 T19, N_min 16, aabb_scale 1) it times
(a) HashGridEncoding alone and (b) the whole default NeRF network: grid -> density MLP (64 wide, 1 hidden,
16 out) -> rgb MLP on [16 density outputs, SH degree 4 of the direction] (64 wide, 2 hidden). Random points
in the unit cube, random unit directions; the median over repeats of points per second. Also (c) the NeuS
default SDF network (positional encoding of 6 frequencies, 8 layers of 256, skip at 4, softplus beta 100, 257
outputs) and (d) the NeuS fixture as loaded (tests/data/sdf/neus_bunny.pth, 4x64). The device's memory
bandwidth is measured with a 256 MiB copy; the hash grid's bound is that bandwidth divided by the bytes one
point reads from the tables (levels x 8 corners x features x 4 bytes): the rate at which the table reads alone
would saturate memory if none hit a cache (coarse levels do, so a grid can exceed it). Prints one line per
measurement and a final JSON line with the machine info (or writes it with --out).

Usage: python benchmarks/hashgrid_throughput.py [--device auto|cpu|cuda] [--points 262144] [--repeats 5]
       [--chunk N] [--threads N] [--out result.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import torch

from neuras_distill.components.tcnn import (
    HashGridConfig,
    HashGridEncoding,
    TcnnMLP,
    next_multiple,
    ngp_per_level_scale,
    sh_encode_deg4,
)
from neuras_distill.device import cpu_name

CONFIGS = {"L16 F2 T19": (16, 2), "L8 F4 T19": (8, 4)}


def _time(fn, x, d, device: torch.device, repeats: int) -> float:
    """Median seconds of fn(x, d) over ``repeats`` runs after one warm-up."""
    fn(x[:1024], d[:1024])
    times = []
    for _ in range(repeats):
        if device.type == "cuda":
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        fn(x, d)
        if device.type == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def memory_bandwidth(device: torch.device, mib: int = 256, repeats: int = 5) -> float:
    """Bytes per second a large device-to-device copy moves (read + write), median of ``repeats``."""
    src = torch.ones(mib * 2**18, device=device)
    dst = torch.empty_like(src)
    times = []
    for _ in range(repeats + 1):
        if device.type == "cuda":
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        dst.copy_(src)
        if device.type == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    return 2 * src.numel() * src.element_size() / statistics.median(times[1:])


class NeuSDefaultSDF(torch.nn.Module):
    """The NeuS paper's SDF network (d_in 3, multires 6, 8 x 256, skip at 4, softplus beta 100, 1 + 256 out)."""

    def __init__(self):
        super().__init__()
        self.freqs = 2.0 ** torch.arange(6)
        dims = [39] + [256] * 8 + [257]
        self.layers = torch.nn.ModuleList()
        for i in range(len(dims) - 1):
            out = dims[i + 1] - (39 if i + 1 == 4 else 0)
            self.layers.append(torch.nn.Linear(dims[i], out))
        self.act = torch.nn.Softplus(beta=100)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        f = self.freqs.to(x.device)
        xf = (x[:, :, None] * f).reshape(x.shape[0], -1)
        pe = torch.cat([x, torch.sin(xf), torch.cos(xf)], dim=-1)
        h = pe
        for i, layer in enumerate(self.layers):
            if i == 4:
                h = torch.cat([h, pe], dim=-1) / 2 ** 0.5
            h = layer(h)
            if i < len(self.layers) - 1:
                h = self.act(h)
        return h


def run_neus(device: torch.device, points: int, repeats: int) -> list[dict]:
    """(c) and (d): the NeuS default network and the fixture field."""
    from adapters.neus.adapter import NeuSAdapter
    from neuras_distill.device_field import on_device

    gen = torch.Generator().manual_seed(1)
    x = (torch.rand(points, 3, generator=gen) * 2 - 1).to(device)
    data = Path(__file__).resolve().parent.parent / "tests" / "data" / "sdf"
    fixture = on_device(NeuSAdapter().load(data / "neus_bunny.pth", cameras=data / "cameras_sphere.npz",
                                           width=400, height=400), device)
    rows = []
    for name, fn in (("NeuS default 8x256", NeuSDefaultSDF().to(device)),
                     ("NeuS fixture 4x64", fixture.geometry)):
        with torch.inference_mode():
            sec = _time(lambda xx, dd: fn(xx), x, x, device, repeats)
        rows.append({"config": name, "what": "sdf network", "device": str(device), "points": points,
                     "median_s": sec, "points_per_s": points / sec})
        print(f"{device.type:5s} {name:20s} {'sdf network':12s} {points / sec / 1e6:8.3f} M points/s "
              f"({sec * 1e3:.1f} ms for {points} points)", flush=True)
    return rows


def run(device: torch.device, points: int, repeats: int, chunk: int | None) -> list[dict]:
    results = []
    bandwidth = memory_bandwidth(device)
    print(f"{device.type:5s} memory bandwidth (copy, read + write) {bandwidth / 1e9:.1f} GB/s", flush=True)
    gen = torch.Generator().manual_seed(0)
    x = torch.rand(points, 3, generator=gen).to(device)
    d = torch.nn.functional.normalize(torch.randn(points, 3, generator=gen), dim=-1).to(device)
    for name, (levels, feats) in CONFIGS.items():
        cfg = HashGridConfig(levels, feats, 19, 16, ngp_per_level_scale(1.0, 16, levels))
        enc = HashGridEncoding(cfg, torch.randn(cfg.n_params(), generator=gen) * 1e-2)
        if chunk:
            enc.chunk_size = chunk
        density = TcnnMLP(next_multiple(cfg.n_output_dims(), 16), 64, 1, 16)
        rgb = TcnnMLP(16 + 16, 64, 2, 3)
        enc, density, rgb = enc.to(device), density.to(device), rgb.to(device)

        def encode_only(xx, dd):
            return enc(xx)

        def full_network(xx, dd):
            h = density(enc(xx))
            return torch.exp(h[:, 0]), torch.sigmoid(rgb(torch.cat([h, sh_encode_deg4(dd)], dim=-1)))

        with torch.inference_mode():
            for what, fn in (("encoding", encode_only), ("encoding+density+rgb", full_network)):
                sec = _time(fn, x, d, device, repeats)
                table_bytes = levels * 8 * feats * 4            # per point: 8 corners per level, float32
                bound = bandwidth / table_bytes
                row = {"config": name, "what": what, "device": str(device), "points": points,
                       "chunk_size": enc.chunk_size, "median_s": sec, "points_per_s": points / sec,
                       "table_bytes_per_point": table_bytes, "bandwidth_bytes_per_s": bandwidth,
                       "bandwidth_bound_points_per_s": bound}
                print(f"{device.type:5s} {name:11s} {what:21s} {points / sec / 1e6:8.3f} M points/s "
                      f"({sec * 1e3:.1f} ms for {points} points, chunk {enc.chunk_size}); table reads "
                      f"{table_bytes} B/point: bandwidth bound {bound / 1e6:.1f} M points/s "
                      f"({points / sec / bound:.1%} of it)", flush=True)
                results.append(row)
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="auto", help="cpu, cuda[:N], or auto (cpu, then cuda if available)")
    parser.add_argument("--points", type=int, default=2**18)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--chunk", type=int, default=None,
                        help="HashGridEncoding.chunk_size (default: its own)")
    parser.add_argument("--threads", type=int, default=None, help="torch.set_num_threads (default: torch's)")
    parser.add_argument("--out", type=Path, default=None, help="also write the JSON summary here")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    from neuras_distill.device import resolve_device

    if args.device == "auto":
        devices = [torch.device("cpu")] + ([torch.device("cuda")] if torch.cuda.is_available() else [])
    else:
        devices = [resolve_device(args.device)]
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads (interop "
          f"{torch.get_num_interop_threads()}), {os.cpu_count()} CPUs: {cpu_name()}", flush=True)
    results = []
    for dev in devices:
        results += run(dev, args.points, args.repeats, args.chunk)
        results += run_neus(dev, args.points, args.repeats)
    summary = {
        "benchmark": "hashgrid_throughput", "torch": torch.__version__, "threads": torch.get_num_threads(),
        "cpu_count": os.cpu_count(), "cpu": cpu_name(), "python": platform.python_version(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "load_average": os.getloadavg() if hasattr(os, "getloadavg") else None, "results": results,
    }
    print(json.dumps(summary))
    if args.out:
        args.out.write_text(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
