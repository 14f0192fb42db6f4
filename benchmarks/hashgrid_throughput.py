"""Throughput of the pure-PyTorch Instant-NGP field pieces (neuras_distill.components.tcnn), forward only.

For the two Instant-NGP default grids (L16 F2 T19 and L8 F4 T19, N_min 16, aabb_scale 1) it times
(a) HashGridEncoding alone and (b) the whole default NeRF network: grid -> density MLP (64 wide, 1 hidden,
16 out) -> rgb MLP on [16 density outputs, SH degree 4 of the direction] (64 wide, 2 hidden). Random points
in the unit cube, random unit directions; the median over repeats of points per second. Prints one line per
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

CONFIGS = {"L16 F2 T19": (16, 2), "L8 F4 T19": (8, 4)}


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


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


def run(device: torch.device, points: int, repeats: int, chunk: int | None) -> list[dict]:
    results = []
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
                row = {"config": name, "what": what, "device": str(device), "points": points,
                       "chunk_size": enc.chunk_size, "median_s": sec, "points_per_s": points / sec}
                print(f"{device.type:5s} {name:11s} {what:21s} {points / sec / 1e6:8.3f} M points/s "
                      f"({sec * 1e3:.1f} ms for {points} points, chunk {enc.chunk_size})", flush=True)
                results.append(row)
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="auto", help="cpu, cuda, or auto (cpu, then cuda if available)")
    parser.add_argument("--points", type=int, default=2**18)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--chunk", type=int, default=None,
                        help="HashGridEncoding.chunk_size (default: its own)")
    parser.add_argument("--threads", type=int, default=None, help="torch.set_num_threads (default: torch's)")
    parser.add_argument("--out", type=Path, default=None, help="also write the JSON summary here")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.device == "auto":
        devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    else:
        devices = [args.device]
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads (interop "
          f"{torch.get_num_interop_threads()}), {os.cpu_count()} CPUs: {_cpu_name()}", flush=True)
    results = []
    for dev in devices:
        results += run(torch.device(dev), args.points, args.repeats, args.chunk)
    summary = {
        "benchmark": "hashgrid_throughput", "torch": torch.__version__, "threads": torch.get_num_threads(),
        "cpu_count": os.cpu_count(), "cpu": _cpu_name(), "python": platform.python_version(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "load_average": os.getloadavg() if hasattr(os, "getloadavg") else None, "results": results,
    }
    print(json.dumps(summary))
    if args.out:
        args.out.write_text(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
