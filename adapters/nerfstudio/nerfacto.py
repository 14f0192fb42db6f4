"""nerfstudio's nerfacto field in plain PyTorch, from a checkpoint's state dict (docs/formats.md §3.3).

This module owns :class:`NerfactoNetwork`: density and colour of nerfstudio's ``NerfactoField`` (nerfstudio
1.1 ``fields/nerfacto_field.py``) at points and directions **in nerfstudio's frame**, for the
``implementation="torch"`` parameter layout (what nerfstudio writes without tiny-cuda-nn):

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

from neuras_distill.errors import BadInputError, require

from .run import NerfactoSettings

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


class NerfactoNetwork(nn.Module):
    """The nerfacto field in nerfstudio's frame: :meth:`density` (N, 3) -> (N,), :meth:`rgb` -> (N, 3).

    Args:
        state: the field's state dict (``_model.field.`` prefix removed), torch layout.
        settings: the model section of config.yml.
        appearance: "mean" (nerfstudio's eval with ``use_average_appearance_embedding``), "zeros", or the
            index of a training image whose embedding row is used.
        source: the checkpoint's name for messages.
    """

    def __init__(self, state: dict, settings: NerfactoSettings, appearance="mean", source: str = "checkpoint"):
        super().__init__()
        s = settings
        require(s.implementation == "torch" or "mlp_base.model.0.hash_table" in state,
                f"{source}: this run was trained with tiny-cuda-nn (implementation 'tcnn': parameters in tcnn's "
                "fused layout, mlp_base.tcnn_encoding.params); only the 'torch' layout is read so far. Re-export "
                "the run with implementation=torch (ns-train ... --pipeline.model.implementation torch "
                "--load-dir <run>/nerfstudio_models) or see docs/formats.md §3")
        table = state.get("mlp_base.model.0.hash_table")
        require(table is not None, f"{source}: no mlp_base.model.0.hash_table: not a nerfacto field checkpoint")
        size = 2 ** s.log2_hashmap_size
        require(tuple(table.shape) == (s.num_levels * size, s.features_per_level),
                f"{source}: hash table has shape {tuple(table.shape)}, config.yml says {s.num_levels} levels x "
                f"2^{s.log2_hashmap_size} entries x {s.features_per_level} features "
                f"({(s.num_levels * size, s.features_per_level)}); config and checkpoint are from different runs")
        self.settings = s
        self.register_buffer("hash_table", table.float().contiguous())
        self.table_size = size
        # exactly nerfstudio's expression and dtypes (a numpy float64 raised to an int64 tensor gives float32): a
        # resolution computed in float64 can floor to the next integer at some level
        growth = (np.exp((np.log(s.max_res) - np.log(s.base_res)) / (s.num_levels - 1)) if s.num_levels > 1
                  else 1)
        levels = torch.arange(s.num_levels)
        self.register_buffer("scalings", torch.floor(s.base_res * growth ** levels).float())
        self.register_buffer("level_offsets", levels * size)
        self.base = _linear_stack(state, "mlp_base.model.1", source)
        require(self.base[0].in_features == s.num_levels * s.features_per_level
                and self.base[-1].out_features == 1 + s.geo_feat_dim,
                f"{source}: base MLP maps {self.base[0].in_features} -> {self.base[-1].out_features}, expected "
                f"{s.num_levels * s.features_per_level} -> {1 + s.geo_feat_dim}")
        self.head = _linear_stack(state, "mlp_head", source)
        emb = state.get("embedding_appearance.embedding.weight")
        width = emb.shape[1] if emb is not None else 0
        require(self.head[0].in_features == 16 + s.geo_feat_dim + width and self.head[-1].out_features == 3,
                f"{source}: colour MLP takes {self.head[0].in_features} inputs, expected 16 (directions) + "
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

    def encode(self, p: torch.Tensor) -> torch.Tensor:
        """Hash-grid features (N, L * F) of positions in [0, 1]^3 (nerfstudio's ``HashEncoding.pytorch_fwd``)."""
        scaled = p[:, None, :] * self.scalings[None, :, None]              # (N, L, 3)
        c = torch.ceil(scaled).long()
        f = torch.floor(scaled).long()
        t = scaled - f                                                     # weight of the ceil corner
        primes = torch.tensor(_PRIMES, device=p.device)
        out = 0.0
        for cx in (0, 1):
            for cy in (0, 1):
                for cz in (0, 1):
                    corner = torch.stack([(c if cx else f)[..., 0], (c if cy else f)[..., 1],
                                          (c if cz else f)[..., 2]], dim=-1) * primes
                    index = (corner[..., 0] ^ corner[..., 1] ^ corner[..., 2]) % self.table_size + self.level_offsets
                    w = ((t[..., 0] if cx else 1 - t[..., 0]) * (t[..., 1] if cy else 1 - t[..., 1])
                         * (t[..., 2] if cz else 1 - t[..., 2]))
                    out = out + w[..., None] * self.hash_table[index]
        return out.reshape(p.shape[0], -1)

    @staticmethod
    def _mlp(layers: nn.ModuleList, h: torch.Tensor) -> torch.Tensor:
        for i, layer in enumerate(layers):
            h = layer(h)
            if i < len(layers) - 1:
                h = torch.relu(h)
        return h

    # ------------------------------------------------------------------ field
    def base_outputs(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(density (N,) per nerfstudio unit, geometry features (N, 15)) at nerfstudio-frame points (N, 3)."""
        p, inside = self.normalise(x.float())
        h = self._mlp(self.base, self.encode(p))
        density = self.settings.average_init_density * torch.exp(h[:, 0]) * inside
        return density, h[:, 1:]

    def density(self, x: torch.Tensor) -> torch.Tensor:
        return self.base_outputs(x)[0]

    def rgb(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """(N, 3) colour in [0, 1] at nerfstudio-frame points x and unit directions d (N, 3)."""
        _, geo = self.base_outputs(x)
        d = torch.nn.functional.normalize(d.float(), dim=-1)
        parts = [sh4_nerfstudio((d + 1.0) / 2.0), geo]
        if self.appearance.numel():
            parts.append(self.appearance.expand(x.shape[0], -1))
        return torch.sigmoid(self._mlp(self.head, torch.cat(parts, dim=-1)))


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
