"""Instant-NGP snapshot files (``.ingp`` = gzip(msgpack), ``.msgpack`` = raw msgpack): read, validate, write.

This module owns the container and the key tree (docs/formats.md §1.1–1.4, §1.9) and is the only
importer of ``msgpack``. :func:`sniff_snapshot` recognises a snapshot from its first bytes (the adapter's
``sniff``); :func:`read_snapshot` turns a file into an :class:`NgpSnapshot` of validated plain numpy arrays
and numbers, or raises one :class:`~neuras_distill.errors.BadInputError` naming the problem. Every size is
checked against the configuration *before* anything is allocated from it, and decompression is capped at a
multiple of the file's size, so memory stays bounded by the file.

:func:`write_snapshot` writes the same layout (used by the test helpers and the fixture trainer).

Layout recap: ``params_binary`` = density MLP, rgb MLP, hash grid, fp16 (``"__half"``) or fp32 (``"float"``);
MLPs bias-free, row-major [out, in], output rows padded to 16 (8 in pre-2022-09 CutlassMLP snapshots, told
apart by the parameter count); ``density_grid_binary`` = fp16 optical thickness, 128^3 per cascade, Morton
order inside a cascade.
"""

from __future__ import annotations

import gzip
import math
import zlib
from dataclasses import dataclass, field as dc_field
from pathlib import Path

import numpy as np

from neuras_distill.components.tcnn import HashGridConfig, mlp_param_count, next_multiple
from neuras_distill.errors import BadInputError, require

#: Decompressed size allowed per byte of file (a real snapshot inflates about 1-20x; a zip bomb far more).
MAX_INFLATION = 256
GRID_SIZE = 128
MODES = ("nerf", "sdf", "image", "volume")
MLP_TYPES = ("FullyFusedMLP", "CutlassMLP", "MLP")
SH_DEGREE = 4
#: Bytes read (and at most inflated) to recognise a snapshot.
SNIFF_BYTES = 1 << 16


@dataclass
class MLPSpec:
    """A bias-free tcnn MLP: ``n_in`` (padded) inputs, ``width`` neurons, ``n_hidden_layers``, ``n_out``
    outputs used, output rows padded to ``output_alignment``."""

    n_in: int
    width: int
    n_hidden_layers: int
    n_out: int
    output_alignment: int = 16

    @property
    def n_params(self) -> int:
        return mlp_param_count(self.n_in, self.width, self.n_hidden_layers, self.n_out,
                               output_alignment=self.output_alignment)


@dataclass
class NgpCamera:
    """One training camera as stored: (3, 4) ngp-space camera-to-world, intrinsics in pixels."""

    c2w_ngp: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    distorted: bool = False


@dataclass
class NgpSnapshot:
    """The validated content of a NeRF snapshot (all arrays float32 numpy, ngp conventions)."""

    grid: HashGridConfig
    density_mlp: MLPSpec
    rgb_mlp: MLPSpec
    density_params: np.ndarray      # (density_mlp.n_params,)
    rgb_params: np.ndarray          # (rgb_mlp.n_params,)
    grid_params: np.ndarray         # (grid.n_params(),)
    aabb_scale: int
    scale: float = 0.33
    offset: tuple = (0.5, 0.5, 0.5)
    from_mitsuba: bool = False
    is_hdr: bool = False
    exposure: float = 0.0
    n_extra_dims: int = 0
    extra_dims: np.ndarray | None = None   # (n_images, n_extra_dims) per-image latents
    density_grid: np.ndarray | None = None  # (cascades, 128, 128, 128) indexed [c, ix, iy, iz], ngp axes
    render_aabb: tuple | None = None        # ((3,), (3,)) ngp space
    background_color: tuple = (0.0, 0.0, 0.0, 0.0)
    cameras: list = dc_field(default_factory=list)
    params_type: str = "__half"
    cutlass_alignment_8: bool = False
    training_step: int | None = None
    notes: list = dc_field(default_factory=list)

    @property
    def dir_pad(self) -> int:
        return next_multiple(SH_DEGREE**2 + self.n_extra_dims, 16)


# ---------------------------------------------------------------------------------------------- reading
def sniff_snapshot_kind(head: bytes) -> str | None:
    """Container guess from the first bytes: "gzip", "zlib", "msgpack" (a map), or None."""
    if head[:2] == b"\x1f\x8b":
        return "gzip"
    if len(head) >= 2 and head[0] == 0x78 and head[1] in (0x01, 0x5E, 0x9C, 0xDA):
        return "zlib"
    if head[:1] and (0x80 <= head[0] <= 0x8F or head[0] in (0xDE, 0xDF)):
        return "msgpack"
    return None


def sniff_snapshot(path) -> bool:
    """Whether ``path`` holds an Instant-NGP NeRF snapshot, from at most its first :data:`SNIFF_BYTES` bytes.

    The container is told by its magic bytes (:func:`sniff_snapshot_kind`); a compressed head is inflated up
    to :data:`SNIFF_BYTES` and must start with a msgpack map. The root map's ``snapshot`` key must appear in
    that head and 3DGRUT's Gaussian-particle ``.ingp`` files (``nre_data``) are not claimed. Never raises
    for unreadable or foreign files (False)."""
    try:
        with open(path, "rb") as f:
            raw = f.read(SNIFF_BYTES)
    except OSError:
        return False
    kind = sniff_snapshot_kind(raw[:4])
    if kind is None:
        return False
    if kind != "msgpack":
        try:
            raw = zlib.decompressobj(16 + 15 if kind == "gzip" else 15).decompress(raw, SNIFF_BYTES)
        except zlib.error:
            return False
        if not raw or not (0x80 <= raw[0] <= 0x8F or raw[0] in (0xDE, 0xDF)):
            return False
    return b"snapshot" in raw and b"nre_data" not in raw


def _inflate(data: bytes, wbits: int, limit: int, path: Path) -> bytes:
    d = zlib.decompressobj(wbits)
    try:
        out = d.decompress(data, limit + 1)
    except zlib.error as exc:
        raise BadInputError(f"{path}: the compressed stream is corrupt ({exc}); re-save the snapshot") from None
    if len(out) > limit:
        raise BadInputError(f"{path}: decompresses to more than {MAX_INFLATION}x its size; "
                            "this is not an Instant-NGP snapshot")
    if not d.eof:
        raise BadInputError(f"{path}: the compressed stream is truncated (the file ends before the data does); "
                            "copy or re-save the snapshot")
    return out


def read_snapshot_tree(path) -> dict:
    """The raw msgpack tree of a snapshot file (decompressed by its magic bytes, not its extension)."""
    path = Path(path)
    require(path.exists(), f"{path} does not exist; give the path of an Instant-NGP snapshot (.ingp/.msgpack)")
    require(path.is_file(), f"{path} is a directory; give the snapshot file (.ingp/.msgpack) inside it")
    data = path.read_bytes()
    require(len(data) > 0, f"{path} is empty; give an Instant-NGP snapshot (.ingp/.msgpack)")
    kind = sniff_snapshot_kind(data[:4])
    limit = MAX_INFLATION * len(data) + (1 << 20)
    if kind == "gzip":
        data = _inflate(data, 16 + 15, limit, path)
    elif kind == "zlib":
        data = _inflate(data, 15, limit, path)
    elif kind is None:
        raise BadInputError(f"{path} is not an Instant-NGP snapshot (neither gzip-compressed nor a msgpack map)")
    import msgpack

    try:
        tree = msgpack.unpackb(data, raw=False, strict_map_key=False)
    except Exception as exc:  # noqa: BLE001 - msgpack raises many types for damaged input
        if kind == "msgpack":  # uncompressed: only the first byte looked like a map, so it may be anything
            raise BadInputError(f"{path} is not an Instant-NGP snapshot, or its msgpack data is damaged "
                                f"({type(exc).__name__}); re-save it from instant-ngp") from None
        raise BadInputError(f"{path}: the snapshot's msgpack data is damaged or truncated "
                            f"({type(exc).__name__}); re-save it from instant-ngp") from None
    require(isinstance(tree, dict), f"{path} holds a msgpack {type(tree).__name__}, not an Instant-NGP snapshot")
    return tree


def read_snapshot(path) -> NgpSnapshot:
    """Read and validate a NeRF snapshot. Raises BadInputError with one line naming the problem."""
    path = Path(path)
    return parse_snapshot(read_snapshot_tree(path), name=str(path))


def _get(d: dict, key: str, default=None):
    return d.get(key, default) if isinstance(d, dict) else default


def _number(value, what: str, name: str, *, integer: bool = False, lo: float | None = None,
            hi: float | None = None) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    if ok:
        ok = math.isfinite(float(value)) and (not integer or float(value) == int(value))
    require(ok, f"{name}: {what} must be a finite {'integer' if integer else 'number'}, got {value!r}")
    v = int(value) if integer else float(value)
    require((lo is None or v >= lo) and (hi is None or v <= hi),
            f"{name}: {what} = {v} is outside [{lo}, {hi}]")
    return v


def _mlp_spec(cfg, n_in: int, n_out: int, which: str, name: str) -> MLPSpec:
    require(isinstance(cfg, dict), f"{name}: the snapshot has no '{which}' network configuration")
    otype = cfg.get("otype", "FullyFusedMLP")
    require(otype in MLP_TYPES, f"{name}: {which} network type {otype!r} is not supported "
                                f"(supported: {', '.join(MLP_TYPES)})")
    act = cfg.get("activation", "ReLU")
    require(act == "ReLU", f"{name}: {which} activation {act!r} is not supported (only ReLU)")
    out_act = cfg.get("output_activation", "None")
    require(out_act == "None", f"{name}: {which} output activation {out_act!r} is not supported (only None)")
    width = _number(cfg.get("n_neurons", 64), f"{which}.n_neurons", name, integer=True, lo=1, hi=1024)
    hidden = _number(cfg.get("n_hidden_layers", 1 if which == "network" else 2), f"{which}.n_hidden_layers",
                     name, integer=True, lo=1, hi=16)
    return MLPSpec(n_in=n_in, width=width, n_hidden_layers=hidden, n_out=n_out)


def _check_dir_encoding(cfg, name: str) -> None:
    if cfg is None:
        return
    require(isinstance(cfg, dict), f"{name}: dir_encoding must be a map")
    nested = cfg.get("nested") if cfg.get("otype") == "Composite" else [cfg]
    require(isinstance(nested, list) and nested, f"{name}: dir_encoding has no nested encodings")
    first = nested[0]
    require(isinstance(first, dict) and first.get("otype") == "SphericalHarmonics",
            f"{name}: direction encoding {first.get('otype') if isinstance(first, dict) else first!r} is not "
            "supported (only SphericalHarmonics, as in every instant-ngp NeRF config)")
    degree = first.get("degree", SH_DEGREE)
    require(degree == SH_DEGREE, f"{name}: spherical-harmonics degree {degree} is not supported (only {SH_DEGREE})")


def parse_snapshot(tree: dict, *, name: str = "snapshot") -> NgpSnapshot:
    """Validate a decoded snapshot tree and slice its parameters (see module docstring)."""
    if "snapshot" not in tree:
        if "nre_data" in tree or "mog_positions" in tree:
            raise BadInputError(f"{name} is a 3DGRUT Gaussian-particle file (it shares the .ingp extension), "
                                "not an Instant-NGP NeRF snapshot")
        raise BadInputError(f"{name} is not an Instant-NGP snapshot: it has no 'snapshot' key "
                            "(a network config without trained state?)")
    snap = tree["snapshot"]
    require(isinstance(snap, dict), f"{name}: 'snapshot' is a {type(snap).__name__}, not a map")
    mode = snap.get("mode", "nerf" if "nerf" in snap else None)
    require(mode is not None, f"{name}: the snapshot has neither 'mode' nor NeRF state; not a NeRF snapshot")
    require(mode == "nerf", f"{name} is an Instant-NGP '{mode}' snapshot; only NeRF snapshots hold a radiance "
                            "field (SDF checkpoints go through from-sdf)" if mode in MODES else
            f"{name}: unknown snapshot mode {mode!r}")
    nerf = snap.get("nerf")
    require(isinstance(nerf, dict), f"{name}: the NeRF snapshot has no 'nerf' section")
    dataset = _get(nerf, "dataset", {}) or {}

    aabb_scale = nerf.get("aabb_scale", _get(dataset, "aabb_scale", 1))
    aabb_scale = _number(aabb_scale, "aabb_scale", name, integer=True, lo=1, hi=128)
    require(aabb_scale & (aabb_scale - 1) == 0, f"{name}: aabb_scale must be a power of two, got {aabb_scale}")

    grid = HashGridConfig.from_json(tree.get("encoding") or {}, aabb_scale=float(aabb_scale))
    _check_dir_encoding(tree.get("dir_encoding"), name)
    n_extra = _number(_get(dataset, "n_extra_learnable_dims", 0), "n_extra_learnable_dims", name,
                      integer=True, lo=0, hi=1024)
    if _get(dataset, "has_light_dirs", False):
        n_extra += 3
    density_cfg = tree.get("network") or {}
    density_out = _number(density_cfg.get("n_output_dims", 16), "network.n_output_dims", name, integer=True,
                          lo=1, hi=1024)
    density = _mlp_spec(density_cfg, next_multiple(grid.n_output_dims(), 16), density_out, "network", name)
    dir_pad = next_multiple(SH_DEGREE**2 + n_extra, 16)
    rgb = _mlp_spec(tree.get("rgb_network") or {}, next_multiple(next_multiple(density_out, 16) + dir_pad, 16),
                    3, "rgb_network", name)

    # ---- parameters: validate every size before allocating anything from them
    params_type = snap.get("params_type", "__half")
    require(params_type in ("__half", "float"), f"{name}: params_type {params_type!r} is not '__half' or 'float'")
    itemsize = 2 if params_type == "__half" else 4
    blob = snap.get("params_binary")
    if isinstance(blob, dict) and "bytes" in blob:  # JSON-converted snapshots keep blobs as byte lists
        blob = bytes(blob["bytes"]) if len(blob["bytes"]) < (1 << 31) else None
    require(blob is not None, f"{name}: the snapshot has no parameters ('params_binary' is missing); "
                              "save it after training")
    require(isinstance(blob, (bytes, bytearray)), f"{name}: 'params_binary' is not binary data")
    n_params = snap.get("n_params")
    require(n_params is not None, f"{name}: the snapshot has no 'n_params'")
    n_params = _number(n_params, "n_params", name, integer=True, lo=0)
    require(n_params * itemsize == len(blob),
            f"{name}: n_params = {n_params} needs {n_params * itemsize} bytes of {params_type} parameters but "
            f"params_binary has {len(blob)}; the file is damaged")
    mlp_total = density.n_params + rgb.n_params
    expected = mlp_total + grid.n_params()
    cutlass8 = False
    if n_params != expected:
        rgb8 = MLPSpec(rgb.n_in, rgb.width, rgb.n_hidden_layers, rgb.n_out, output_alignment=8)
        if n_params == density.n_params + rgb8.n_params + grid.n_params():
            rgb, cutlass8 = rgb8, True
        else:
            raise BadInputError(
                f"{name}: the snapshot has {n_params} parameters but its configuration needs {expected} "
                f"(density MLP {density.n_params}, rgb MLP {rgb.n_params}, hash grid {grid.n_params()} for "
                f"{grid.n_levels} levels x {grid.n_features_per_level} features, 2^{grid.log2_hashmap_size} "
                f"table, aabb_scale {aabb_scale}); the file and its config disagree")
    values = np.frombuffer(blob, dtype="<f2" if itemsize == 2 else "<f4").astype(np.float32)
    bad = ~np.isfinite(values)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        part = ("density MLP" if first < density.n_params else
                "rgb MLP" if first < density.n_params + rgb.n_params else "hash grid")
        raise BadInputError(f"{name}: {int(bad.sum())} parameters are NaN or Inf (first in the {part}); "
                            "the training diverged or the file is damaged")
    d_end = density.n_params
    r_end = d_end + rgb.n_params

    out = NgpSnapshot(grid=grid, density_mlp=density, rgb_mlp=rgb, density_params=values[:d_end],
                      rgb_params=values[d_end:r_end], grid_params=values[r_end:], aabb_scale=aabb_scale,
                      params_type=params_type, cutlass_alignment_8=cutlass8, n_extra_dims=n_extra)
    if cutlass8:
        out.notes.append("rgb MLP output padded to 8 rows (CutlassMLP snapshot from before tiny-cuda-nn 2022-09)")
    out.training_step = snap.get("training_step") if isinstance(snap.get("training_step"), int) else None

    # ---- frame
    out.scale = _number(_get(dataset, "scale", 0.33), "dataset.scale", name, lo=1e-12)
    offset = _get(dataset, "offset", [0.5, 0.5, 0.5])
    if isinstance(offset, (int, float)):
        offset = [offset] * 3
    require(isinstance(offset, (list, tuple)) and len(offset) == 3,
            f"{name}: dataset.offset must be 3 numbers, got {offset!r}")
    out.offset = tuple(_number(o, "dataset.offset", name) for o in offset)
    out.from_mitsuba = bool(_get(dataset, "from_mitsuba", False))
    out.is_hdr = bool(_get(dataset, "is_hdr", False))
    if isinstance(snap.get("exposure"), (int, float)) and math.isfinite(snap["exposure"]):
        out.exposure = float(snap["exposure"])
    bg = snap.get("background_color")
    if isinstance(bg, (list, tuple)) and len(bg) in (3, 4) and all(isinstance(c, (int, float)) for c in bg):
        bg = [float(c) for c in bg] + [1.0] * (4 - len(bg))
        if all(math.isfinite(c) for c in bg):
            out.background_color = tuple(bg)
    out.render_aabb = _box(snap.get("render_aabb"))

    # ---- per-image latents
    if n_extra:
        opts = nerf.get("extra_dims_opt") or []
        lat = []
        for i, opt in enumerate(opts):
            var = _get(opt, "variable")
            require(isinstance(var, list) and len(var) == n_extra,
                    f"{name}: extra_dims_opt[{i}] must hold {n_extra} latent values")
            lat.append(var)
        if lat:
            arr = np.asarray(lat, dtype=np.float32)
            require(bool(np.isfinite(arr).all()), f"{name}: the per-image latent codes contain NaN or Inf")
            out.extra_dims = arr
        else:
            out.notes.append(f"{n_extra} extra input dims but no per-image latents stored; zeros are used")

    # ---- density (occupancy) grid
    out.density_grid = _density_grid(snap, aabb_scale, name, out.notes)

    # ---- cameras
    out.cameras = _cameras(dataset, name, out.notes)
    return out


def _box(value) -> tuple | None:
    if not isinstance(value, dict):
        return None
    lo, hi = value.get("min"), value.get("max")
    try:
        lo, hi = np.asarray(lo, dtype=np.float64).reshape(3), np.asarray(hi, dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        return None
    if not (np.isfinite(lo).all() and np.isfinite(hi).all() and (lo < hi).all()):
        return None
    return tuple(lo.tolist()), tuple(hi.tolist())


def _density_grid(snap: dict, aabb_scale: int, name: str, notes: list) -> np.ndarray | None:
    blob = snap.get("density_grid_binary")
    if blob is None or (isinstance(blob, (bytes, bytearray)) and len(blob) == 0):
        notes.append("no density grid stored; empty space is found by sampling the field")
        return None
    require(isinstance(blob, (bytes, bytearray)), f"{name}: density_grid_binary is not binary data")
    size = snap.get("density_grid_size", GRID_SIZE)
    require(size == GRID_SIZE, f"{name}: density_grid_size {size!r} is not {GRID_SIZE}")
    cells = GRID_SIZE**3
    cascades_needed = max(0, math.ceil(math.log2(aabb_scale))) + 1
    if len(blob) == 2 * cells * cascades_needed:
        grid = np.frombuffer(blob, dtype="<f2").astype(np.float32)
    elif len(blob) == 4 * cells * 8:  # snapshots from before 2022-07: fp32, all 8 cascades
        grid = np.frombuffer(blob, dtype="<f4")[: cells * cascades_needed].astype(np.float32)
    else:
        raise BadInputError(f"{name}: density_grid_binary has {len(blob)} bytes; aabb_scale {aabb_scale} needs "
                            f"{2 * cells * cascades_needed} (fp16, {cascades_needed} cascades of {GRID_SIZE}^3)")
    # fp16 storage turns optical thickness above 65504 into +inf: those are the densest cells, keep them
    grid = np.nan_to_num(grid, nan=0.0, posinf=65504.0, neginf=-1.0).astype(np.float32)
    grid = grid.reshape(cascades_needed, cells)
    return morton_to_xyz(grid)


# ---------------------------------------------------------------------------------------------- morton
def _expand_bits(v: np.ndarray) -> np.ndarray:
    """10-bit integers -> 30-bit integers with two zero bits between each bit (tcnn ``expand_bits``)."""
    v = v.astype(np.uint32)
    v = (v * np.uint32(0x00010001)) & np.uint32(0xFF0000FF)
    v = (v * np.uint32(0x00000101)) & np.uint32(0x0F00F00F)
    v = (v * np.uint32(0x00000011)) & np.uint32(0xC30C30C3)
    v = (v * np.uint32(0x00000005)) & np.uint32(0x49249249)
    return v


def morton3d(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray) -> np.ndarray:
    """Morton code with x in bit 0, y in bit 1, z in bit 2 (tcnn ``morton3D``)."""
    return _expand_bits(ix) | (_expand_bits(iy) << np.uint32(1)) | (_expand_bits(iz) << np.uint32(2))


def _morton_table(n: int = GRID_SIZE) -> np.ndarray:
    i = np.arange(n)
    ix, iy, iz = np.meshgrid(i, i, i, indexing="ij")
    return morton3d(ix, iy, iz).astype(np.int64)  # (n, n, n): [ix, iy, iz] -> Morton index


def morton_to_xyz(grid: np.ndarray) -> np.ndarray:
    """(C, 128^3) cascades in Morton order -> (C, 128, 128, 128) indexed [c, ix, iy, iz]."""
    table = _morton_table(GRID_SIZE)
    return np.stack([g[table] for g in grid])


def xyz_to_morton(grid: np.ndarray) -> np.ndarray:
    """(C, 128, 128, 128) [c, ix, iy, iz] -> (C, 128^3) in Morton order."""
    table = _morton_table(GRID_SIZE).reshape(-1)
    out = np.empty((grid.shape[0], GRID_SIZE**3), dtype=grid.dtype)
    for c in range(grid.shape[0]):
        out[c, table] = grid[c].reshape(-1)
    return out


# ---------------------------------------------------------------------------------------------- cameras
def _cameras(dataset: dict, name: str, notes: list) -> list:
    meta, xforms = _get(dataset, "metadata"), _get(dataset, "xforms")
    if not isinstance(meta, list) or not isinstance(xforms, list) or not meta:
        return []
    if len(meta) != len(xforms):
        notes.append(f"dataset has {len(meta)} metadata entries but {len(xforms)} poses; cameras not used")
        return []
    cams = []
    for i, (m, x) in enumerate(zip(meta, xforms)):
        try:
            mat = np.asarray(_get(x, "start", x), dtype=np.float64)
            if mat.shape == (4, 3):  # column-major serialisation of some older builds
                mat = mat.T
            mat = mat.reshape(3, 4)
            fx, fy = (float(v) for v in m["focal_length"])
            w, h = (int(v) for v in m["resolution"])
            px, py = (float(v) for v in m.get("principal_point", [0.5, 0.5]))
        except (KeyError, TypeError, ValueError):
            notes.append(f"training camera {i} is malformed; stored cameras not used")
            return []
        if not (np.isfinite(mat).all() and fx > 0 and fy > 0 and w > 0 and h > 0):
            notes.append(f"training camera {i} has invalid values; stored cameras not used")
            return []
        lens = m.get("lens") or {}
        distorted = any(isinstance(v, (int, float)) and not isinstance(v, bool) and v != 0
                        for k, v in lens.items()) or any(bool(lens.get(k)) for k in
                                                         ("is_fisheye", "latlong", "equirectangular", "orthographic"))
        cams.append(NgpCamera(mat, fx, fy, px * w, py * h, w, h, distorted))
    if any(c.distorted for c in cams):
        notes.append("training cameras have lens distortion; neuras-distill renders undistorted pinhole views")
    return cams


# ---------------------------------------------------------------------------------------------- writing
def build_snapshot_tree(*, grid: HashGridConfig, density_params: np.ndarray, rgb_params: np.ndarray,
                        grid_params: np.ndarray, aabb_scale: int, network: dict | None = None,
                        rgb_network: dict | None = None, params_type: str = "__half",
                        scale: float = 0.33, offset=(0.5, 0.5, 0.5), density_grid: np.ndarray | None = None,
                        cameras: list | None = None, background_color=(0.0, 0.0, 0.0, 1.0),
                        is_hdr: bool = False, n_extra_dims: int = 0, extra_dims: np.ndarray | None = None,
                        write_per_level_scale: bool = True, render_aabb=None, from_mitsuba: bool = False,
                        training_step: int = 0) -> dict:
    """A snapshot tree in instant-ngp's layout (§1.2). ``density_grid`` is (C, 128, 128, 128) [c, ix, iy, iz]
    optical thickness; ``cameras`` a list of :class:`NgpCamera`."""
    network = dict(network or {"otype": "FullyFusedMLP", "activation": "ReLU", "output_activation": "None",
                               "n_neurons": 64, "n_hidden_layers": 1})
    rgb_network = dict(rgb_network or {"otype": "FullyFusedMLP", "activation": "ReLU",
                                       "output_activation": "None", "n_neurons": 64, "n_hidden_layers": 2})
    encoding = {"otype": "HashGrid", "n_levels": grid.n_levels, "n_features_per_level": grid.n_features_per_level,
                "log2_hashmap_size": grid.log2_hashmap_size, "base_resolution": grid.base_resolution}
    if grid.interpolation != "Linear":
        encoding["interpolation"] = grid.interpolation
    if write_per_level_scale:
        encoding["per_level_scale"] = grid.per_level_scale
    dtype = "<f2" if params_type == "__half" else "<f4"
    params = np.concatenate([np.asarray(a, np.float32).reshape(-1)
                             for a in (density_params, rgb_params, grid_params)]).astype(dtype)
    cams = cameras or []
    dataset = {
        "n_images": len(cams), "paths": [f"images/{i:04d}.png" for i in range(len(cams))],
        "metadata": [{"focal_length": [c.fx, c.fy], "lens": {"is_fisheye": False, "k1": 0.0, "k2": 0.0,
                                                             "p1": 0.0, "p2": 0.0},
                      "principal_point": [c.cx / c.width, c.cy / c.height], "rolling_shutter": [0.0] * 4,
                      "resolution": [c.width, c.height]} for c in cams],
        "xforms": [{"start": np.asarray(c.c2w_ngp, np.float64).reshape(3, 4).tolist(),
                    "end": np.asarray(c.c2w_ngp, np.float64).reshape(3, 4).tolist()} for c in cams],
        "render_aabb": {"min": [0.0] * 3, "max": [1.0] * 3}, "up": [0.0, 1.0, 0.0],
        "offset": [float(o) for o in offset], "scale": float(scale), "aabb_scale": int(aabb_scale),
        "from_mitsuba": bool(from_mitsuba), "is_hdr": bool(is_hdr), "wants_importance_sampling": True,
        "n_extra_learnable_dims": int(n_extra_dims), "envmap_resolution": [0, 0],
    }
    half = 0.5 * aabb_scale
    snap = {
        "n_params": int(params.size), "params_type": params_type, "params_binary": params.tobytes(),
        "version": 1, "mode": "nerf", "density_grid_size": GRID_SIZE,
        "nerf": {"aabb_scale": int(aabb_scale), "cam_pos_offset": {}, "cam_rot_offset": {},
                 "extra_dims_opt": [{"iter": 0, "first_moment": [0.0] * n_extra_dims,
                                     "second_moment": [0.0] * n_extra_dims, "variable": [float(v) for v in row],
                                     "learning_rate": 1e-3, "epsilon": 1e-8, "beta1": 0.9, "beta2": 0.99}
                                    for row in (extra_dims if extra_dims is not None else [])],
                 "rgb": {"rays_per_batch": 4096, "measured_batch_size": 0,
                         "measured_batch_size_before_compaction": 0},
                 "dataset": dataset},
        "training_step": int(training_step), "loss": 0.0,
        "aabb": {"min": [0.5 - half] * 3, "max": [0.5 + half] * 3}, "bounding_radius": 1.0,
        "render_aabb_to_local": np.eye(3).tolist(),
        "render_aabb": ({"min": list(render_aabb[0]), "max": list(render_aabb[1])} if render_aabb is not None
                        else {"min": [0.5 - half] * 3, "max": [0.5 + half] * 3}),
        "up_dir": [0.0, 1.0, 0.0], "sun_dir": [0.0, 1.0, 0.0], "exposure": 0.0,
        "background_color": [float(c) for c in background_color],
        "camera": {"matrix": np.eye(4)[:3].tolist(), "fov_axis": 1, "relative_focal_length": [1.0, 1.0],
                   "screen_center": [0.5, 0.5], "zoom": 1.0, "scale": 1.0, "aperture_size": 0.0,
                   "autofocus": False, "autofocus_target": [0.5, 0.5], "autofocus_depth": 0.5},
    }
    if density_grid is not None:
        snap["density_grid_binary"] = xyz_to_morton(np.asarray(density_grid, np.float32)).astype("<f2").tobytes()
    return {"loss": {"otype": "Huber"}, "optimizer": {"otype": "Ema", "decay": 0.95},
            "encoding": encoding, "network": network,
            "dir_encoding": {"otype": "Composite", "nested": [{"n_dims_to_encode": 3,
                                                               "otype": "SphericalHarmonics", "degree": 4},
                                                              {"otype": "Identity"}]},
            "rgb_network": rgb_network, "snapshot": snap}


def write_snapshot(path, tree: dict, *, compress: bool = True) -> Path:
    """Write ``tree`` as ``.ingp`` (gzip, ``compress``) or raw ``.msgpack`` bytes; returns the path."""
    import msgpack

    path = Path(path)
    data = msgpack.packb(tree, use_bin_type=True)
    if compress:
        data = gzip.compress(data, compresslevel=9, mtime=0)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    tmp.replace(path)
    return path
