"""nerfstudio's nerfacto field in plain PyTorch, from a checkpoint's state dict (docs/formats.md §3.3, §3.4).

This module owns :class:`NerfactoNetwork`: density and colour of nerfstudio's ``NerfactoField`` (nerfstudio
1.1 ``fields/nerfacto_field.py``) at points and directions **in nerfstudio's frame**. The tiny-cuda-nn layout
(``implementation="tcnn"``) is :mod:`.tcnn_layout`'s; this module reads the ``implementation="torch"`` layout
(what nerfstudio writes without tiny-cuda-nn, key names of nerfstudio >= 1.0.1 and of 0.3 .. 1.0):

* positions: L-infinity scene contraction (``|x|_inf < 1`` unchanged, else ``(2 - 1/|x|_inf) x / |x|_inf``), then
  ``(x + 2) / 4`` into [0, 1]^3 (without contraction: normalised by the scene box); points outside (0, 1)^3 get
  density 0 (nerfstudio's ``selector``);
* hash grid (``HashEncoding``): level l has resolution ``floor(base_res * b^l)``, ``b = exp((ln max_res -
  ln base_res) / (L - 1))``; the 8 corners of the cell (floor / ceil of ``x * res``) are hashed for every level
  (``(x * 1) ^ (y * 2654435761) ^ (z * 805459861)`` in int64, modulo the table size, plus ``l * T``) and
  interpolated trilinearly; table ``hash_table`` (L * T, F);
* base MLP (``mlp_base.model.1.layers.N``): ReLU hidden layers, no output activation, 1 + 15 outputs;
  density = ``average_init_density * exp(h_0)``; the 15 others are the geometry features;
* colour: spherical harmonics of degree 4 (16 components) of ``(d + 1) / 2`` (nerfstudio's torch ``SHEncoding``
  evaluates the polynomials on the [0, 1]-mapped direction), concatenated with the geometry features and the
  appearance embedding (eval mode: the mean of the embedding rows with ``use_average_appearance_embedding``,
  else zeros, or the row of one training image), through ``mlp_head.layers.N`` (ReLU, sigmoid out).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from neuras_distill.components.tcnn import TcnnMLP, sh_encode_deg4
from neuras_distill.errors import BadInputError, require

from .run import NerfactoSettings
from .tcnn_layout import is_tcnn_state, tcnn_modules

_PRIMES = (1, 2654435761, 805459861)


def contract_inf(x: torch.Tensor) -> torch.Tensor:
    """nerfstudio's ``SceneContraction(order=inf)``: (N, 3) -> (N, 3) inside the cube [-2, 2]^3."""
    mag = x.abs().amax(dim=-1, keepdim=True)
    return torch.where(mag < 1, x, (2 - 1 / mag) * (x / mag))


def sh4_nerfstudio(d01: torch.Tensor) -> torch.Tensor:
    """The 16 real spherical-harmonic components nerfstudio's torch SHEncoding (levels 4) computes for its
    input (N, 3), here ``(d + 1) / 2`` as the field passes it."""
    x, y, z = d01[:, 0], d01[:, 1], d01[:, 2]
    xx, yy, zz = x * x, y * y, z * z
    return torch.stack([
        torch.full_like(x, 0.28209479177387814),
        0.4886025119029199 * y, 0.4886025119029199 * z, 0.4886025119029199 * x,
        1.0925484305920792 * x * y, 1.0925484305920792 * y * z, 0.9461746957575601 * zz - 0.31539156525251999,
        1.0925484305920792 * x * z, 0.5462742152960396 * (xx - yy),
        0.5900435899266435 * y * (3 * xx - yy), 2.890611442640554 * x * y * z,
        0.4570457994644658 * y * (5 * zz - 1), 0.3731763325901154 * z * (5 * zz - 3),
        0.4570457994644658 * x * (5 * zz - 1), 1.445305721320277 * z * (xx - yy),
        0.5900435899266435 * x * (xx - 3 * yy)], dim=-1)


def _linear_stack(state: dict, prefix: str, source: str) -> nn.ModuleList:
    """``prefix.layers.N.weight/bias`` of a state dict as Linear layers, in order."""
    layers = nn.ModuleList()
    n = 0
    while f"{prefix}.layers.{n}.weight" in state:
        w = state[f"{prefix}.layers.{n}.weight"]
        b = state.get(f"{prefix}.layers.{n}.bias")
        require(w.ndim == 2 and (b is None or tuple(b.shape) == (w.shape[0],)),
                f"{source}: {prefix}.layers.{n} has weight {tuple(w.shape)} and bias "
                f"{None if b is None else tuple(b.shape)}; the checkpoint does not match nerfacto's MLP")
        lin = nn.Linear(w.shape[1], w.shape[0], bias=b is not None)
        with torch.no_grad():
            lin.weight.copy_(w.float())
            if b is not None:
                lin.bias.copy_(b.float())
        if layers:
            require(layers[-1].out_features == lin.in_features,
                    f"{source}: {prefix}.layers.{n} takes {lin.in_features} inputs after a layer with "
                    f"{layers[-1].out_features} outputs; the checkpoint does not match nerfacto's MLP")
        layers.append(lin)
        n += 1
    require(n > 0, f"{source}: no {prefix}.layers.* in the checkpoint")
    return layers


class TorchHashGrid(nn.Module):
    """nerfstudio's torch ``HashEncoding``: positions in [0, 1]^3 (N, 3) -> features (N, L * F)."""

    def __init__(self, table: torch.Tensor, s: NerfactoSettings):
        super().__init__()
        self.register_buffer("hash_table", table.float().contiguous())
        self.table_size = 2 ** s.log2_hashmap_size
        # exactly nerfstudio's expression and dtypes (a numpy float64 raised to an int64 tensor gives float32): a
        # resolution computed in float64 can floor to the next integer at some level
        growth = (np.exp((np.log(s.max_res) - np.log(s.base_res)) / (s.num_levels - 1)) if s.num_levels > 1
                  else 1)
        levels = torch.arange(s.num_levels)
        self.register_buffer("scalings", torch.floor(s.base_res * growth ** levels).float())
        self.register_buffer("level_offsets", levels * self.table_size)

    def forward(self, p: torch.Tensor) -> torch.Tensor:
        """The same function as nerfstudio's loop over the 8 corners, in one gather: the table size is a power
        of two and every product is non-negative (``p`` >= 0), so ``(hx ^ hy ^ hz) mod T`` equals the XOR of the
        per-axis products each taken mod T first; the 8 corners are the XOR combinations of the floor / ceil
        terms of each axis, gathered and weighted by one ``embedding_bag`` (float32 sums in another order than
        nerfstudio's: agreement to ~1e-7)."""
        n, levels = p.shape[0], self.scalings.shape[0]
        scaled = p[:, None, :] * self.scalings[None, :, None]              # (N, L, 3)
        f = torch.floor(scaled)
        t = scaled - f                                                     # weight of the ceil corner
        primes = torch.tensor(_PRIMES, device=p.device)
        mask = self.table_size - 1
        terms = torch.stack([(f.long() * primes) & mask, (torch.ceil(scaled).long() * primes) & mask], dim=-1)
        index = (terms[:, :, 0, :, None, None] ^ terms[:, :, 1, None, :, None] ^ terms[:, :, 2, None, None, :])
        index = index + self.level_offsets[None, :, None, None, None]      # (N, L, 2, 2, 2): corner (cx, cy, cz)
        w = torch.stack([1 - t, t], dim=-1)                                # (N, L, 3, 2)
        weights = w[:, :, 0, :, None, None] * w[:, :, 1, None, :, None] * w[:, :, 2, None, None, :]
        table = self.hash_table if self.hash_table.dtype == torch.float16 else self.hash_table.float()
        out = torch.nn.functional.embedding_bag(index.reshape(-1, 8), table, mode="sum",
                                                per_sample_weights=weights.reshape(-1, 8).to(table.dtype))
        return out.float().reshape(n, levels * table.shape[1])


class ReluMLP(nn.Module):
    """nerfstudio's torch ``MLP``: Linear layers with ReLU between them, no output activation."""

    def __init__(self, layers: nn.ModuleList):
        super().__init__()
        self.layers = layers

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        for i, layer in enumerate(self.layers):
            h = layer(h)
            if i < len(self.layers) - 1:
                h = torch.relu(h)
        return h


#: (hash table, base MLP prefix) of the torch layout per nerfstudio era (>= 1.0.1, then 0.3 .. 1.0)
_TORCH_ERAS = (("mlp_base.model.0.hash_table", "mlp_base.model.1"), ("mlp_base_grid.hash_table", "mlp_base_mlp"))


def _torch_modules(state: dict, s: NerfactoSettings, source: str) -> tuple[nn.Module, nn.Module]:
    """(base, head) of the ``implementation: torch`` layout (also what ``tcnn`` runs fall back to without
    tiny-cuda-nn installed)."""
    table_key, mlp_prefix = next(((t, m) for t, m in _TORCH_ERAS if t in state), (None, None))
    require(table_key is not None,
            f"{source}: neither a torch hash table (mlp_base.model.0.hash_table, mlp_base_grid.hash_table) nor "
            "tiny-cuda-nn parameters (mlp_base.model.params, ...): not a nerfacto field checkpoint")
    table = state[table_key]
    size = 2 ** s.log2_hashmap_size
    require(tuple(table.shape) == (s.num_levels * size, s.features_per_level),
            f"{source}: hash table has shape {tuple(table.shape)}, config.yml says {s.num_levels} levels x "
            f"2^{s.log2_hashmap_size} entries x {s.features_per_level} features "
            f"({(s.num_levels * size, s.features_per_level)}); config and checkpoint are from different runs")
    base_layers = _linear_stack(state, mlp_prefix, source)
    require(base_layers[0].in_features == s.num_levels * s.features_per_level
            and base_layers[-1].out_features == 1 + s.geo_feat_dim,
            f"{source}: base MLP maps {base_layers[0].in_features} -> {base_layers[-1].out_features}, expected "
            f"{s.num_levels * s.features_per_level} -> {1 + s.geo_feat_dim}")
    return nn.Sequential(TorchHashGrid(table, s), ReluMLP(base_layers)), ReluMLP(_linear_stack(state, "mlp_head",
                                                                                                source))


class NerfactoNetwork(nn.Module):
    """The nerfacto field in nerfstudio's frame: :meth:`density` (N, 3) -> (N,), :meth:`rgb` -> (N, 3).

    Args:
        state: the field's state dict (``_model.field.`` prefix removed), torch or tiny-cuda-nn layout (found from
            the keys: a run configured for tcnn but trained without it has the torch layout).
        settings: the model section of config.yml.
        appearance: "mean" (nerfstudio's eval with ``use_average_appearance_embedding``), "zeros", or the
            index of a training image whose embedding row is used.
        source: the checkpoint's name for messages.

    ``layout`` names what was read ("torch" or "tcnn (<era>)").
    """

    def __init__(self, state: dict, settings: NerfactoSettings, appearance="mean", source: str = "checkpoint"):
        super().__init__()
        s = settings
        self.settings = s
        if is_tcnn_state(state):
            self.base, self.head, era = tcnn_modules(state, s, source)
            self.layout = f"tcnn ({era})"
        else:
            self.base, self.head = _torch_modules(state, s, source)
            self.layout = "torch"
        emb = state.get("embedding_appearance.embedding.weight")
        width = emb.shape[1] if emb is not None else 0
        head_in = self.head.n_input_dims if isinstance(self.head, TcnnMLP) else self.head.layers[0].in_features
        head_out = self.head.n_output_dims if isinstance(self.head, TcnnMLP) else self.head.layers[-1].out_features
        require(head_in == 16 + s.geo_feat_dim + width and head_out == 3,
                f"{source}: colour MLP takes {head_in} inputs, expected 16 (directions) + "
                f"{s.geo_feat_dim} (geometry) + {width} (appearance)")
        if emb is None:
            self.register_buffer("appearance", torch.zeros(0))
        elif appearance == "mean":
            self.register_buffer("appearance", emb.float().mean(0) if s.use_average_appearance_embedding
                                 else torch.zeros(width))
        elif appearance == "zeros":
            self.register_buffer("appearance", torch.zeros(width))
        else:
            i = int(appearance)
            require(0 <= i < emb.shape[0], f"--appearance {i}: the run has {emb.shape[0]} training images "
                                           f"(0 .. {emb.shape[0] - 1})")
            self.register_buffer("appearance", emb[i].float().clone())
        aabb = state.get("aabb")
        self.register_buffer("scene_box", aabb.float() if aabb is not None else torch.tensor([[-1.0] * 3, [1.0] * 3]))
        self.contracted = not s.disable_scene_contraction

    # ------------------------------------------------------------------ pieces
    def normalise(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(positions in [0, 1]^3, inside mask): contraction (or the scene box), nerfstudio's selector."""
        if self.contracted:
            p = (contract_inf(x) + 2.0) / 4.0
        else:
            lo, hi = self.scene_box[0], self.scene_box[1]
            p = (x - lo) / (hi - lo)
        inside = ((p > 0.0) & (p < 1.0)).all(dim=-1)
        return p * inside[:, None], inside

    def direction_encoding(self, d: torch.Tensor) -> torch.Tensor:
        """(N, 16) spherical harmonics of unit directions d (N, 3) as the layout's SHEncoding computes them: tcnn's
        maps nerfstudio's ``(d + 1) / 2`` back to d; the torch one evaluates its polynomials on ``(d + 1) / 2``."""
        if self.layout == "torch":
            return sh4_nerfstudio((d + 1.0) / 2.0)
        return sh_encode_deg4(d)

    # ------------------------------------------------------------------ field
    def base_outputs(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(density (N,) per nerfstudio unit, geometry features (N, 15)) at nerfstudio-frame points (N, 3)."""
        p, inside = self.normalise(x.float())
        h = self.base(p)
        density = self.settings.average_init_density * torch.exp(h[:, 0]) * inside
        return density, h[:, 1:]

    def density(self, x: torch.Tensor) -> torch.Tensor:
        return self.base_outputs(x)[0]

    def rgb(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """(N, 3) colour in [0, 1] at nerfstudio-frame points x and unit directions d (N, 3)."""
        _, geo = self.base_outputs(x)
        d = torch.nn.functional.normalize(d.float(), dim=-1)
        parts = [self.direction_encoding(d), geo]
        if self.appearance.numel():
            parts.append(self.appearance.expand(x.shape[0], -1))
        return torch.sigmoid(self.head(torch.cat(parts, dim=-1)))


def field_state(pipeline: dict, source: str) -> dict:
    """The field's entries of a checkpoint's ``pipeline`` state dict (``_model.field.`` and, for DDP,
    ``module._model.field.`` removed)."""
    out = {}
    for key, value in pipeline.items():
        k = key[len("module."):] if key.startswith("module.") else key
        if k.startswith("_model.field."):
            out[k[len("_model.field."):]] = value
    if not out:
        raise BadInputError(f"{source}: the checkpoint's pipeline has no _model.field.* weights: not a nerfacto "
                            "run (keys start with " + ", ".join(sorted({k.split('.')[0] for k in pipeline})[:4]) + ")")
    return out
