"""Safe reading of PyTorch checkpoints (``torch.save`` files): the one place that calls ``torch.load``.

This module owns:

* :func:`load_torch_checkpoint`: ``torch.load(path, weights_only=True, map_location="cpu")`` behind checks
  that turn every failure into one clear :class:`~neuras_distill.errors.BadInputError` line. A checkpoint
  may hold tensors, numbers, strings and plain containers only; a pickle that references any other global
  (a class, a function such as ``os.system``) is refused *without executing it* (the weights-only
  unpickler never imports or calls what it is not allowed to).
* :func:`inspect_torch_zip`: the zip directory of a checkpoint and its small ``data.pkl``, read without
  loading any tensor (used by adapters' ``sniff``).
* :func:`check_finite`: every floating tensor of a (nested) state dict is finite, else an error naming the key.

Memory is bounded by the file size: only the zip format (``torch.save``'s default since PyTorch 1.6) is
read, every member must be stored uncompressed (as ``torch.save`` writes it) and lie inside the file, so no
size announced in a header is allocated before the bytes are seen. The legacy pre-1.6 format, TorchScript
archives and compressed members are refused with a message saying so.
"""

from __future__ import annotations

import re
import zipfile
from pathlib import Path
from typing import Any, Iterator

import torch

from ..errors import BadInputError

ZIP_MAGIC = b"PK\x03\x04"
LEGACY_MAGIC = b"\x80\x02\x8a\x0al\xfc\x9cF\xf9 j\xa8P\x19"  # pickle proto 2 + torch's legacy magic number
MAX_PICKLE_BYTES = 64 * 2**20  # data.pkl larger than this is not a checkpoint of weights


def _zip_members(path: Path, size: int) -> tuple[zipfile.ZipFile, zipfile.ZipInfo]:
    """Open ``path`` as a torch zip checkpoint, validate its directory, return (zip, data.pkl member)."""
    try:
        zf = zipfile.ZipFile(path)
    except zipfile.BadZipFile:
        raise BadInputError(f"{path} is truncated or damaged: it starts like a PyTorch checkpoint (zip) but "
                            "its zip directory is missing; copy or re-save the file again") from None
    except OSError as exc:
        raise BadInputError(f"{path} cannot be read: {exc.strerror or exc}") from None
    try:
        infos = zf.infolist()
        names = [i.filename for i in infos]
        pkl = [i for i in infos if i.filename.endswith("data.pkl") and i.filename.count("/") == 1]
        if any(n.endswith("/constants.pkl") for n in names):
            raise BadInputError(f"{path} is a TorchScript archive (torch.jit.save), not a checkpoint of weights; "
                                "give the training checkpoint (torch.save of a state dict)")
        if len(pkl) != 1:
            raise BadInputError(f"{path} is a zip file but not a PyTorch checkpoint (no single <name>/data.pkl "
                                f"inside; members: {', '.join(names[:5])}{'...' if len(names) > 5 else ''})")
        for info in infos:
            if info.compress_type != zipfile.ZIP_STORED or info.file_size != info.compress_size:
                raise BadInputError(f"{path}: member {info.filename} is compressed; torch.save never compresses, "
                                    "so this is not a plain PyTorch checkpoint (unzip and re-save it with torch.save)")
            if info.header_offset + info.compress_size > size:
                raise BadInputError(f"{path} is truncated: member {info.filename} extends past the end of the file")
        if pkl[0].file_size > MAX_PICKLE_BYTES:
            raise BadInputError(f"{path}: its pickle (data.pkl) is {pkl[0].file_size} bytes; a checkpoint of weights "
                                f"has a small one (< {MAX_PICKLE_BYTES // 2**20} MiB)")
    except BaseException:
        zf.close()
        raise
    return zf, pkl[0]


def _check_path(path) -> tuple[Path, int]:
    path = Path(path)
    if not path.exists():
        raise BadInputError(f"{path} does not exist; give the path of the checkpoint file")
    if path.is_dir():
        raise BadInputError(f"{path} is a directory; give the checkpoint file inside it (e.g. ckpt_300000.pth)")
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise BadInputError(f"{path} cannot be read: {exc.strerror or exc}") from None
    if size == 0:
        raise BadInputError(f"{path} is empty (0 bytes); the checkpoint was not written completely")
    return path, size


def _read_head(path: Path, n: int = 16) -> bytes:
    try:
        with open(path, "rb") as fh:
            return fh.read(n)
    except OSError as exc:
        raise BadInputError(f"{path} cannot be read: {exc.strerror or exc}") from None


def inspect_torch_zip(path) -> tuple[list[str], bytes]:
    """(member names, raw bytes of data.pkl) of a zip-format torch checkpoint, no tensor loaded.

    Raises :class:`BadInputError` when ``path`` is not a readable zip-format torch checkpoint.
    """
    path, size = _check_path(path)
    if _read_head(path, 4) != ZIP_MAGIC:
        raise BadInputError(f"{path} is not a zip-format PyTorch checkpoint")
    zf, pkl = _zip_members(path, size)
    with zf:
        return [i.filename for i in zf.infolist()], zf.read(pkl)


#: Pickle globals a checkpoint may hold besides tensors and containers when the caller allows numpy scalars
#: (nerfstudio's learning-rate scheduler leaves ``numpy.float64`` learning rates in the optimizer state): the
#: name the pickle uses -> the object it stands for. Nothing outside this table is ever imported.
NUMPY_SCALAR_GLOBALS = ("numpy.core.multiarray.scalar", "numpy._core.multiarray.scalar", "numpy.dtype",
                        "numpy.dtypes.Float64DType", "numpy.dtypes.Float32DType", "numpy.dtypes.Int64DType",
                        "_codecs.encode")


def _numpy_scalar_global(name: str):
    import codecs

    import numpy as np

    if name.endswith("multiarray.scalar"):
        core = getattr(np, "_core", None) or np.core
        return core.multiarray.scalar
    if name == "numpy.dtype":
        return np.dtype
    if name == "_codecs.encode":
        return codecs.encode
    return getattr(np.dtypes, name.rsplit(".", 1)[-1])


def _resolves(name: str) -> bool:
    try:
        _numpy_scalar_global(name)
        return True
    except AttributeError:
        return False


def load_torch_checkpoint(path, *, numpy_scalars: bool = False) -> dict:
    """Load a ``torch.save`` checkpoint safely: weights only, onto the CPU.

    Returns the top-level dict. Raises :class:`BadInputError` (one line: what is wrong, what to do) for a
    missing path, a directory, an empty, truncated or foreign file, the legacy or TorchScript formats, a
    top level that is not a dict, and pickles that need more than tensors and plain containers (those are
    never executed). ``numpy_scalars``: also allow the numpy scalar and dtype globals of
    :data:`NUMPY_SCALAR_GLOBALS` (the file's globals are listed first; any other one is refused by name).
    """
    path, size = _check_path(path)
    head = _read_head(path, 16)
    if head.startswith(LEGACY_MAGIC[:2]) and LEGACY_MAGIC[2:] in head:
        raise BadInputError(f"{path} uses PyTorch's legacy serialization (before PyTorch 1.6), which cannot be "
                            "read with bounded memory; re-save it with a current PyTorch (torch.save)")
    if not head.startswith(ZIP_MAGIC):
        raise BadInputError(f"{path} is not a PyTorch checkpoint (unrecognised content, first bytes {head[:8]!r}); "
                            "give the .pth/.ckpt file written by torch.save")
    zf, _ = _zip_members(path, size)
    zf.close()
    allowed = []
    if numpy_scalars:
        try:
            found = torch.serialization.get_unsafe_globals_in_checkpoint(path)
        except Exception as exc:  # noqa: BLE001 - a file whose pickle cannot even be listed is damaged
            raise BadInputError(_describe_load_error(path, exc)) from None
        other = [g for g in found if g not in NUMPY_SCALAR_GLOBALS]
        if other:
            raise BadInputError(f"{path} needs more than tensors, numbers and numpy scalars (found {other[0]}); "
                                "it was not loaded, because loading it would run code from the file")
        # all of the table (the dtype classes are reached through numpy.dtype and are not listed on their own)
        allowed = [(_numpy_scalar_global(g), g) for g in NUMPY_SCALAR_GLOBALS if _resolves(g)]
    try:
        with torch.serialization.safe_globals(allowed):
            obj = torch.load(path, weights_only=True, map_location="cpu")
    except Exception as exc:  # noqa: BLE001 - every failure of a foreign file is the user's input problem
        raise BadInputError(_describe_load_error(path, exc)) from None
    if not isinstance(obj, dict):
        raise BadInputError(f"{path} holds a {type(obj).__name__}, not a dict of weights; expected a training "
                            "checkpoint (a dict with the network state dicts)")
    return obj


_GLOBAL_RE = re.compile(r"GLOBAL ([A-Za-z_][\w.]*)")


def _describe_load_error(path: Path, exc: Exception) -> str:
    text = str(exc)
    found = _GLOBAL_RE.search(text)
    if found:
        return (f"{path} needs more than tensors and plain containers (found {found.group(1)}); it was not "
                "loaded, because loading it would run code from the file. Re-save only the state dicts "
                "(tensors, numbers, strings, dicts, lists)")
    first = text.strip().splitlines()[0] if text.strip() else type(exc).__name__
    if "weights only load failed" in text.lower() or "unpickl" in text.lower():
        return (f"{path} needs more than tensors and plain containers ({first[:160]}); it was not loaded. "
                "Re-save only the state dicts")
    if isinstance(exc, (EOFError, zipfile.BadZipFile)) or "zip archive" in text or "PytorchStreamReader" in text:
        return f"{path} is truncated or damaged ({first[:160]}); copy or re-save the checkpoint"
    return f"{path} could not be read as a PyTorch checkpoint: {type(exc).__name__}: {first[:200]}"


# ------------------------------------------------------------------------------------------ contents
def iter_tensors(obj: Any, prefix: str = "") -> Iterator[tuple[str, torch.Tensor]]:
    """(dotted key, tensor) for every tensor in nested dicts / lists / tuples."""
    if isinstance(obj, torch.Tensor):
        yield prefix, obj
    elif isinstance(obj, dict):
        for k, v in obj.items():
            yield from iter_tensors(v, f"{prefix}.{k}" if prefix else str(k))
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            yield from iter_tensors(v, f"{prefix}.{i}" if prefix else str(i))


def check_finite(obj: Any, source: str = "checkpoint") -> None:
    """Raise :class:`BadInputError` naming the first floating tensor of ``obj`` with NaN or Inf values."""
    for key, t in iter_tensors(obj):
        if t.is_floating_point() or t.is_complex():
            finite = torch.isfinite(t)
            if not bool(finite.all()):
                bad = int((~finite).sum())
                raise BadInputError(f"{source}: weights {key!r} contain NaN or Inf ({bad} of {t.numel()} values); "
                                    "the training diverged or the file is damaged; use an earlier checkpoint")
