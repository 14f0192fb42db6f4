"""Network pieces the NeuS-family readers share: NeuS's positional encoding, ``nn.Linear`` weights read from a
state dict (plain or weight-normalised, shapes validated), MLP evaluation, activations by name."""

from __future__ import annotations

import re
from typing import Any, Callable

import torch
import torch.nn.functional as F

from neuras_distill.errors import BadInputError, require

SOFTPLUS_BETA = 100.0


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


def shape_of(t: Any) -> tuple:
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
        require(v.ndim == 2, f"{source}: {kv!r} should be a matrix (out, in), got shape {shape_of(v)}")
        out = v.shape[0]
        require(tuple(g.shape) in ((out, 1), (out,)),
                f"{source}: {kg!r} has shape {shape_of(g)}, expected ({out}, 1) to match {kv!r} {shape_of(v)}")
        v64 = v.double()
        norm = v64.norm(dim=1, keepdim=True)
        require(bool((norm > 0).all()), f"{source}: {kv!r} has an all-zero row; weight norm is undefined")
        w = (g.double().reshape(out, 1) * v64 / norm).float()
        break
    if w is None:
        plain = get(f"{prefix}.weight")
        require(plain is not None, f"{source}: missing weights of layer {prefix!r} (expected {prefix}.weight_g/"
                                   f"weight_v, {prefix}.parametrizations.weight.original0/1 or {prefix}.weight)")
        require(plain.ndim == 2,
                f"{source}: {prefix + '.weight'!r} should be a matrix (out, in), got {shape_of(plain)}")
        w = plain.float()
    b = get(f"{prefix}.bias")
    if b is not None:
        require(tuple(b.shape) == (w.shape[0],),
                f"{source}: {prefix + '.bias'!r} has shape {shape_of(b)}, expected ({w.shape[0]},)")
        b = b.float()
    return w, b


def layer_indices(sd: dict, pattern: str, source: str, what: str) -> list[int]:
    rx = re.compile(pattern)
    ids = sorted({int(m.group(1)) for k in sd if isinstance(k, str) and (m := rx.match(k))})
    require(ids, f"{source}: no {what} layers found (keys like {pattern.replace(chr(92), '')!r})")
    return ids

def softplus100(x: torch.Tensor) -> torch.Tensor:
    return F.softplus(x, beta=SOFTPLUS_BETA)


def run_mlp(h: torch.Tensor, layers, act) -> torch.Tensor:
    """``h`` through ``layers`` [(weight, bias or None), ...] with ``act`` between layers (not after the last)."""
    last = len(layers) - 1
    for k, (w, b) in enumerate(layers):
        h = F.linear(h, w, b)
        if k < last:
            h = act(h)
    return h

def find_entry(sd: dict, *names: str) -> tuple[str, torch.Tensor] | tuple[None, None]:
    for n in names:
        if n in sd:
            return n, sd[n]
    return None, None


def activation(name, where: str) -> Callable[[torch.Tensor], torch.Tensor]:
    n = "none" if name is None else str(name).lower()
    table = {"none": lambda x: x, "relu": torch.relu, "sigmoid": torch.sigmoid, "softplus": F.softplus,
             "tanh": torch.tanh}
    require(n in table, f"{where}: activation {name!r} is not supported ({', '.join(table)})")
    return table[n]

