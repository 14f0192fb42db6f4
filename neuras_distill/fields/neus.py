"""SDF fields loaded from NeuS-family checkpoints: Totoro97/NeuS (MLP) and bennyguo/instant-nsr-pl (hash grid).

This module owns (checkpoint-formats.md §4.1, §4.2; the sources were read at the commits pinned there):

* :class:`NeuSField`: a Totoro97/NeuS checkpoint (``sdf_network_fine``, ``variance_network_fine``,
  ``color_network_fine``). The checkpoint stores no config, so the architecture is inferred from the tensor
  shapes (:func:`infer_neus_architecture`): layer count, ``d_hidden``, ``multires`` from lin0's input width
  ``3 + 6·multires``, the skip layers (a layer whose input is the previous output plus the embedded input),
  ``d_feature``, the colour net's ``multires_view`` from its input width ``9 + 6·multires_view + d_feature``
  (NeuS's "idr" mode). Softplus(β=100) between SDF layers, skip inputs ``cat(h, PE(x)) / √2``,
  ``sdf = out[0] / scale``, ReLU colour MLP with sigmoid output on ``[x, PE(d), ∇sdf (unnormalised), feature]``.
* :class:`HashGridNeuSField`: an instant-nsr-pl PyTorch-Lightning checkpoint (``state_dict`` with prefix
  ``model.``): TCNN hash grid on ``(x + r) / 2r`` (+ ``2·x_net − 1`` when ``include_xyz``), weight-norm
  VanillaMLP with biases (Softplus(100) when ``sphere_init``), colour from a TCNN MLP on
  ``[feature, SH4(d), normalize(∇sdf)]``. Its hyper-parameters are not in the checkpoint: defaults are
  instant-nsr-pl's ``configs/neus-blender.yaml`` (:data:`NSR_DEFAULT_MODEL`), overridable with a dict or the
  run's ``parsed.yaml`` (:func:`read_nsr_config`); the grid's parameter count is checked against the config
  before anything is allocated.
* :class:`SphereFrame`: NeuS's normalised frame. Both pipelines train in a unit-sphere frame given by a
  similarity ``scale_mat`` (``cameras_sphere.npz``): ``p_world = s·Q·p + t`` (NeuS: ``s = scale_mat[0, 0]``,
  ``Q = I``). The fields live in the user's world frame: points are mapped into the network frame, signed
  distances are multiplied by ``s`` (world units), ``inv_s`` is divided by ``s`` (the same opacities).
* :func:`load_neus_checkpoint`: file -> field (the adapter's ``load``), with the VolSDF density option.

Both fields: kind ``"sdf"``; ``aabb`` = the network frame's object box in the world (NeuS: the cube around the
unit sphere; instant-nsr-pl: ``[-radius, radius]^3``); ``geometry(x)`` (N, 3) world -> (N,) world-unit signed
distance, negative inside; ``radiance(x, d)`` (N, 3), unit travel directions -> (N, 3) in [0, 1] (normals by
autograd, enabled locally so callers may run under ``torch.no_grad``); ``inv_s``; ``background_color``
(white unless told); ``cameras`` when a camera file was given. Evaluation is chunked (``chunk`` points).
Outside the network's domain the SDF is bounded: NeuS never trains outside its unit sphere (its rays are cut
there), so :class:`NeuSField` intersects its SDF with that sphere (``bound="sphere"``); the hash grid is
undefined outside its box, so :class:`HashGridNeuSField` clamps to the box and adds the distance to it.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
import torch.nn.functional as F

from ..errors import BadInputError, require
from .base import evaluate_chunked

DEFAULT_CHUNK = None          # None: sized from the network so one chunk's autograd graph stays ~256 MB
ACTIVATION_BUDGET = 2**28     # bytes of activations kept for the normal's backward pass, per chunk
NEUS_KEYS = ("sdf_network_fine", "variance_network_fine", "color_network_fine")
SOFTPLUS_BETA = 100.0
INV_S_RANGE = (1e-6, 1e6)

# instant-nsr-pl configs/neus-blender.yaml @ e5fe3f2 (the model section's parts the field needs)
NSR_DEFAULT_MODEL: dict = {
    "radius": 1.5,
    "geometry": {
        "feature_dim": 13,
        "xyz_encoding_config": {"otype": "HashGrid", "n_levels": 16, "n_features_per_level": 2,
                                "log2_hashmap_size": 19, "base_resolution": 32,
                                "per_level_scale": 1.3195079107728942, "include_xyz": True},
        "mlp_network_config": {"otype": "VanillaMLP", "activation": "ReLU", "output_activation": "none",
                               "n_neurons": 64, "n_hidden_layers": 1, "sphere_init": True,
                               "sphere_init_radius": 0.5, "weight_norm": True},
    },
    "texture": {
        "dir_encoding_config": {"otype": "SphericalHarmonics", "degree": 4},
        "mlp_network_config": {"otype": "FullyFusedMLP", "activation": "ReLU", "output_activation": "none",
                               "n_neurons": 64, "n_hidden_layers": 2},
        "color_activation": "sigmoid",
    },
}


# ---------------------------------------------------------------------------------------------- frame
class SphereFrame:
    """The similarity ``p_world = s·Q·p + t`` from a network frame to the world (``Q`` a rotation, s > 0)."""

    def __init__(self, scale_mat: np.ndarray | None = None):
        from .neus_cameras import check_similarity, similarity_parts

        m = np.eye(4) if scale_mat is None else check_similarity(scale_mat, "scale_mat")
        s, q, t = similarity_parts(m)
        self.matrix = m
        self.scale = float(s)
        self.rotation = torch.as_tensor(q, dtype=torch.float32)
        self.translation = torch.as_tensor(t, dtype=torch.float32)
        self._identity_rot = bool(np.allclose(q, np.eye(3), atol=1e-12))

    def __repr__(self) -> str:
        return f"SphereFrame(scale={self.scale:.6g}, translation={self.translation.tolist()})"

    def to_local(self, x: torch.Tensor) -> torch.Tensor:
        """World points (N, 3) -> network-frame points ``Qᵀ (x − t) / s`` (dtype and device of x)."""
        p = x - self.translation.to(x)
        if not self._identity_rot:
            p = p @ self.rotation.to(x)
        return p / self.scale

    def dir_to_local(self, d: torch.Tensor) -> torch.Tensor:
        """World directions (N, 3) -> network-frame directions ``Qᵀ d`` (lengths kept)."""
        return d if self._identity_rot else d @ self.rotation.to(d)

    def to_world(self, p: torch.Tensor) -> torch.Tensor:
        """Network-frame points (N, 3) -> world points."""
        p = p * self.scale
        if not self._identity_rot:
            p = p @ self.rotation.to(p).T
        return p + self.translation.to(p)

    def box_to_world(self, half: float) -> torch.Tensor:
        """(2, 3) world aabb of the network-frame cube ``[-half, half]^3``."""
        corners = torch.tensor([[i, j, k] for i in (-1.0, 1.0) for j in (-1.0, 1.0) for k in (-1.0, 1.0)]) * half
        w = self.to_world(corners)
        return torch.stack([w.min(0).values, w.max(0).values])


# ---------------------------------------------------------------------------------------------- pieces
def positional_encoding(x: torch.Tensor, multires: int) -> torch.Tensor:
    """NeuS / nerf-pytorch embedder: ``[x, sin(2^0 x), cos(2^0 x), ..., sin(2^(m-1) x), cos(2^(m-1) x)]``
    -> (N, 3 + 6m) for x (N, 3)."""
    if multires <= 0:
        return x
    parts = [x]
    for k in range(multires):
        xf = x * float(2.0**k)
        parts.append(torch.sin(xf))
        parts.append(torch.cos(xf))
    return torch.cat(parts, dim=-1)


def _shape(t: Any) -> tuple:
    return tuple(t.shape) if isinstance(t, torch.Tensor) else (type(t).__name__,)


def linear_from_state(sd: dict, prefix: str, source: str) -> tuple[torch.Tensor, torch.Tensor | None]:
    """(W (out, in), bias (out,) or None) of a ``nn.Linear`` saved plain or with weight norm (dim 0).

    Accepts ``{prefix}.weight_g`` / ``.weight_v`` (legacy ``nn.utils.weight_norm``),
    ``{prefix}.parametrizations.weight.original0`` / ``original1`` (new API) or ``{prefix}.weight``;
    ``W = g · v / ‖v‖_row``. Shapes are validated (message names the key, expected and found shapes).
    """
    def get(key: str):
        v = sd.get(key)
        if v is not None and not isinstance(v, torch.Tensor):
            raise BadInputError(f"{source}: {key!r} is a {type(v).__name__}, expected a tensor")
        return v

    styles = [(f"{prefix}.weight_g", f"{prefix}.weight_v"),
              (f"{prefix}.parametrizations.weight.original0", f"{prefix}.parametrizations.weight.original1")]
    w = None
    for kg, kv in styles:
        g, v = get(kg), get(kv)
        if g is None and v is None:
            continue
        require(g is not None and v is not None, f"{source}: has {kg if g is not None else kv!r} but not "
                                                 f"{kv if g is not None else kg!r} (weight norm needs both)")
        require(v.ndim == 2, f"{source}: {kv!r} should be a matrix (out, in), got shape {_shape(v)}")
        out = v.shape[0]
        require(tuple(g.shape) in ((out, 1), (out,)),
                f"{source}: {kg!r} has shape {_shape(g)}, expected ({out}, 1) to match {kv!r} {_shape(v)}")
        v64 = v.double()
        norm = v64.norm(dim=1, keepdim=True)
        require(bool((norm > 0).all()), f"{source}: {kv!r} has an all-zero row; weight norm is undefined")
        w = (g.double().reshape(out, 1) * v64 / norm).float()
        break
    if w is None:
        plain = get(f"{prefix}.weight")
        require(plain is not None, f"{source}: missing weights of layer {prefix!r} (expected {prefix}.weight_g/"
                                   f"weight_v, {prefix}.parametrizations.weight.original0/1 or {prefix}.weight)")
        require(plain.ndim == 2, f"{source}: {prefix + '.weight'!r} should be a matrix (out, in), got {_shape(plain)}")
        w = plain.float()
    b = get(f"{prefix}.bias")
    if b is not None:
        require(tuple(b.shape) == (w.shape[0],),
                f"{source}: {prefix + '.bias'!r} has shape {_shape(b)}, expected ({w.shape[0]},)")
        b = b.float()
    return w, b


def _layer_indices(sd: dict, pattern: str, source: str, what: str) -> list[int]:
    rx = re.compile(pattern)
    ids = sorted({int(m.group(1)) for k in sd if isinstance(k, str) and (m := rx.match(k))})
    require(ids, f"{source}: no {what} layers found (keys like {pattern.replace(chr(92), '')!r})")
    return ids


def _sd(ckpt: dict, key: str, source: str) -> dict:
    sd = ckpt.get(key)
    require(sd is not None, f"{source}: missing {key!r}; a NeuS checkpoint has {', '.join(NEUS_KEYS)}")
    require(isinstance(sd, dict), f"{source}: {key!r} is a {type(sd).__name__}, expected a state dict")
    return sd


def _inv_s(sd: dict, key: str, source: str) -> float:
    v = sd.get(key)
    require(isinstance(v, torch.Tensor), f"{source}: missing the variance {key!r} (scalar tensor)")
    require(v.numel() == 1, f"{source}: {key!r} has shape {_shape(v)}, expected a scalar ()")
    val = float(v.reshape(()).double())
    require(math.isfinite(val), f"{source}: {key!r} is {val}")
    return float(min(max(math.exp(min(10.0 * val, 700.0)), INV_S_RANGE[0]), INV_S_RANGE[1]))


def _chunk(chunk: int | None, bytes_per_point: int) -> int:
    """Points per evaluation batch: ``chunk`` if given, else what fits ACTIVATION_BUDGET (1024 .. 65536)."""
    if chunk is not None:
        require(int(chunk) >= 1, f"chunk must be >= 1, got {chunk}")
        return int(chunk)
    return int(min(2**16, max(1024, ACTIVATION_BUDGET // max(1, bytes_per_point))))


def _softplus(x: torch.Tensor) -> torch.Tensor:
    return F.softplus(x, beta=SOFTPLUS_BETA)


def _mlp(h: torch.Tensor, layers, act) -> torch.Tensor:
    """``h`` through ``layers`` [(weight, bias or None), ...] with ``act`` between layers (not after the last)."""
    last = len(layers) - 1
    for k, (w, b) in enumerate(layers):
        h = F.linear(h, w, b)
        if k < last:
            h = act(h)
    return h


def _white(background_color) -> torch.Tensor:
    bg = torch.as_tensor((1.0, 1.0, 1.0) if background_color is None else background_color,
                         dtype=torch.float32).reshape(-1)
    require(bg.numel() == 3 and bool(torch.isfinite(bg).all()),
            f"background_color must be 3 finite numbers, got {bg.tolist()}")
    return bg


# ---------------------------------------------------------------------------------------------- NeuS (MLP)
def infer_neus_architecture(sdf_sd: dict, color_sd: dict, source: str = "checkpoint") -> dict:
    """The NeuS hyper-parameters implied by the state dicts' shapes (validated; BadInputError on mismatch).

    Returns ``{"multires", "d_in", "d_hidden", "n_layers" (hidden layers, NeuS's conf value), "skip_in",
    "d_feature", "multires_view", "color_d_hidden", "color_n_layers"}``.
    """
    src_s, src_c = f"{source}: sdf_network_fine", f"{source}: color_network_fine"
    ids = _layer_indices(sdf_sd, r"^lin(\d+)\.", src_s, "lin<k>")
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

    cids = _layer_indices(color_sd, r"^lin(\d+)\.", src_c, "lin<k>")
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


class NeuSField:
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

    kind = "sdf"

    def __init__(self, checkpoint: dict, *, scale_mat=None, sdf_scale: float = 1.0, background_color=None,
                 cameras=None, bound: str = "sphere", chunk: int | None = DEFAULT_CHUNK,
                 source: str = "checkpoint"):
        require(isinstance(checkpoint, dict), f"{source}: expected a checkpoint dict, got {type(checkpoint).__name__}")
        require(bound in ("sphere", "none"), f"bound must be 'sphere' or 'none', got {bound!r}")
        require(sdf_scale > 0 and math.isfinite(sdf_scale), f"sdf_scale must be positive, got {sdf_scale}")
        sdf_sd = _sd(checkpoint, "sdf_network_fine", source)
        var_sd = _sd(checkpoint, "variance_network_fine", source)
        col_sd = _sd(checkpoint, "color_network_fine", source)
        from .checkpoint import check_finite

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
        self.frame = SphereFrame(scale_mat)
        self.inv_s_network = _inv_s(var_sd, "variance", f"{source}: variance_network_fine")
        self.inv_s = self.inv_s_network / self.frame.scale
        self.aabb = self.frame.box_to_world(1.0)
        self.background_color = _white(background_color)
        self.cameras = cameras
        self.bound = bound
        widths = sum(w.shape[0] for w, _ in self._sdf_layers) + sum(w.shape[0] for w, _ in self._col_layers)
        self.chunk = _chunk(chunk, 12 * widths)

    def default_cameras(self, n: int, width: int = 512, height: int = 512):
        """An orbit (z up) framing the unit sphere NeuS trained in, for checkpoints without cameras."""
        from ..scenes.analytic import orbit_framing

        return orbit_framing(self.aabb, n, width, height, padding=1.0 / math.sqrt(3.0))

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
                h = _softplus(h)
        return torch.cat([h[:, :1] / self.sdf_scale, h[:, 1:]], dim=-1)

    def color_network(self, p: torch.Tensor, normals: torch.Tensor, view_dirs: torch.Tensor,
                      features: torch.Tensor) -> torch.Tensor:
        """NeuS ``RenderingNetwork`` ("idr"): (N, 3) each + (N, d_feature) -> (N, 3) in [0, 1]."""
        h = torch.cat([p, positional_encoding(view_dirs, self.multires_view), normals, features], dim=-1)
        return torch.sigmoid(_mlp(h, self._col_layers, torch.relu))

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

    # -- Field contract (world frame)
    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        """x (N, 3) world points -> (N,) signed distance in world units, negative inside."""
        return evaluate_chunked(lambda xc: self._local_sdf(self.frame.to_local(xc)) * self.frame.scale,
                                self._cast(x), chunk=self.chunk)

    def sdf_and_gradient(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(network-frame SDF (N,), its gradient ∇_p sdf (N, 3), unnormalised) at world points x (N, 3)."""
        return evaluate_chunked(lambda xc: self._sdf_grad(self.frame.to_local(xc))[:2], self._cast(x),
                                chunk=self.chunk)

    def _sdf_grad(self, p: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        with torch.enable_grad():
            p = p.detach().requires_grad_(True)
            out = self.sdf_network(p)
            (grad,) = torch.autograd.grad(out[:, 0].sum(), p)
        return out[:, 0].detach(), grad.detach(), out[:, 1:].detach()

    def radiance(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """x (N, 3) world points, d (N, 3) unit travel directions -> (N, 3) colour in [0, 1]."""
        def run(xc: torch.Tensor, dc: torch.Tensor) -> torch.Tensor:
            p = self.frame.to_local(xc)
            _, grad, feat = self._sdf_grad(p)
            return self.color_network(p, grad, self.frame.dir_to_local(dc), feat)

        return evaluate_chunked(run, self._cast(x), self._cast(d), chunk=self.chunk)


# ---------------------------------------------------------------------------------------------- instant-nsr-pl
def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def read_nsr_config(config) -> dict:
    """instant-nsr-pl config -> the full parsed dict (``{"model": ..., ...}`` or a bare model section).

    ``config`` is a dict, or a path to the run's ``config/parsed.yaml`` (YAML needs PyYAML; a JSON file
    works without it — JSON is valid YAML).
    """
    if isinstance(config, dict):
        return config
    path = Path(config)
    require(path.is_file(), f"config {path} does not exist (give instant-nsr-pl's <run>/config/parsed.yaml)")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise BadInputError(f"config {path} cannot be read as text: {exc}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError:
        try:
            import yaml  # optional: only needed for YAML configs
        except ImportError:
            raise BadInputError(f"config {path} is YAML; reading it needs PyYAML (pip install pyyaml), "
                                "or pass the config as JSON") from None
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise BadInputError(f"config {path} is not valid YAML: {str(exc).splitlines()[0]}") from None
    require(isinstance(data, dict), f"config {path} does not hold a mapping (got {type(data).__name__})")
    return data


def nsr_model_config(config=None) -> dict:
    """The model section (defaults of neus-blender.yaml overridden by ``config``, full or model-only)."""
    if config is None:
        return _merge(NSR_DEFAULT_MODEL, {})
    data = read_nsr_config(config)
    model = data.get("model", data)
    require(isinstance(model, dict), "config: 'model' is not a mapping")
    return _merge(NSR_DEFAULT_MODEL, model)


def _grid_config(enc: dict):
    from ..components.tcnn import HashGridConfig

    otype = str(enc.get("otype", "HashGrid"))
    require(otype in ("HashGrid", "ProgressiveBandHashGrid"),
            f"geometry.xyz_encoding_config.otype {otype!r} is not supported (HashGrid, ProgressiveBandHashGrid)")
    enc = {k: v for k, v in enc.items() if k in ("n_levels", "n_features_per_level", "log2_hashmap_size",
                                                 "base_resolution", "per_level_scale", "interpolation")}
    enc["otype"] = "HashGrid"
    return HashGridConfig.from_json(enc)


def _grid_alternatives(n: int, cfg) -> list[str]:
    """Simple configs (same N_min and per_level_scale) whose parameter count is n."""
    from ..components.tcnn import HashGridConfig

    hits = []
    for f in (2, 1, 4, 8):
        for log2 in range(10, 25):
            for levels in range(1, 33):
                c = HashGridConfig(levels, f, log2, cfg.base_resolution, cfg.per_level_scale, cfg.interpolation)
                if c.n_params() == n:
                    hits.append(f"n_levels={levels}, n_features_per_level={f}, log2_hashmap_size={log2}")
    return hits[:3]


def _find(sd: dict, *names: str) -> tuple[str, torch.Tensor] | tuple[None, None]:
    for n in names:
        if n in sd:
            return n, sd[n]
    return None, None


def _activation(name, where: str) -> Callable[[torch.Tensor], torch.Tensor]:
    n = "none" if name is None else str(name).lower()
    table = {"none": lambda x: x, "relu": torch.relu, "sigmoid": torch.sigmoid, "softplus": F.softplus,
             "tanh": torch.tanh}
    require(n in table, f"{where}: activation {name!r} is not supported ({', '.join(table)})")
    return table[n]


class HashGridNeuSField:
    """An instant-nsr-pl hash-grid NeuS field in the world frame (see the module docstring).

    Args:
        state_dict: the Lightning ``state_dict`` (with or without the ``model.`` prefix).
        config: None (neus-blender defaults), a dict (full parsed config or the model section) or a path to
            ``parsed.yaml``/JSON.
        scale_mat: (4, 4) similarity from the network frame to the world (DTU-style data); None: identity.
        background_color, cameras, chunk: as :class:`NeuSField`.
    """

    kind = "sdf"

    def __init__(self, state_dict: dict, config=None, *, scale_mat=None, background_color=None, cameras=None,
                 chunk: int | None = DEFAULT_CHUNK, source: str = "checkpoint"):
        from .checkpoint import check_finite

        require(isinstance(state_dict, dict),
                f"{source}: 'state_dict' is a {type(state_dict).__name__}, not a dict")
        sd = {k[6:] if isinstance(k, str) and k.startswith("model.") else k: v for k, v in state_dict.items()}
        self.source = source
        self.model_config = model = nsr_model_config(config)
        self.radius = self._radius(sd, config, float(model["radius"]), source)
        self.notes: list[str] = []
        if any(isinstance(k, str) and k.startswith(("geometry_bg.", "texture_bg.")) for k in sd):
            self.notes.append("the learned background model (geometry_bg/texture_bg) is not loaded; "
                              "background_color is used instead")
        var_key, var = _find(sd, "variance.variance")
        require(var is not None, f"{source}: missing 'model.variance.variance' (the NeuS sharpness)")
        grid_params = self._checked_grid_params(sd, model["geometry"]["xyz_encoding_config"])
        check_finite({k: v for k, v in sd.items() if isinstance(k, str) and k.startswith(
            ("geometry.encoding", "geometry.network", "texture.", "variance."))}, source)
        self._build_geometry(sd, model["geometry"], grid_params)
        self._build_texture(sd, model["texture"])

        self.frame = SphereFrame(scale_mat)
        self.inv_s_network = _inv_s({"v": var}, "v", f"{source}: {var_key}")
        self.inv_s = self.inv_s_network / self.frame.scale
        self.aabb = self.frame.box_to_world(self.radius)
        self.background_color = _white(background_color)
        self.cameras = cameras
        per_point = 12 * (sum(w.shape[0] for w, _ in self._geo_layers) + 64) + 600 * self.grid_config.n_levels
        self.chunk = _chunk(chunk, per_point)

    def _checked_grid_params(self, sd: dict, enc_cfg: dict) -> torch.Tensor:
        """The flat hash-grid table, its length checked against the config before anything is allocated."""
        source = self.source
        key, params = _find(sd, "geometry.encoding.encoding.params", "geometry.encoding.encoding.encoding.params")
        require(params is not None, f"{source}: missing 'model.geometry.encoding.encoding.params' (the hash "
                                    "grid); not an instant-nsr-pl hash-grid NeuS checkpoint")
        require(isinstance(params, torch.Tensor) and params.ndim == 1,
                f"{source}: {key!r} should be a flat tensor, got shape {_shape(params)}")
        self.grid_config = gcfg = _grid_config(enc_cfg)
        self.include_xyz = bool(enc_cfg.get("include_xyz", False))
        n_grid = gcfg.n_params()
        if params.numel() != n_grid:
            alts = _grid_alternatives(int(params.numel()), gcfg)
            hint = (f"; with base_resolution={gcfg.base_resolution} and per_level_scale="
                    f"{gcfg.per_level_scale:.6g} these match: {' | '.join(alts)}") if alts else ""
            raise BadInputError(
                f"{source}: the hash grid {key!r} has {params.numel():,} parameters but the config "
                f"(n_levels={gcfg.n_levels}, n_features_per_level={gcfg.n_features_per_level}, "
                f"log2_hashmap_size={gcfg.log2_hashmap_size}, base_resolution={gcfg.base_resolution}) gives "
                f"{n_grid:,}; pass config=<run>/config/parsed.yaml (or a dict with model.geometry."
                f"xyz_encoding_config){hint}")
        return params

    def _build_geometry(self, sd: dict, geo: dict, grid_params: torch.Tensor) -> None:
        """Hash grid + VanillaMLP (Linear, act, Linear, act, ..., Linear; keys ``layers.0``, ``.2``, ...)."""
        from ..components.tcnn import HashGridEncoding

        mlp_cfg, gcfg = geo["mlp_network_config"], self.grid_config
        require(str(mlp_cfg.get("otype", "VanillaMLP")) == "VanillaMLP",
                f"config: geometry.mlp_network_config.otype {mlp_cfg.get('otype')!r} is not supported "
                "(VanillaMLP)")
        for bad in ("sdf_activation", "feature_activation"):
            require(bad not in geo, f"config: geometry.{bad} is not supported")
        src = f"{self.source}: geometry.network"
        geo_sd = {k[len("geometry.network."):]: v for k, v in sd.items()
                  if isinstance(k, str) and k.startswith("geometry.network.")}
        require(geo_sd, f"{self.source}: missing 'model.geometry.network.layers.*' (the SDF MLP)")
        ids = _layer_indices(geo_sd, r"^layers\.(\d+)\.", src, "layers.<i>")
        require(ids == list(range(0, 2 * len(ids), 2)),
                f"{src}: layer indices {ids} are not 0, 2, 4, ... (Linear/activation pairs of a VanillaMLP)")
        self._geo_layers = [linear_from_state(geo_sd, f"layers.{i}", src) for i in ids]
        n_in = 3 * int(self.include_xyz) + gcfg.n_output_dims()
        w0 = self._geo_layers[0][0]
        require(w0.shape[1] == n_in,
                f"{src}: 'layers.0' weight has shape {tuple(w0.shape)}, expected input width {n_in} "
                f"({'3 (xyz) + ' if self.include_xyz else ''}{gcfg.n_levels}·{gcfg.n_features_per_level} "
                "grid features); check include_xyz and the grid config")
        for j in range(1, len(ids)):
            prev, w = self._geo_layers[j - 1][0], self._geo_layers[j][0]
            require(w.shape[1] == prev.shape[0],
                    f"{src}: 'layers.{ids[j]}' weight has shape {tuple(w.shape)}, expected input width "
                    f"{prev.shape[0]}")
        self.feature_dim = int(self._geo_layers[-1][0].shape[0])
        cfg_feat = int(geo.get("feature_dim", self.feature_dim))
        require(cfg_feat == self.feature_dim, f"{src}: last layer has {self.feature_dim} outputs but the "
                                              f"config's geometry.feature_dim is {cfg_feat}")
        self._geo_act = _softplus if mlp_cfg.get("sphere_init", False) else _activation(
            mlp_cfg.get("activation", "ReLU"), "geometry.mlp_network_config")
        self._geo_out_act = _activation(mlp_cfg.get("output_activation", "none"), "geometry.mlp_network_config")
        self.encoding = HashGridEncoding(gcfg, grid_params.detach().float())
        self.encoding.requires_grad_(False)

    def _build_texture(self, sd: dict, tex: dict) -> None:
        """``[feature, SH4(d), normal]`` -> TCNN MLP (``texture.network.params``) or VanillaMLP -> activation."""
        from ..components.tcnn import TcnnMLP, mlp_param_count

        dcfg = tex.get("dir_encoding_config", {})
        require(str(dcfg.get("otype")) == "SphericalHarmonics" and int(dcfg.get("degree", 4)) == 4,
                f"config: texture.dir_encoding_config {dcfg} is not supported (SphericalHarmonics degree 4)")
        tcfg = tex["mlp_network_config"]
        self.texture_in = n_in = self.feature_dim + 16 + 3
        n_in_cfg = tex.get("input_feature_dim")
        require(n_in_cfg is None or int(n_in_cfg) == self.feature_dim + 3,
                f"config: texture.input_feature_dim {n_in_cfg} should be feature_dim + 3 = {self.feature_dim + 3}")
        self._tex_out_act = _activation(tcfg.get("output_activation", "none"), "texture.mlp_network_config")
        self._color_act = _activation(tex.get("color_activation", "sigmoid"), "texture.color_activation")
        otype = str(tcfg.get("otype", "FullyFusedMLP"))
        key, params = _find(sd, "texture.network.params")
        if otype == "VanillaMLP" or params is None:
            tex_sd = {k[len("texture.network."):]: v for k, v in sd.items()
                      if isinstance(k, str) and k.startswith("texture.network.")}
            require(tex_sd, f"{self.source}: missing 'model.texture.network.params' (the colour MLP)")
            src = f"{self.source}: texture.network"
            ids = _layer_indices(tex_sd, r"^layers\.(\d+)\.", src, "layers.<i>")
            self._tex_layers = [linear_from_state(tex_sd, f"layers.{i}", src) for i in ids]
            w0, wl = self._tex_layers[0][0], self._tex_layers[-1][0]
            require(w0.shape[1] == n_in, f"{src}: 'layers.{ids[0]}' has input width {w0.shape[1]}, expected {n_in}")
            require(wl.shape[0] == 3, f"{src}: last layer has {wl.shape[0]} outputs, expected 3")
            self._tex_act = _activation(tcfg.get("activation", "ReLU"), "texture.mlp_network_config")
            self._texture_mlp = self._vanilla_texture
            return
        require(otype in ("FullyFusedMLP", "CutlassMLP"),
                f"config: texture.mlp_network_config.otype {otype!r} is not supported")
        require(isinstance(params, torch.Tensor) and params.ndim == 1,
                f"{self.source}: {key!r} should be a flat tensor, got shape {_shape(params)}")
        require(str(tcfg.get("activation", "ReLU")).lower() == "relu",
                "config: texture.mlp_network_config.activation must be ReLU")
        width, n_hidden = int(tcfg.get("n_neurons", 64)), int(tcfg.get("n_hidden_layers", 2))
        aligns = (16, 8) if otype == "FullyFusedMLP" else (8, 16)  # CutlassMLP used 8 before TCNN f00206e
        counts = {a: mlp_param_count(n_in, width, n_hidden, 3, a, a) for a in aligns}
        align = next((a for a in aligns if counts[a] == params.numel()), None)
        require(align is not None,
                f"{self.source}: {key!r} has {params.numel():,} parameters but a {otype} with input {n_in}, "
                f"{n_hidden} hidden layers of {width} and 3 outputs has {counts[aligns[0]]:,}; pass the run's "
                "config (texture.mlp_network_config)")
        self._texture_mlp = TcnnMLP(n_in, width, n_hidden, 3, params.detach().float(), output_alignment=align,
                                    input_alignment=align, pad_value=1.0)  # TCNN pads network inputs with 1.0
        self._texture_mlp.requires_grad_(False)

    def _vanilla_texture(self, h: torch.Tensor) -> torch.Tensor:
        last = len(self._tex_layers) - 1
        for j, (w, b) in enumerate(self._tex_layers):
            h = F.linear(h, w, b)
            if j < last:
                h = self._tex_act(h)
        return h

    @staticmethod
    def _radius(sd: dict, config, cfg_radius: float, source: str) -> float:
        """The box radius: the ``scene_aabb`` buffer when the checkpoint has it (it is what was trained),
        else the config's ``model.radius``; an explicit config radius must agree with the buffer."""
        aabb = sd.get("scene_aabb")
        radius = cfg_radius
        if isinstance(aabb, torch.Tensor) and aabb.numel() == 6 and bool(torch.isfinite(aabb).all()):
            lo, hi = aabb.double().reshape(2, 3)
            r = float(hi.max())
            if torch.allclose(lo, -hi, rtol=1e-5, atol=1e-7) and torch.allclose(hi, torch.full_like(hi, r), rtol=1e-5):
                given = None
                if config is not None:
                    data = read_nsr_config(config)
                    given = (data.get("model", data) or {}).get("radius")
                require(given is None or abs(float(given) - r) <= 1e-5 * r,
                        f"{source}: the checkpoint's scene_aabb has radius {r:g} but the config says "
                        f"model.radius = {given}; give the config of this run")
                radius = r
        require(radius > 0 and math.isfinite(radius), f"config: model.radius must be positive, got {radius}")
        return float(radius)

    def default_cameras(self, n: int, width: int = 512, height: int = 512):
        """An orbit (z up) framing the object box, for checkpoints that come without cameras."""
        from ..scenes.analytic import orbit_framing

        return orbit_framing(self.aabb, n, width, height)

    def __repr__(self) -> str:
        g = self.grid_config
        return (f"HashGridNeuSField(radius={self.radius}, grid L{g.n_levels} F{g.n_features_per_level} "
                f"T2^{g.log2_hashmap_size} N{g.base_resolution} b{g.per_level_scale:.4g}, "
                f"mlp {len(self._geo_layers)} layers, feature {self.feature_dim}, inv_s={self.inv_s:.4g}, "
                f"{self.frame!r})")

    # -- networks (network frame)
    def sdf_network(self, p: torch.Tensor) -> torch.Tensor:
        """Network-frame points (N, 3) inside ``[-r, r]^3`` -> (N, feature_dim) raw outputs (sdf = column 0)."""
        x = ((p + self.radius) / (2.0 * self.radius)).clamp(0.0, 1.0)
        h = self.encoding(x)
        if self.include_xyz:
            h = torch.cat([x * 2.0 - 1.0, h], dim=-1)
        return self._geo_out_act(_mlp(h, self._geo_layers, self._geo_act))

    def texture_network(self, features: torch.Tensor, dirs: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
        """instant-nsr-pl ``VolumeRadiance``: (N, F), unit dirs (N, 3), unit normals (N, 3) -> (N, 3)."""
        from ..components.tcnn import sh_encode_deg4

        h = torch.cat([features, sh_encode_deg4(dirs), normals], dim=-1)
        return self._color_act(self._tex_out_act(self._texture_mlp(h)))

    def _outside(self, p: torch.Tensor) -> torch.Tensor:
        return (p - p.clamp(-self.radius, self.radius)).norm(dim=-1)

    # -- Field contract (world frame)
    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        """x (N, 3) world points -> (N,) signed distance in world units, negative inside."""
        def run(xc: torch.Tensor) -> torch.Tensor:
            p = self.frame.to_local(xc)
            return (self.sdf_network(p)[:, 0] + self._outside(p)) * self.frame.scale

        return evaluate_chunked(run, x.reshape(-1, 3).float(), chunk=self.chunk)

    def _sdf_grad(self, p: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        with torch.enable_grad():
            p = p.detach().requires_grad_(True)
            out = self.sdf_network(p)
            (grad,) = torch.autograd.grad(out[:, 0].sum(), p)
        return out[:, 0].detach(), grad.detach(), out.detach()

    def sdf_and_gradient(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(network-frame SDF (N,), its gradient (N, 3)) at world points x (N, 3)."""
        return evaluate_chunked(lambda xc: self._sdf_grad(self.frame.to_local(xc))[:2], x.reshape(-1, 3).float(),
                                chunk=self.chunk)

    def radiance(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """x (N, 3) world points, d (N, 3) unit travel directions -> (N, 3) colour in [0, 1]."""
        def run(xc: torch.Tensor, dc: torch.Tensor) -> torch.Tensor:
            p = self.frame.to_local(xc)
            _, grad, feat = self._sdf_grad(p)
            n = F.normalize(grad, dim=-1, eps=1e-12)
            return self.texture_network(feat, F.normalize(self.frame.dir_to_local(dc), dim=-1), n)

        return evaluate_chunked(run, x.reshape(-1, 3).float(), d.reshape(-1, 3).float(), chunk=self.chunk)


# ---------------------------------------------------------------------------------------------- loading
def detect_form(ckpt: dict) -> str | None:
    """``"neus"``, ``"nsr"`` or None from a loaded checkpoint's keys."""
    if "sdf_network_fine" in ckpt:
        return "neus"
    sd = ckpt.get("state_dict")
    if isinstance(sd, dict) and any(isinstance(k, str) and k.endswith("geometry.encoding.encoding.params")
                                    or k in ("model.variance.variance", "variance.variance") for k in sd):
        return "nsr"
    return None


def _read_cameras(cameras, width, height, nsr_cfg: dict | None):
    """(Cameras or None, scale_mat or None) from a camera-file path (npz or transforms.json) or Cameras."""
    from ..render.cameras import Cameras
    from .neus_cameras import cameras_from_neus_npz

    if cameras is None:
        return None, None
    if isinstance(cameras, Cameras):
        return cameras, None
    path = Path(cameras)
    require(path.is_file(), f"camera file {path} does not exist" if not path.exists() else
            f"camera file {path} is a directory; give cameras_sphere.npz or transforms.json")
    with open(path, "rb") as fh:
        head = fh.read(4)
    if head.startswith(b"PK"):  # npz = zip
        if (width is None or height is None) and nsr_cfg is not None:
            wh = (nsr_cfg.get("dataset") or {}).get("img_wh")
            if isinstance(wh, (list, tuple)) and len(wh) == 2:
                width = wh[0] if width is None else width
                height = wh[1] if height is None else height
        return cameras_from_neus_npz(path, width, height)
    return Cameras.from_transforms(path), None


def with_density(field, density: str = "neus", beta: float | None = None):
    """``field`` itself (``density="neus"``) or its VolSDF Laplace density view (``"laplace"``, kind
    ``"density"``) with ``beta`` in world units (default ``1 / field.inv_s``: the NeuS ramp's width)."""
    from ..scenes.analytic import SDFToDensityField

    require(density in ("neus", "laplace"), f"density must be 'neus' or 'laplace', got {density!r}")
    if density == "neus":
        return field
    beta = 1.0 / float(field.inv_s) if beta is None else float(beta)
    require(beta > 0 and math.isfinite(beta), f"beta must be positive and finite, got {beta}")
    return SDFToDensityField(field, beta)


def load_neus_checkpoint(path, *, cameras=None, config=None, density: str = "neus", width: int | None = None,
                         height: int | None = None, beta: float | None = None, scale_mat=None,
                         background_color=None, bound: str = "sphere", sdf_scale: float = 1.0,
                         chunk: int | None = DEFAULT_CHUNK):
    """Load a NeuS (``.pth``) or instant-nsr-pl (``.ckpt``) checkpoint as a world-frame field.

    Args:
        cameras: path of ``cameras_sphere.npz`` (its scale matrix places the field in the world and its
            cameras are attached) or of a ``transforms.json`` (cameras attached, network frame = world),
            or a :class:`Cameras`; None: network frame = world, no cameras.
        config: instant-nsr-pl only: dict or path of ``parsed.yaml``/JSON (defaults: neus-blender).
        density: ``"neus"`` (kind "sdf", NeuS opacity from ``inv_s``) or ``"laplace"`` (kind "density",
            VolSDF σ with ``beta``).
        width, height: training image size for ``cameras_sphere.npz`` (not stored in it).
        scale_mat: explicit (4, 4) network-to-world similarity (overrides the npz's).
        background_color: (3,), default white. bound, sdf_scale: NeuS only (see :class:`NeuSField`).
    """
    from .checkpoint import load_torch_checkpoint

    ckpt = load_torch_checkpoint(path)
    form = detect_form(ckpt)
    if form is None:
        keys = ", ".join(sorted(str(k) for k in ckpt)[:8])
        raise BadInputError(f"{path} is not a NeuS checkpoint (no 'sdf_network_fine') nor an instant-nsr-pl one "
                            f"(no state_dict with 'model.geometry.encoding.encoding.params'); top-level keys: {keys}")
    if form == "neus":
        require(config is None, "config= is for instant-nsr-pl checkpoints; a NeuS checkpoint needs none")
    nsr_cfg = read_nsr_config(config) if (form == "nsr" and config is not None) else None
    cams, npz_scale = _read_cameras(cameras, width, height, nsr_cfg)
    scale = scale_mat if scale_mat is not None else npz_scale
    source = str(path)
    if form == "neus":
        field = NeuSField(ckpt, scale_mat=scale, sdf_scale=sdf_scale, background_color=background_color,
                          cameras=cams, bound=bound, chunk=chunk, source=source)
    else:
        field = HashGridNeuSField(ckpt["state_dict"], nsr_cfg, scale_mat=scale, background_color=background_color,
                                  cameras=cams, chunk=chunk, source=source)
    return with_density(field, density, beta)
