"""nerfacto's tiny-cuda-nn parameter layout (``implementation: tcnn``, nerfstudio's default on a GPU).

This module owns :func:`tcnn_modules`: the field's base network (hash grid + density MLP) and colour head from
the flat ``params`` vectors tiny-cuda-nn's PyTorch modules keep (docs/formats.md §3.4). Three eras of key names:

* nerfstudio >= 1.0.1 (``MLPWithHashEncoding``): ``mlp_base.model.params`` (a ``tcnn.NetworkWithInputEncoding``)
  and ``mlp_head.tcnn_encoding.params`` (a ``tcnn.Network``);
* nerfstudio 0.3 .. 1.0 (``HashEncoding`` + ``MLP`` in a ``Sequential``): ``mlp_base_grid.tcnn_encoding.params``
  (a ``tcnn.Encoding``) and ``mlp_base_mlp.tcnn_encoding.params``, also stored as ``mlp_base.0.`` / ``mlp_base.1.``;
* nerfstudio 0.1 .. 0.2: ``mlp_base.params`` (NetworkWithInputEncoding) and ``mlp_head.params``.

Layout (tiny-cuda-nn ``network_with_input_encoding.h``): the network's weights first, then the encoding's; the
network is TCNN's FullyFusedMLP (widths 16 / 32 / 64 / 128) or CutlassMLP: no biases, row-major ``[out, in]``
matrices, inputs padded to a multiple of 16 (8 for older CutlassMLP) and output rows to 16; a plain ``tcnn.Network``
is an Identity encoding whose padded inputs are 1.0. The hash grid is TCNN's (dense coarse levels, the 0.5 offset,
its own hash: :class:`neuras_distill.components.tcnn.HashGridEncoding`) with ``base_resolution = base_res`` and
``per_level_scale = exp((ln max_res - ln base_res) / (L - 1))``, read as float32. The direction encoding is TCNN's
spherical harmonics of the direction itself (tcnn maps nerfstudio's ``(d + 1) / 2`` back), not the torch
layout's polynomials of ``(d + 1) / 2``.

The weights are stored in float32 by tinycudann's PyTorch modules (some forks store float16: both are read) and
evaluated here in float32; tiny-cuda-nn evaluates them in half precision, so densities and colours agree with a
tcnn run to about 1e-3 relative, not bitwise. The hidden-layer count is not in config.yml (nerfacto's field fixes
2 base layers, 3 colour layers): it is found from the parameter count.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from neuras_distill.components.tcnn import HashGridConfig, HashGridEncoding, TcnnMLP, mlp_param_count
from neuras_distill.errors import require

from .run import NerfactoSettings

#: (base network-with-encoding, base grid, base MLP, head) keys per nerfstudio era; None where the era has none
_ERAS = (
    ("nerfstudio >= 1.0.1", "mlp_base.model.params", None, None, "mlp_head.tcnn_encoding.params"),
    ("nerfstudio 0.3 .. 1.0", None, "mlp_base_grid.tcnn_encoding.params", "mlp_base_mlp.tcnn_encoding.params",
     "mlp_head.tcnn_encoding.params"),
    ("nerfstudio 0.1 .. 0.2", "mlp_base.params", None, None, "mlp_head.params"),
)
_MAX_HIDDEN = 16


def is_tcnn_state(state: dict) -> bool:
    """True when the field's state dict holds tiny-cuda-nn ``params`` vectors (of any era)."""
    return any(k is not None and k in state for era in _ERAS for k in era[1:])


def grid_config(s: NerfactoSettings) -> HashGridConfig:
    """The tcnn hash grid nerfstudio configures for the field (``HashEncoding.get_tcnn_encoding_config``)."""
    growth = float(np.exp((np.log(s.max_res) - np.log(s.base_res)) / (s.num_levels - 1))) if s.num_levels > 1 else 1.0
    return HashGridConfig(n_levels=s.num_levels, n_features_per_level=s.features_per_level,
                          log2_hashmap_size=s.log2_hashmap_size, base_resolution=s.base_res, per_level_scale=growth)


def _flat(state: dict, key: str, source: str) -> torch.Tensor:
    value = state[key]
    require(isinstance(value, torch.Tensor) and value.ndim == 1 and value.is_floating_point(),
            f"{source}: {key} should be a flat float tensor (tiny-cuda-nn parameters), got "
            f"{tuple(getattr(value, 'shape', ()))} {getattr(value, 'dtype', type(value).__name__)}")
    return value.detach().float()


def _mlp(params: torch.Tensor, n_in: int, width: int, n_out: int, pad_value: float, key: str, what: str,
         source: str) -> TcnnMLP:
    """The TcnnMLP whose parameter count is ``params.numel()``: hidden layers and alignment found by count."""
    for align in (16, 8):
        for hidden in range(1, _MAX_HIDDEN + 1):
            if mlp_param_count(n_in, width, hidden, n_out, align, align) == params.numel():
                mlp = TcnnMLP(n_in, width, hidden, n_out, params, output_alignment=align, input_alignment=align,
                              pad_value=pad_value)
                return mlp.requires_grad_(False)
    raise_shape(source, key, params.numel(), f"the {what} ({n_in} -> {width} wide -> {n_out}) has "
                f"{mlp_param_count(n_in, width, 1, n_out):,} weights with 1 hidden layer, "
                f"{mlp_param_count(n_in, width, 2, n_out):,} with 2")


def raise_shape(source: str, key: str, n: int, expected: str) -> None:
    require(False, f"{source}: {key} has {n:,} parameters, but {expected}; config.yml and the checkpoint are "
                   "from different runs")


def tcnn_modules(state: dict, s: NerfactoSettings, source: str) -> tuple[nn.Module, nn.Module, str]:
    """(base: points in [0, 1]^3 (N, 3) -> (N, 1 + geo_feat_dim), head: (N, 16 + geo + appearance) -> (N, 3)
    before the sigmoid, the era's name) from a tcnn-layout field state dict."""
    era = next((e for e in _ERAS if (e[1] or e[2]) in state), None)
    require(era is not None, f"{source}: no tiny-cuda-nn base network (mlp_base.model.params, "
                             "mlp_base_grid.tcnn_encoding.params or mlp_base.params): not a nerfacto field")
    name, fused_key, grid_key, mlp_key, head_key = era
    grid = grid_config(s)
    n_feat, n_out = grid.n_output_dims(), 1 + s.geo_feat_dim
    if fused_key is not None:
        params = _flat(state, fused_key, source)
        n_net = params.numel() - grid.n_params()
        if n_net <= 0:
            raise_shape(source, fused_key, params.numel(), f"the hash grid alone ({grid}) has {grid.n_params():,}")
        mlp = _mlp(params[:n_net], n_feat, s.hidden_dim, n_out, 0.0, fused_key,
                   f"density MLP after the hash grid's {grid.n_params():,}", source)
        encoding = HashGridEncoding(grid, params[n_net:])
    else:
        require(mlp_key in state, f"{source}: {grid_key} without {mlp_key}: the checkpoint is incomplete")
        grid_params = _flat(state, grid_key, source)
        if grid_params.numel() != grid.n_params():
            raise_shape(source, grid_key, grid_params.numel(), f"config.yml's hash grid ({grid}) has "
                        f"{grid.n_params():,}")
        encoding = HashGridEncoding(grid, grid_params)
        mlp = _mlp(_flat(state, mlp_key, source), n_feat, s.hidden_dim, n_out, 1.0, mlp_key, "density MLP",
                   source)
    encoding.requires_grad_(False)
    require(head_key in state, f"{source}: no {head_key} (the colour MLP): the checkpoint is incomplete")
    emb = state.get("embedding_appearance.embedding.weight")
    n_head_in = 16 + s.geo_feat_dim + (emb.shape[1] if emb is not None else 0)
    head = _mlp(_flat(state, head_key, source), n_head_in, s.hidden_dim_color, 3, 1.0, head_key,
                "colour MLP", source)
    return nn.Sequential(encoding, mlp), head, name
