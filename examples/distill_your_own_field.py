"""Distill a field you wrote yourself: any object with kind, aabb, geometry and radiance will do.

Run: python examples/distill_your_own_field.py [--out runs/my-field]
"""

from __future__ import annotations

import argparse

import torch

import neuras_distill as nd


class TwoToneSphere:
    """A unit sphere whose colour depends on height and, a little, on the view direction."""

    kind = "sdf"
    aabb = torch.tensor([[-1.2, -1.2, -1.2], [1.2, 1.2, 1.2]])
    inv_s = 800.0
    background_color = torch.tensor([1.0, 1.0, 1.0])

    def geometry(self, x: torch.Tensor) -> torch.Tensor:  # (N, 3) -> (N,) signed distance
        return x.norm(dim=-1) - 1.0

    def radiance(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:  # (N, 3), (N, 3) -> (N, 3)
        t = 0.5 + 0.5 * torch.tanh(4 * x[:, 2:3])
        base = (1 - t) * torch.tensor([0.8, 0.3, 0.2]) + t * torch.tensor([0.2, 0.4, 0.8])
        n = torch.nn.functional.normalize(x, dim=-1)
        glint = 0.15 * torch.relu(-(n * d).sum(-1, keepdim=True)) ** 4
        return (base + glint).clamp(0, 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default="runs/my-field")
    args = parser.parse_args()
    cams = nd.Cameras.orbit([0, 0, 0], 3.5, 24, width=256, height=256, elevation_deg=(-30, 50))
    result = nd.distill(TwoToneSphere(), cams, config=nd.load_config("fast"), out=args.out)
    print(f"PSNR {result.report['psnr']:.2f} dB, speedup {result.report['speedup']:.0f}x -> {result.out}")


if __name__ == "__main__":
    main()
