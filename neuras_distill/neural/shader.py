"""The tiny per-pixel MLP shader (feature [+ view direction] -> rgb).

Owns: :class:`MLPShader`. It runs per fragment in GLSL (``bake/glsl.py`` emits its weights), so it stays
small: ``num_layers`` Linear layers in total (the paper's "3 layers with 32 hidden units" = in -> 32 -> 32 -> 3),
ReLU between them, sigmoid at the end. The view direction is the raw unit vector of travel (camera to
surface), appended after the feature, no encoding (it would cost shader instructions).
"""

from __future__ import annotations

import torch
from torch import nn


class MLPShader(nn.Module):
    """rgb = sigmoid(L_n(relu(... relu(L_1([feature, dir]))))).

    Args:
        feature_dim: D.
        hidden: width of the hidden layers.
        num_layers: number of Linear layers (>= 1); 1 means a linear map from the input to rgb.
        use_viewdir: append the (3,) view direction to the input.
    """

    def __init__(self, feature_dim: int, hidden: int = 32, num_layers: int = 3, use_viewdir: bool = True) -> None:
        super().__init__()
        if num_layers < 1:
            raise ValueError(f"num_layers must be >= 1, got {num_layers}")
        self.feature_dim, self.hidden, self.num_layers = int(feature_dim), int(hidden), int(num_layers)
        self.use_viewdir = bool(use_viewdir)
        self.in_dim = self.feature_dim + (3 if self.use_viewdir else 0)
        dims = [self.in_dim] + [self.hidden] * (self.num_layers - 1) + [3]
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:]))

    def forward(self, features: torch.Tensor, dirs: torch.Tensor | None = None) -> torch.Tensor:
        """features (B, D), dirs (B, 3) unit (ignored when use_viewdir is False) -> rgb (B, 3) in (0, 1)."""
        h = features
        if self.use_viewdir:
            if dirs is None:
                raise ValueError("MLPShader(use_viewdir=True) needs dirs")
            h = torch.cat([h, dirs.to(h.dtype)], dim=-1)
        for n, layer in enumerate(self.layers):
            h = layer(h)
            if n < len(self.layers) - 1:
                h = torch.relu(h)
        return torch.sigmoid(h)

    def weights(self) -> list[tuple]:
        """[(weight (out, in) float32 numpy, bias (out,) float32 numpy)] per layer, for baking."""
        return [(l.weight.detach().float().cpu().numpy(), l.bias.detach().float().cpu().numpy()) for l in self.layers]
