"""Totoro97/NeuS checkpoints (``ckpt_*.pth``): :class:`NeuSField` (docs/formats.md §2.1).

A checkpoint holds ``sdf_network_fine``, ``variance_network_fine``, ``color_network_fine`` (and ``nerf``, the
background, which is ignored). It stores no config, so the architecture is inferred from the tensor shapes
(:func:`infer_neus_architecture`): layer count, ``d_hidden``, ``multires`` from lin0's input width
``3 + 6·multires``, the skip layers (a layer whose input is the previous output plus the embedded input),
``d_feature``, the colour net's ``multires_view`` from its input width ``9 + 6·multires_view + d_feature``
(NeuS's "idr" mode). Softplus(β=100) between SDF layers, skip inputs ``cat(h, PE(x)) / √2``,
``sdf = out[0] / scale``, ReLU colour MLP with sigmoid output on ``[x, PE(d), ∇sdf (unnormalised), feature]``.
The world-frame Field contract is :class:`~.base.NeuSFamilyField`'s.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from neuras_distill.errors import require

from .base import DEFAULT_CHUNK, NeuSFamilyField
from .layers import layer_indices, linear_from_state, positional_encoding, run_mlp, softplus100

NEUS_KEYS = ("sdf_network_fine", "variance_network_fine", "color_network_fine")


def infer_neus_architecture(sdf_sd: dict, color_sd: dict, source: str = "checkpoint") -> dict:
    """The NeuS hyper-parameters implied by the state dicts' shapes (validated; BadInputError on mismatch).

    Returns ``{"multires", "d_in", "d_hidden", "n_layers" (hidden layers, NeuS's conf value), "skip_in",
    "d_feature", "multires_view", "color_d_hidden", "color_n_layers"}``.
    """
    src_s, src_c = f"{source}: sdf_network_fine", f"{source}: color_network_fine"
    ids = layer_indices(sdf_sd, r"^lin(\d+)\.", src_s, "lin<k>")
    require(ids == list(range(len(ids))), f"{src_s}: layers {ids} are not lin0..lin{len(ids) - 1} without gaps")
    require(len(ids) >= 2, f"{src_s}: needs at least 2 layers, found {len(ids)}")
    shapes = [tuple(linear_from_state(sdf_sd, f"lin{k}", src_s)[0].shape) for k in ids]
    for k in ids:
        require(f"lin{k}.bias" in sdf_sd, f"{src_s}: missing 'lin{k}.bias' (NeuS layers have biases)")
    d_in0 = shapes[0][1]
    require(d_in0 >= 3 and (d_in0 - 3) % 6 == 0,
            f"{src_s}: 'lin0' input width {d_in0} is not 3 + 6·multires (NeuS's positional encoding of x)")
    multires = (d_in0 - 3) // 6
    skip_in = []
    for k in ids[1:]:
        prev_out, got_in = shapes[k - 1][0], shapes[k][1]
        if got_in == prev_out + d_in0:
            skip_in.append(k)
        else:
            require(got_in == prev_out,
                    f"{src_s}: 'lin{k}' weight has shape {shapes[k]}, expected input width {prev_out} "
                    f"(lin{k - 1}'s output) or {prev_out + d_in0} (a skip layer adding the {d_in0}-wide input)")
    hidden = [shapes[k][0] + (d_in0 if k + 1 in skip_in else 0) for k in ids[:-1]]
    require(len(set(hidden)) == 1, f"{src_s}: hidden widths differ between layers ({hidden}); not a NeuS SDF net")
    d_out = shapes[-1][0]
    require(d_out >= 1, f"{src_s}: last layer 'lin{ids[-1]}' has no outputs")
    d_feature = d_out - 1

    cids = layer_indices(color_sd, r"^lin(\d+)\.", src_c, "lin<k>")
    require(cids == list(range(len(cids))), f"{src_c}: layers {cids} are not lin0..lin{len(cids) - 1}")
    cshapes = [tuple(linear_from_state(color_sd, f"lin{k}", src_c)[0].shape) for k in cids]
    for k in cids:
        require(f"lin{k}.bias" in color_sd, f"{src_c}: missing 'lin{k}.bias' (NeuS layers have biases)")
    cin = cshapes[0][1]
    rest = cin - 9 - d_feature
    require(rest >= 0 and rest % 6 == 0,
            f"{src_c}: 'lin0' input width {cin} does not match NeuS's 'idr' colour input "
            f"[x 3, PE(view dir) 3+6·k, normal 3, feature {d_feature}] for any k (other modes are not supported)")
    for k in cids[1:]:
        require(cshapes[k][1] == cshapes[k - 1][0],
                f"{src_c}: 'lin{k}' weight has shape {cshapes[k]}, expected input width {cshapes[k - 1][0]}")
    require(cshapes[-1][0] == 3, f"{src_c}: last layer 'lin{cids[-1]}' has {cshapes[-1][0]} outputs, expected 3 (RGB)")
    return {"multires": multires, "d_in": 3, "d_hidden": hidden[0], "n_layers": len(ids) - 1, "skip_in": skip_in,
            "d_feature": d_feature, "multires_view": rest // 6,
            "color_d_hidden": cshapes[0][0] if len(cids) > 1 else 0, "color_n_layers": len(cids) - 1}


def _sd(ckpt: dict, key: str, source: str) -> dict:
    sd = ckpt.get(key)
    require(sd is not None, f"{source}: missing {key!r}; a NeuS checkpoint has {', '.join(NEUS_KEYS)}")
    require(isinstance(sd, dict), f"{source}: {key!r} is a {type(sd).__name__}, expected a state dict")
    return sd




class NeuSField(NeuSFamilyField):
    """A Totoro97/NeuS field in the world frame (see the module docstring).

    Args:
        checkpoint: the loaded checkpoint dict (``sdf_network_fine``, ``variance_network_fine``,
            ``color_network_fine``; ``nerf`` (the background) is ignored).
        scale_mat: (4, 4) similarity from NeuS's unit sphere to the world (``cameras_sphere.npz``'s
            ``scale_mat_0``); None: the world is NeuS's frame.
        sdf_scale: NeuS's ``sdf_network.scale`` conf value (1.0 in every shipped conf; not stored).
        background_color: (3,) constant background, default white.
        cameras: :class:`Cameras` to attach (world frame), or None.
        bound: ``"sphere"`` (SDF intersected with the unit sphere NeuS trained in) or ``"none"``.
        chunk: points per evaluation batch.
    """

    orbit_padding = 1.0 / math.sqrt(3.0)  # the orbit frames the unit sphere NeuS trained in

    def __init__(self, checkpoint: dict, *, scale_mat=None, sdf_scale: float = 1.0, background_color=None,
                 cameras=None, bound: str = "sphere", chunk: int | None = DEFAULT_CHUNK,
                 source: str = "checkpoint"):
        require(isinstance(checkpoint, dict), f"{source}: expected a checkpoint dict, got {type(checkpoint).__name__}")
        require(bound in ("sphere", "none"), f"bound must be 'sphere' or 'none', got {bound!r}")
        require(sdf_scale > 0 and math.isfinite(sdf_scale), f"sdf_scale must be positive, got {sdf_scale}")
        sdf_sd = _sd(checkpoint, "sdf_network_fine", source)
        var_sd = _sd(checkpoint, "variance_network_fine", source)
        col_sd = _sd(checkpoint, "color_network_fine", source)
        from neuras_distill.fields.checkpoint import check_finite

        check_finite({"sdf_network_fine": sdf_sd, "variance_network_fine": var_sd, "color_network_fine": col_sd},
                     source)
        self.arch = infer_neus_architecture(sdf_sd, col_sd, source)
        n_sdf = self.arch["n_layers"] + 1
        n_col = self.arch["color_n_layers"] + 1
        self._sdf_layers = [linear_from_state(sdf_sd, f"lin{k}", source) for k in range(n_sdf)]
        self._col_layers = [linear_from_state(col_sd, f"lin{k}", source) for k in range(n_col)]
        self._skip = set(self.arch["skip_in"])
        self.multires = self.arch["multires"]
        self.multires_view = self.arch["multires_view"]
        self.sdf_scale = float(sdf_scale)
        self.bound = bound
        widths = sum(w.shape[0] for w, _ in self._sdf_layers) + sum(w.shape[0] for w, _ in self._col_layers)
        self._place(scale_mat=scale_mat, variance=(var_sd, "variance", f"{source}: variance_network_fine"),
                    box_half=1.0, background_color=background_color, cameras=cameras, chunk=chunk,
                    bytes_per_point=12 * widths)

    def __repr__(self) -> str:
        a = self.arch
        return (f"NeuSField(sdf {a['n_layers'] + 1} layers x {a['d_hidden']}, multires {a['multires']}, "
                f"skip {a['skip_in']}, feature {a['d_feature']}, colour multires_view {a['multires_view']}, "
                f"inv_s={self.inv_s:.4g}, {self.frame!r})")

    # -- networks (network frame)
    def sdf_network(self, p: torch.Tensor) -> torch.Tensor:
        """NeuS ``SDFNetwork.forward``: network-frame points (N, 3) -> (N, 1 + d_feature), sdf first."""
        inputs = positional_encoding(p * self.sdf_scale, self.multires)
        h = inputs
        last = len(self._sdf_layers) - 1
        for k, (w, b) in enumerate(self._sdf_layers):
            if k in self._skip:
                h = torch.cat([h, inputs], dim=-1) / math.sqrt(2.0)
            h = F.linear(h, w, b)
            if k < last:
                h = softplus100(h)
        return torch.cat([h[:, :1] / self.sdf_scale, h[:, 1:]], dim=-1)

    def color_network(self, p: torch.Tensor, normals: torch.Tensor, view_dirs: torch.Tensor,
                      features: torch.Tensor) -> torch.Tensor:
        """NeuS ``RenderingNetwork`` ("idr"): (N, 3) each + (N, d_feature) -> (N, 3) in [0, 1]."""
        h = torch.cat([p, positional_encoding(view_dirs, self.multires_view), normals, features], dim=-1)
        return torch.sigmoid(run_mlp(h, self._col_layers, torch.relu))

    def _local_sdf(self, p: torch.Tensor) -> torch.Tensor:
        f = self.sdf_network(p)[:, 0]
        if self.bound == "sphere":
            f = torch.maximum(f, p.norm(dim=-1) - 1.0)
        return f

    def to(self, device=None, dtype=None) -> "NeuSField":
        """Move / cast the weights (in place; returns self). Inputs are cast to the weights' dtype."""
        self._sdf_layers = [(w.to(device, dtype), b.to(device, dtype)) for w, b in self._sdf_layers]
        self._col_layers = [(w.to(device, dtype), b.to(device, dtype)) for w, b in self._col_layers]
        return self

    def _cast(self, t: torch.Tensor) -> torch.Tensor:
        w = self._sdf_layers[0][0]
        return t.reshape(-1, 3).to(device=w.device, dtype=w.dtype)

    # -- hooks of NeuSFamilyField (network frame)
    def _features(self, out: torch.Tensor) -> torch.Tensor:
        return out[:, 1:]  # NeuS's feature vector follows the SDF

    def _colour(self, p: torch.Tensor, grad: torch.Tensor, d: torch.Tensor,
                features: torch.Tensor) -> torch.Tensor:
        return self.color_network(p, grad, d, features)  # NeuS feeds the unnormalised gradient as the normal
