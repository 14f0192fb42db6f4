"""Pure-PyTorch re-implementation of the tiny-cuda-nn pieces that Instant-NGP and hash-grid NeuS use.

This module owns (docs/formats.md §1.4-§1.6; TCNN encodings/grid.h, common_device.h,
fully_fused_mlp.cu):

* :class:`HashGridConfig`: the multiresolution hash-grid hyper-parameters and the per-level quantities TCNN
  derives from them (scale ``s_l``, vertices per axis ``R_l``, table size ``T_l``, table offsets), computed
  with TCNN's float32 arithmetic so that boundary levels round the same way (L16 at aabb_scale 1:
  ``s_15 = 2046.9987 -> R = 2048``; L8: ``s_7 = 2047.0 -> R = 2048``).
* :class:`HashGridEncoding`: the encoding itself, ``x (N, 3) in [0, 1]^3 -> (N, L*F)``, vectorised over all
  levels and the 8 corners of each cell, differentiable with respect to the table and to ``x``.
* :class:`TcnnMLP`: FullyFusedMLP / CutlassMLP with TCNN's flat parameter layout (no biases, row-major
  ``[out, in]`` matrices, padded input columns and output rows).
* :func:`sh_encode_deg4`: TCNN's degree-4 real spherical harmonics (its constants and signs).
* :func:`ngp_per_level_scale`, :func:`mlp_param_count`, :func:`next_multiple`: the sizes a loader needs to
  split a ``params_binary`` blob.

Frames: hash-grid inputs are points in TCNN network space, the unit cube ``[0, 1]^3`` (for Instant-NGP the
"ngp" frame of §1.8). SH inputs are unit direction vectors ``d`` (not TCNN's ``(d + 1) / 2`` record).

Everything runs in fp32 on CPU or CUDA. TCNN itself interpolates and multiplies in fp16, so outputs agree with
a real TCNN run to about 1e-3 relative, not bitwise (§1.5 item 8).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from ..device import chunk_for_memory
from ..errors import BadInputError, require

BYTES_PER_POINT_LEVEL = 200    # forward temporaries of HashGridEncoding per point and level (measured, float32)
GPU_MAX_CHUNK = 2**21          # points per HashGridEncoding call on a GPU (memory permitting)

__all__ = [
    "HashGridConfig",
    "HashGridEncoding",
    "TcnnMLP",
    "mlp_param_count",
    "next_multiple",
    "ngp_per_level_scale",
    "sh_encode_deg4",
]

# TCNN common_device.h coherent_prime_hash factors for dims 0, 1, 2 (since TCNN d063915, 2022-01-19).
HASH_PRIMES = (1, 2654435761, 805459861)
_U32 = 0xFFFFFFFF
_INTERPOLATIONS = ("Linear", "Smoothstep")


def _f32(v: float) -> float:
    """Round a Python float to the nearest float32 (as a C ``float`` assignment does)."""
    return float(np.float32(v))


def next_multiple(n: int, m: int) -> int:
    """Smallest multiple of ``m`` that is >= ``n`` (TCNN ``next_multiple``), for n >= 0, m >= 1."""
    return (int(n) + int(m) - 1) // int(m) * int(m)


def ngp_per_level_scale(aabb_scale: float, base_resolution: int, n_levels: int) -> float:
    """Instant-NGP's automatic ``per_level_scale`` (INGP testbed.cu ``reset_network``).

    ``b = exp(ln(2048 * aabb_scale / N_min) / (L - 1))`` in float32 arithmetic as INGP does it (``logf``,
    ``expf``, each operation rounded to float32), so the finest level has about 2048 cells per ngp unit.
    Returns 1.0 for a single level (the value is unused then: level 0 does not depend on it).
    """
    require(_is_int(n_levels) and int(n_levels) >= 1, f"n_levels must be an integer >= 1, got {n_levels!r}")
    require(_is_int(base_resolution) and int(base_resolution) >= 1,
            f"base_resolution must be an integer >= 1, got {base_resolution!r}")
    a = float(aabb_scale)
    require(math.isfinite(a) and a > 0, f"aabb_scale must be positive and finite, got {aabb_scale!r}")
    if n_levels == 1:
        return 1.0
    ratio = _f32(_f32(2048.0 * _f32(a)) / _f32(float(base_resolution)))
    return _f32(math.exp(_f32(_f32(math.log(ratio)) / _f32(float(n_levels - 1)))))


def _is_int(v: Any) -> bool:
    if isinstance(v, bool):
        return False
    if isinstance(v, (int, np.integer)):
        return True
    return isinstance(v, (float, np.floating)) and math.isfinite(float(v)) and float(v).is_integer()


def _level_is_hashed(resolution: int, table_size: int) -> bool:
    """TCNN ``grid_index``'s dense-or-hash decision, with its uint32 ``stride`` (overflow included).

    ``stride`` is multiplied by R while ``stride <= T``; the level is hashed iff ``T < stride`` afterwards.
    That equals ``R^3 > T`` except when ``R^3`` wraps around 2^32 (e.g. R = 2048 with log2_hashmap_size 22),
    where TCNN falls back to the (wrapped) dense index; we reproduce that.
    """
    stride = 1
    for _ in range(3):
        if stride > table_size:
            break
        stride = (stride * resolution) & _U32
    return table_size < stride


@dataclass(frozen=True)
class HashGridConfig:
    """Hyper-parameters of a TCNN multiresolution hash grid on 3-D inputs (§1.5)."""

    n_levels: int = 16
    """L, number of resolution levels (1..32)."""
    n_features_per_level: int = 2
    """F, features per level (1, 2, 4 or 8)."""
    log2_hashmap_size: int = 19
    """log2 of the largest table size per level (1..30)."""
    base_resolution: int = 16
    """N_min, vertices per axis of the coarsest level (>= 1)."""
    per_level_scale: float = 2.0
    """b, growth factor of the scale from one level to the next (finite, >= 1); used as float32."""
    interpolation: str = "Linear"
    """"Linear" or "Smoothstep" (weights ``w^2 (3 - 2w)``)."""

    def __post_init__(self) -> None:
        def bad(name: str, value: Any, want: str) -> BadInputError:
            return BadInputError(f"hash grid: {name} must be {want}, got {value!r}")

        if not _is_int(self.n_levels) or not 1 <= int(self.n_levels) <= 32:
            raise bad("n_levels", self.n_levels, "an integer in 1..32")
        if not _is_int(self.n_features_per_level) or int(self.n_features_per_level) not in (1, 2, 4, 8):
            raise bad("n_features_per_level", self.n_features_per_level, "one of 1, 2, 4, 8")
        if not _is_int(self.log2_hashmap_size) or not 1 <= int(self.log2_hashmap_size) <= 30:
            raise bad("log2_hashmap_size", self.log2_hashmap_size, "an integer in 1..30")
        if not _is_int(self.base_resolution) or int(self.base_resolution) < 1:
            raise bad("base_resolution", self.base_resolution, "an integer >= 1")
        try:
            b = float(self.per_level_scale)
        except (TypeError, ValueError):
            raise bad("per_level_scale", self.per_level_scale, "a finite number >= 1") from None
        if not (math.isfinite(b) and b >= 1.0):
            raise bad("per_level_scale", self.per_level_scale, "a finite number >= 1")
        interp = {k.lower(): k for k in _INTERPOLATIONS}.get(str(self.interpolation).lower())
        if interp is None:
            raise bad("interpolation", self.interpolation, f"one of {_INTERPOLATIONS}")
        normalised = (("n_levels", int(self.n_levels)),
                      ("n_features_per_level", int(self.n_features_per_level)),
                      ("log2_hashmap_size", int(self.log2_hashmap_size)),
                      ("base_resolution", int(self.base_resolution)), ("per_level_scale", b),
                      ("interpolation", interp))
        for name, value in normalised:
            object.__setattr__(self, name, value)

    # -- per-level quantities (TCNN grid.h constructor; common_device.h grid_scale / grid_resolution) --------

    def level_scales(self) -> list[float]:
        """``s_l = exp2f(l * log2f(b)) * N_min - 1`` per level, each operation rounded to float32."""
        log2b = _f32(math.log2(_f32(self.per_level_scale)))
        n_min = _f32(float(self.base_resolution))
        return [_f32(_f32(_f32(2.0 ** _f32(level * log2b)) * n_min) - 1.0) for level in range(self.n_levels)]

    def level_resolutions(self) -> list[int]:
        """``R_l = ceil(s_l) + 1``, vertices per axis of each level."""
        return [int(math.ceil(s)) + 1 for s in self.level_scales()]

    def level_sizes(self) -> list[int]:
        """Table entries per level: ``T_l = min(next_multiple(min(R_l^3, 2^31 - 1), 8), 2^log2_T)``."""
        cap = 1 << self.log2_hashmap_size
        return [min(next_multiple(min(r**3, 2**31 - 1), 8), cap) for r in self.level_resolutions()]

    def level_is_hashed(self) -> list[bool]:
        """Per level: True where vertices are hashed, False where the dense (wrapped) index is used."""
        return [_level_is_hashed(r, t) for r, t in zip(self.level_resolutions(), self.level_sizes())]

    def level_offsets(self) -> list[int]:
        """L + 1 cumulative table offsets in entries (multiply by F for parameter offsets)."""
        offsets = [0]
        for t in self.level_sizes():
            offsets.append(offsets[-1] + t)
        return offsets

    def n_params(self) -> int:
        """``F * sum_l T_l``, the length of the flat parameter vector."""
        return self.n_features_per_level * self.level_offsets()[-1]

    def n_output_dims(self) -> int:
        """``L * F``."""
        return self.n_levels * self.n_features_per_level

    @classmethod
    def from_json(cls, enc: dict, *, aabb_scale: float = 1.0) -> "HashGridConfig":
        """Config from a TCNN / Instant-NGP ``encoding`` dict, filling defaults as Instant-NGP does.

        Accepted ``otype``: "HashGrid", or "Grid" with ``type`` "Hash" (case-insensitive, as TCNN). Missing
        keys: n_levels 16, n_features_per_level 2, log2_hashmap_size 19, interpolation "Linear", hash
        "CoherentPrime" (the only hash supported); ``base_resolution`` missing or 0 -> ``1 << (log2 // 3)``
        with log2 = ``log2_hashmap_size`` or 15 if that is missing too (INGP); ``per_level_scale`` missing or
        <= 0 -> :func:`ngp_per_level_scale` with ``aabb_scale`` (INGP; TCNN alone would default to 2.0).
        Everything is validated before any allocation; problems raise :class:`BadInputError` naming the field
        and value.
        """
        require(isinstance(enc, dict), f"hash grid: encoding config must be a dict, got {type(enc).__name__}")
        otype = str(enc.get("otype", "<missing>"))
        kind = otype.lower()
        if kind == "grid":
            gtype = str(enc.get("type", "Hash"))
            require(gtype.lower() == "hash",
                    f"hash grid: encoding otype 'Grid' with type {gtype!r} is not supported "
                    "(only type 'Hash')")
        elif kind != "hashgrid":
            raise BadInputError(f"hash grid: encoding otype {otype!r} is not supported; expected 'HashGrid' "
                                "(or 'Grid' with type 'Hash')")
        hash_type = str(enc.get("hash", "CoherentPrime"))
        require(hash_type.lower() == "coherentprime",
                f"hash grid: hash {hash_type!r} is not supported; only 'CoherentPrime' (the TCNN default)")
        n_pos = enc.get("n_pos_dims", enc.get("n_dims_to_encode", 3))
        require(n_pos == 3, f"hash grid: only 3-D inputs are supported, got n_pos_dims {n_pos!r}")

        n_levels = enc.get("n_levels", 16)
        n_features = enc.get("n_features_per_level", 2)
        log2 = enc.get("log2_hashmap_size", 19)
        interpolation = enc.get("interpolation", "Linear")
        # Validate the integers the derived defaults depend on before using them.
        cls._check_int("n_levels", n_levels, 1, 32)
        cls._check_int("log2_hashmap_size", log2, 1, 30)
        base = enc.get("base_resolution", 0)
        if base is None or (_is_int(base) and int(base) == 0):
            base = 1 << (int(enc.get("log2_hashmap_size", 15)) // 3)
        cls._check_int("base_resolution", base, 1, None)
        b = enc.get("per_level_scale")
        if b is None or (isinstance(b, (int, float)) and not isinstance(b, bool) and b <= 0):
            b = ngp_per_level_scale(aabb_scale, int(base), int(n_levels))
        return cls(n_levels=n_levels, n_features_per_level=n_features, log2_hashmap_size=log2,
                   base_resolution=base, per_level_scale=b, interpolation=interpolation)

    @staticmethod
    def _check_int(name: str, value: Any, lo: int, hi: int | None) -> None:
        ok = _is_int(value) and int(value) >= lo and (hi is None or int(value) <= hi)
        want = f"an integer in {lo}..{hi}" if hi is not None else f"an integer >= {lo}"
        require(ok, f"hash grid: {name} must be {want}, got {value!r}")

    def __repr__(self) -> str:
        return (f"HashGridConfig(L={self.n_levels}, F={self.n_features_per_level}, "
                f"log2_T={self.log2_hashmap_size}, N_min={self.base_resolution}, "
                f"b={self.per_level_scale:.6f}, {self.interpolation}, n_params={self.n_params():,})")


def _flat_params(params, n: int, what: str, hint: str = "") -> torch.Tensor:
    """A detached float32 copy of ``params`` after checking it is a flat (n,) array (BadInputError if not)."""
    if not isinstance(params, torch.Tensor):
        params = torch.as_tensor(np.asarray(params))
    params = params.detach()
    require(params.ndim == 1 and params.numel() == n,
            f"{what}: params must be a flat tensor of {n:,} values{hint}, got shape {tuple(params.shape)}")
    return params.to(torch.float32).clone()


class HashGridEncoding(torch.nn.Module):
    """TCNN multiresolution hash encoding: x (N, 3) in [0, 1]^3 network space -> (N, L*F) float32.

    ``params`` is the flat (n_params,) table in TCNN layout: level l occupies entries
    ``[off_l, off_l + T_l)``, entry e, feature f at ``(off_l + e) * F + f``. Output is level-major
    ``[l0f0, l0f1, ..., l1f0, ...]``.

    Per level (§1.5): ``pos = fmaf(s_l, x, 0.5)`` (computed in float64, then rounded once to float32, which
    equals the fused multiply-add), ``g = floor(pos)``, ``w = pos - g`` (Smoothstep: ``w^2 (3 - 2w)``); corner
    ``g + c`` is indexed densely ``(vx + vy R + vz R^2) mod 2^32 mod T`` or hashed
    ``(vx ^ vy*2654435761 ^ vz*805459861) mod 2^32 mod T``. Points outside the unit cube are not clamped:
    like TCNN they wrap around (uint32 arithmetic) and read valid but meaningless entries.

    All levels of a kind (dense / hashed) are computed at once in a (levels, corners, points) layout, and one
    ``embedding_bag`` per kind gathers and weights the 8 corners. Differentiable with respect to ``params``
    (dense gradient) and ``x``. Evaluates ``chunk_size`` points at a time to bound memory (about 200 bytes per
    point and level in the forward pass; with autograd each chunk's backward also allocates a table-sized
    gradient, so use a larger ``chunk_size`` for training on big tables).

    Examples:
        >>> cfg = HashGridConfig(n_levels=4, log2_hashmap_size=10, base_resolution=4)
        >>> enc = HashGridEncoding(cfg)
        >>> enc(torch.rand(5, 3)).shape
        torch.Size([5, 8])
    """

    def __init__(self, config: HashGridConfig, params: torch.Tensor | None = None, *,
                 chunk_size: int = 2**14):
        super().__init__()
        require(isinstance(config, HashGridConfig),
                f"HashGridEncoding needs a HashGridConfig, got {type(config).__name__}")
        require(int(chunk_size) >= 1, f"chunk_size must be >= 1, got {chunk_size!r}")
        self.config = config
        self.chunk_size = int(chunk_size)
        n = config.n_params()
        if params is None:
            # TCNN grid.h initialize_params: uniform in [-1e-4, 1e-4].
            params = torch.empty(n, dtype=torch.float32).uniform_(-1e-4, 1e-4)
        else:
            params = _flat_params(params, n, f"hash grid {config}", " (F * sum T_l)")
        self.params = torch.nn.Parameter(params)

        scales = config.level_scales()
        res = config.level_resolutions()
        sizes = config.level_sizes()
        offsets = config.level_offsets()
        hashed = config.level_is_hashed()
        # int32 indices unless a dense index before wrapping (< off + 2T) could pass 2^31.
        self._idx_dtype = torch.int32 if offsets[-1] + 2 * max(sizes) < 2**31 else torch.int64
        corners = [(c >> 2 & 1, c >> 1 & 1, c & 1) for c in range(8)]  # corner c = 4 cx + 2 cy + cz
        # Groups = runs of consecutive levels of one kind (normally: dense levels 0..k-1, then hashed ones);
        # each run is evaluated for all its levels at once and the runs are concatenated in level order.
        self._groups: list[tuple[str, str, int, int, bool]] = []
        start = 0
        for lv in range(1, config.n_levels + 1):
            if lv < config.n_levels and hashed[lv] == hashed[start]:
                continue
            levels = list(range(start, lv))
            kind = "hash" if hashed[start] else "dense"
            prefix = f"_g{len(self._groups)}"

            def buf(name: str, values: list, dtype: torch.dtype, prefix: str = prefix) -> None:
                self.register_buffer(prefix + name, torch.tensor(values, dtype=dtype), persistent=False)

            # s_l as float32 bit patterns: integer buffers follow .to(device) but not .half() / .double().
            buf("_scale_bits", np.asarray([scales[k] for k in levels], np.float32).view(np.int32).tolist(),
                torch.int32)
            if kind == "hash":
                t = 1 << config.log2_hashmap_size
                if any(sizes[k] != t for k in levels):
                    raise RuntimeError("internal: a hashed level whose size is not 2^log2_hashmap_size")
                buf("_primes", [p & (t - 1) for p in HASH_PRIMES], torch.int64)
                # The run's tables are consecutive blocks of 2^k entries: the block start j * 2^k has no bits
                # in common with a hash < 2^k, so it can be XOR-ed in with the z term.
                buf("_block", [(k - start) * t for k in levels], torch.int64)
                fast = True
            else:
                strides = [[1, res[k], res[k] ** 2] for k in levels]
                buf("_stride", strides, torch.int64)
                buf("_size", [sizes[k] for k in levels], torch.int64)
                buf("_offset", [offsets[k] for k in levels], torch.int64)
                # Fast path (points inside the cube): corner vertices <= R, so the raw index is below
                # R + R^2 + R^3 < 2 T and one conditional subtraction replaces "mod 2^32 mod T".
                fast = (self._idx_dtype == torch.int32
                        and all(res[k] ** 3 + res[k] ** 2 + res[k] < 2**31 for k in levels))
                buf("_corner", [[offsets[k] + sum(c * st for c, st in zip(cn, strides[i])) for cn in corners]
                                for i, k in enumerate(levels)], torch.int64)
                buf("_limit", [offsets[k] + sizes[k] for k in levels], torch.int64)
            self._groups.append((kind, prefix, offsets[start], offsets[lv], fast))
            start = lv

    @property
    def n_output_dims(self) -> int:
        return self.config.n_output_dims()

    def flat_params(self) -> torch.Tensor:
        """(n_params,) table in TCNN layout, detached (for writing snapshots)."""
        return self.params.detach()

    def extra_repr(self) -> str:
        return f"{self.config!r}, chunk_size={self.chunk_size}"

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x (N, 3) points in [0, 1]^3 -> (N, L*F) features, float32 (float64 if ``params`` is float64)."""
        if not isinstance(x, torch.Tensor) or x.ndim != 2 or x.shape[-1] != 3:
            raise BadInputError(f"hash grid: x must be a (N, 3) tensor, got {tuple(getattr(x, 'shape', ()))}")
        n = x.shape[0]
        x = x.to(self._compute_dtype())  # TCNN reads float32 positions
        # One check (and one device sync) per call: inside the cube (and not NaN) the dense levels may take
        # the int32 fast path.
        inside = n == 0 or bool(((x >= 0) & (x <= 1)).all())
        # on a GPU the chunk grows to what a quarter of free memory holds (up to GPU_MAX_CHUNK): at 2^14 points
        # per chunk the ~100 small kernels of one chunk cost more than their work (26 M points/s on an H100)
        step = chunk_for_memory(self.chunk_size, BYTES_PER_POINT_LEVEL * self.config.n_levels, x.device,
                                max_items=GPU_MAX_CHUNK)
        if n <= step:
            return self._encode(x, inside)
        return torch.cat([self._encode(x[i:i + step], inside) for i in range(0, n, step)])

    def _compute_dtype(self) -> torch.dtype:
        # float64 only for gradcheck-style use; positions and weights of half tables are float32.
        return torch.float64 if self.params.dtype == torch.float64 else torch.float32

    def _encode(self, x: torch.Tensor, inside: bool) -> torch.Tensor:
        n = x.shape[0]
        f = self.config.n_features_per_level
        dtype = self._compute_dtype()
        table = self.params.view(-1, f)  # (total entries, F)
        if table.dtype != torch.float16:      # half tables (precision.half_tables) are gathered in half, as TCNN
            table = table.to(dtype)
        xt = x.to(torch.float64).T  # (3, n)
        outs = []
        for kind, prefix, first, end, fast in self._groups:
            scales = getattr(self, prefix + "_scale_bits").view(torch.float32).to(torch.float64)
            lg = scales.shape[0]
            # (Lg, 3, n): fmaf(s, x, 0.5) -- the product is exact in float64 for float32 inputs, so the one
            # rounding to float32 below gives the fused result.
            pos = xt[None] * scales[:, None, None] + 0.5
            if dtype != torch.float64:
                pos = pos.to(dtype)
            g = torch.floor(pos)
            w = pos - g
            if self.config.interpolation == "Smoothstep":
                w = w * w * (3.0 - 2.0 * w)
            gi = g.detach().to(torch.int64)  # TCNN (uint32_t)(int)floor(pos), taken mod 2^32 below
            if kind == "hash":
                idx, rows = self._hash_index(gi, prefix), table[first:end]
            elif fast and inside:
                idx, rows = self._dense_index_fast(gi, prefix), table
            else:
                idx, rows = self._dense_index_exact(gi, prefix), table
            wp = torch.stack([1.0 - w, w], dim=2)  # (Lg, 3, 2, n): weight of corner bit 0 / 1 per axis
            # (Lg, 2, 2, 2, n): the 8 trilinear weights, corner c = 4 cx + 2 cy + cz
            wt = wp[:, 0, :, None, None] * wp[:, 1, None, :, None] * wp[:, 2, None, None, :]
            # Bags of 8 corners in (level, point) order; one fused gather + weighted sum -> (Lg * n, F).
            bags = idx.reshape(lg, 8, n).transpose(1, 2).reshape(lg * n, 8)
            bag_w = wt.reshape(lg, 8, n).transpose(1, 2).reshape(lg * n, 8)
            outs.append(F.embedding_bag(bags, rows, per_sample_weights=bag_w.to(rows.dtype), mode="sum")
                        .to(dtype).view(lg, n, f))
        out = outs[0] if len(outs) == 1 else torch.cat(outs, dim=0)  # (L, n, F)
        return out.transpose(0, 1).reshape(n, self.config.n_output_dims())

    def _hash_index(self, gi: torch.Tensor, prefix: str) -> torch.Tensor:
        """gi (Lg, 3, n) int64 cell origins -> (Lg, 2, 2, 2, n) corner entries, relative to the run's start.

        ``(v * p) mod 2^32 mod 2^k == ((v mod 2^k) * (p mod 2^k)) mod 2^k``: masking first keeps every
        product below 2^60 (no integer overflow) and handles negative ``gi`` like uint32. The ``+1`` corner
        is ``(v + 1) p = v p + p``, so only (Lg, 3, n) products are formed.
        """
        mask = (1 << self.config.log2_hashmap_size) - 1
        primes = getattr(self, prefix + "_primes")[None, :, None]  # p mod 2^k
        h0 = ((gi & mask) * primes) & mask  # (Lg, 3, n)
        h1 = (h0 + primes) & mask
        t = torch.stack([h0, h1], dim=2)  # (Lg, 3, 2, n)
        t[:, 2] |= getattr(self, prefix + "_block")[:, None, None]  # level block start, see __init__
        t = t.to(self._idx_dtype)
        return t[:, 0, :, None, None] ^ t[:, 1, None, :, None] ^ t[:, 2, None, None, :]

    def _dense_index_fast(self, gi: torch.Tensor, prefix: str) -> torch.Tensor:
        """Dense levels, 0 <= gi <= R - 1: ``off + base + corner`` with one conditional wrap, int32."""
        base = (gi * getattr(self, prefix + "_stride")[:, :, None]).sum(dim=1).to(self._idx_dtype)  # (Lg, n)
        corner = getattr(self, prefix + "_corner").to(self._idx_dtype)  # (Lg, 8): off + c . stride
        idx = base[:, None, :] + corner[:, :, None]  # (Lg, 8, n)
        limit = getattr(self, prefix + "_limit").to(self._idx_dtype)[:, None, None]
        size = getattr(self, prefix + "_size").to(self._idx_dtype)[:, None, None]
        return torch.where(idx >= limit, idx - size, idx)

    def _dense_index_exact(self, gi: torch.Tensor, prefix: str) -> torch.Tensor:
        """Dense levels, any gi: TCNN's ``(vx + vy R + vz R^2) mod 2^32 mod T`` with v = gi + c in uint32."""
        v = torch.stack([gi, gi + 1], dim=2) & _U32  # (Lg, 3, 2, n), < 2^32
        t = v * getattr(self, prefix + "_stride")[:, :, None, None]  # < 2^32 * R^2 <= 2^62
        idx = t[:, 0, :, None, None] + t[:, 1, None, :, None] + t[:, 2, None, None, :]
        idx = (idx & _U32) % getattr(self, prefix + "_size")[:, None, None, None, None]
        return (idx + getattr(self, prefix + "_offset")[:, None, None, None, None]).to(self._idx_dtype)


# ---------------------------------------------------------------------------------------------------------
# MLP


def _mlp_shapes(n_input_dims: int, width: int, n_hidden_layers: int, n_output_dims: int,
                output_alignment: int, input_alignment: int) -> list[tuple[int, int]]:
    checks = (("n_input_dims", n_input_dims, 1), ("width", width, 1), ("n_hidden_layers", n_hidden_layers, 0),
              ("n_output_dims", n_output_dims, 1), ("output_alignment", output_alignment, 1),
              ("input_alignment", input_alignment, 1))
    for name, v, lo in checks:
        require(_is_int(v) and int(v) >= lo, f"tcnn MLP: {name} must be an integer >= {lo}, got {v!r}")
    in_pad = next_multiple(int(n_input_dims), int(input_alignment))
    out_pad = next_multiple(int(n_output_dims), int(output_alignment))
    width, n_hidden_layers = int(width), int(n_hidden_layers)
    if n_hidden_layers == 0:
        return [(out_pad, in_pad)]
    return [(width, in_pad)] + [(width, width)] * (n_hidden_layers - 1) + [(out_pad, width)]


def mlp_param_count(n_input_dims: int, width: int, n_hidden_layers: int, n_output_dims: int,
                    output_alignment: int = 16, input_alignment: int = 16) -> int:
    """Weights of a TCNN MLP: ``width*in_pad + (n_hidden_layers - 1)*width^2 + out_pad*width`` (no biases).

    ``in_pad``/``out_pad`` are the dims rounded up to the alignments (16; 8 for CutlassMLP before TCNN
    f00206e). ``n_hidden_layers = 0`` (CutlassMLP only) is one ``out_pad x in_pad`` matrix.
    """
    shapes = _mlp_shapes(n_input_dims, width, n_hidden_layers, n_output_dims, output_alignment,
                         input_alignment)
    return sum(o * i for o, i in shapes)


class TcnnMLP(torch.nn.Module):
    """TCNN FullyFusedMLP / CutlassMLP: ReLU hidden layers, no biases, raw (linear) output.

    ``params`` is the flat TCNN weight vector: matrices ``[width x in_pad]``, ``(n_hidden_layers - 1) x
    [width x width]``, ``[out_pad x width]``, each row-major ``[out, in]`` (``y = W x``). Inputs are padded
    from ``n_input_dims`` to ``in_pad`` columns holding ``pad_value`` (0 after a grid encoding; 1.0 where
    TCNN's Identity / SH padding feeds ones); output rows beyond ``n_output_dims`` are dropped. Stored as one
    fp32 Parameter ``params`` so that :meth:`flat_params` is the snapshot layout.

    forward(x (N, n_input_dims)) -> (N, n_output_dims).
    """

    def __init__(self, n_input_dims: int, width: int, n_hidden_layers: int, n_output_dims: int,
                 params: torch.Tensor | None = None, output_alignment: int = 16, input_alignment: int = 16,
                 pad_value: float = 0.0):
        super().__init__()
        self.shapes = _mlp_shapes(n_input_dims, width, n_hidden_layers, n_output_dims, output_alignment,
                                  input_alignment)
        self.n_input_dims = int(n_input_dims)
        self.n_output_dims = int(n_output_dims)
        self.width = int(width)
        self.n_hidden_layers = int(n_hidden_layers)
        self.pad_value = float(pad_value)
        n = sum(o * i for o, i in self.shapes)
        if params is None:
            # TCNN initialize_xavier_uniform per matrix.
            chunks = []
            for o, i in self.shapes:
                a = math.sqrt(6.0 / (o + i))
                chunks.append(torch.empty(o * i, dtype=torch.float32).uniform_(-a, a))
            params = torch.cat(chunks)
        else:
            params = _flat_params(params, n, f"tcnn MLP {self._describe()}")
        self.params = torch.nn.Parameter(params)

    def _describe(self) -> str:
        dims = [self.n_input_dims] + [o for o, _ in self.shapes[:-1]] + [self.n_output_dims]
        return " -> ".join(str(v) for v in dims)

    @property
    def n_params(self) -> int:
        return self.params.numel()

    def flat_params(self) -> torch.Tensor:
        """(n_params,) weights in TCNN order, detached (for writing snapshots)."""
        return self.params.detach()

    def matrices(self) -> list[torch.Tensor]:
        """The weight matrices as views ``[out_pad or width, in_pad or width]`` of ``params``."""
        mats, at = [], 0
        for o, i in self.shapes:
            mats.append(self.params[at:at + o * i].view(o, i))
            at += o * i
        return mats

    def extra_repr(self) -> str:
        return (f"{self._describe()}, matrices={self.shapes}, pad_value={self.pad_value}, "
                f"n_params={self.n_params:,}")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x (N, n_input_dims) -> (N, n_output_dims), no output activation."""
        if not isinstance(x, torch.Tensor) or x.ndim != 2 or x.shape[-1] != self.n_input_dims:
            raise BadInputError(f"tcnn MLP: x must be (N, {self.n_input_dims}), "
                                f"got {tuple(getattr(x, 'shape', ()))}")
        mats = self.matrices()
        last = len(mats) - 1
        h = x.to(self.params.dtype)
        for k, w in enumerate(mats):
            if k == last:
                w = w[:self.n_output_dims]  # padded output rows are never read
            if k == 0:
                # Padded input columns hold pad_value: their contribution is a constant bias.
                w_pad = w[:, self.n_input_dims:]
                bias = self.pad_value * w_pad.sum(dim=1) if self.pad_value != 0.0 and w_pad.shape[1] else None
                h = F.linear(h, w[:, :self.n_input_dims], bias)
            else:
                h = F.linear(h, w)
            if k != last:
                h = torch.relu(h)
        return h


# ---------------------------------------------------------------------------------------------------------
# Spherical harmonics


def sh_encode_deg4(d: torch.Tensor) -> torch.Tensor:
    """TCNN SphericalHarmonics, degree 4: d (N, 3) unit directions -> (N, 16), TCNN constants and signs.

    docs/formats.md §1.6; nerfstudio's pure-torch SH uses other signs.

    Evaluated on ``d`` itself (TCNN receives ``(d + 1) / 2`` and maps it back). Not normalised here. Keeps the
    floating dtype of ``d``.
    """
    if not isinstance(d, torch.Tensor) or d.ndim != 2 or d.shape[-1] != 3:
        raise BadInputError(f"sh_encode_deg4: d must be a (N, 3) tensor, "
                            f"got {tuple(getattr(d, 'shape', ()))}")
    if not d.is_floating_point():
        d = d.float()
    x, y, z = d.unbind(-1)
    xy, xz, yz = x * y, x * z, y * z
    x2, y2, z2 = x * x, y * y, z * z
    return torch.stack([
        torch.full_like(x, 0.28209479177387814),
        -0.48860251190291987 * y,
        0.48860251190291987 * z,
        -0.48860251190291987 * x,
        1.0925484305920792 * xy,
        -1.0925484305920792 * yz,
        0.94617469575755997 * z2 - 0.31539156525251999,
        -1.0925484305920792 * xz,
        0.54627421529603959 * (x2 - y2),
        0.59004358992664352 * y * (-3.0 * x2 + y2),
        2.8906114426405538 * xy * z,
        0.45704579946446572 * y * (1.0 - 5.0 * z2),
        0.3731763325901154 * z * (5.0 * z2 - 3.0),
        0.45704579946446572 * x * (1.0 - 5.0 * z2),
        1.4453057213202769 * z * (x2 - y2),
        0.59004358992664352 * x * (-x2 + 3.0 * y2),
    ], dim=-1)
