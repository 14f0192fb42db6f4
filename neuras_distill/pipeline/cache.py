"""The run's work area: every stage's outputs stored under a key, reused when the same inputs come again.

A key is a digest of exactly what a stage's outputs depend on (:func:`digest`): the field's fingerprint
(:func:`field_fingerprint`), the cameras, the stage's own settings, the keys of the stages upstream of it
and the package version. A stored stage is a folder ``<work>/<stage>/<key>/`` holding its files and a
``done.json`` written last, with the size and SHA-256 of every file: a folder without ``done.json`` (a
killed run) or whose files do not match it (truncated, edited) is not reused; it is recomputed and one line
says why. Stages are written into a temporary sibling and renamed into place, so a kill never leaves a
half-written stage that looks finished.

Only our own files are read back, and only as plain arrays (``np.load(allow_pickle=False)``), JSON, or
tensors (``torch.load(weights_only=True)``): nothing in a work area is unpickled.

Several work areas may be searched (the run's own, then the previous run folder's ``work/``): a stage found
in another one is hard-linked (or copied) into the run's own.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from .. import __version__
from ..logs import say

#: Written last into a finished stage folder: {"stage", "key", "version", "files": {name: {bytes, sha256}}}.
DONE = "done.json"


def _feed(h, obj: Any, seen: set, depth: int) -> None:
    """Feed a canonical byte form of ``obj`` into the hash ``h`` (tensors and arrays by dtype, shape and bytes)."""
    if depth > 6:
        h.update(b"<deep>")
        return
    if obj is None or isinstance(obj, (bool, int, float, str)):
        h.update(json.dumps(obj).encode())
    elif isinstance(obj, bytes):
        h.update(b"b%d:" % len(obj) + obj)
    elif torch.is_tensor(obj):
        t = obj.detach().cpu().contiguous()
        h.update(f"T{t.dtype}{tuple(t.shape)}".encode())
        h.update(t.view(torch.uint8).numpy().tobytes() if t.numel() else b"")
    elif isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        h.update(f"A{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes() if a.dtype != object else repr(a.tolist()).encode())
    elif isinstance(obj, np.generic):
        _feed(h, obj.item(), seen, depth)
    elif isinstance(obj, dict):
        h.update(b"{")
        for k in sorted(obj, key=str):
            h.update(str(k).encode() + b":")
            _feed(h, obj[k], seen, depth + 1)
        h.update(b"}")
    elif isinstance(obj, (list, tuple)):
        h.update(b"[")
        for v in obj:
            _feed(h, v, seen, depth + 1)
        h.update(b"]")
    elif isinstance(obj, Path):
        h.update(str(obj).encode())
    elif callable(obj) and not hasattr(obj, "__dict__"):
        h.update(getattr(obj, "__qualname__", type(obj).__qualname__).encode())
    else:                                   # an object: its class and its state (modules: parameters and buffers)
        if id(obj) in seen:
            h.update(b"<seen>")
            return
        seen.add(id(obj))
        h.update(f"{type(obj).__module__}.{type(obj).__qualname__}".encode())
        if isinstance(obj, torch.nn.Module):
            _feed(h, dict(obj.state_dict()), seen, depth + 1)
        to_json = getattr(obj, "to_json", None)
        if callable(to_json) and not isinstance(obj, torch.nn.Module):
            try:
                _feed(h, to_json(), seen, depth + 1)
                return
            except Exception:                           # noqa: BLE001 - fall back to the attributes
                pass
        state = getattr(obj, "__dict__", None)
        if state is not None:
            _feed(h, {k: v for k, v in state.items()
                      if not k.startswith("_") and (isinstance(v, torch.nn.Module) or not callable(v))},
                  seen, depth + 1)


def digest(*parts: Any) -> str:
    """SHA-256 (hex, 24 characters) of ``parts`` and the package version: dicts in key order, tensors and
    arrays by dtype, shape and bytes, other objects by class and attributes."""
    h = hashlib.sha256(__version__.encode())
    for part in parts:
        _feed(h, part, set(), 0)
    return h.hexdigest()[:24]


def field_fingerprint(field) -> str:
    """What identifies a field: its ``source_digest`` when the loader set one (the checkpoint file's SHA-256
    and the load options), else its class and state (parameters, buffers, public attributes)."""
    source = getattr(field, "source_digest", None)
    if isinstance(source, str) and source:
        return digest("source", type(field).__qualname__, source)
    return digest("state", field)


def file_sha256(path: Path, chunk: int = 1 << 22) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


class StageCache:
    """Stored stages in ``work`` (written) and ``extra`` work areas (read, e.g. the previous run's).

    Args:
        work: this run's work area (created when a stage is stored).
        extra: other work areas to reuse from (missing ones are ignored).
        fresh: ignore everything stored (``--fresh``); stages are still stored.
        log: one-line messages (reuse, recompute and why).
    """

    def __init__(self, work: Path, extra: list[Path] | None = None, *, fresh: bool = False, log=say):
        self.work, self.extra, self.fresh, self.log = Path(work), [Path(p) for p in extra or []], fresh, log
        self.reused: list[str] = []

    def folder(self, stage: str, key: str) -> Path:
        return self.work / stage / key

    def _valid(self, folder: Path) -> tuple[bool, str]:
        done = folder / DONE
        if not done.is_file():
            return False, "unfinished"
        try:
            info = json.loads(done.read_text())
            files = info["files"]
        except (OSError, ValueError, KeyError, TypeError):
            return False, "its done.json is unreadable"
        if info.get("version") != __version__:
            return False, f"written by version {info.get('version')}"
        for name, meta in files.items():
            path = folder / name
            if not path.is_file() or path.stat().st_size != meta.get("bytes"):
                return False, f"{name} is missing or truncated"
            if file_sha256(path) != meta.get("sha256"):
                return False, f"{name} does not match its checksum"
        return True, ""

    def lookup(self, stage: str, key: str) -> Path | None:
        """The folder of a valid stored ``stage`` under ``key`` in this run's work area (linked in from another
        work area when found there), or None. An invalid one is removed and named in the log."""
        if self.fresh:
            return None
        own = self.folder(stage, key)
        if own.exists():
            ok, why = self._valid(own)
            if ok:
                return own
            if why != "unfinished":
                self.log(f"stored {stage} stage {key} is not reused ({why}); recomputing it")
            shutil.rmtree(own, ignore_errors=True)
        for area in self.extra:
            other = area / stage / key
            if other.is_dir() and self._valid(other)[0]:
                tmp = own.parent / f".{key}.link-{os.getpid()}"
                shutil.rmtree(tmp, ignore_errors=True)
                tmp.mkdir(parents=True)
                for path in other.iterdir():
                    if path.is_file():
                        try:
                            os.link(path, tmp / path.name)
                        except OSError:
                            shutil.copy2(path, tmp / path.name)
                os.replace(tmp, own)
                return own
        return None

    def store(self, stage: str, key: str, write: Callable[[Path], None]) -> Path:
        """Run ``write(folder)`` into a temporary folder, record its files in ``done.json``, and rename it into
        place as ``<work>/<stage>/<key>``. Returns the final folder."""
        final = self.folder(stage, key)
        tmp = final.parent / f".{key}.tmp-{os.getpid()}"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        write(tmp)
        files = {p.name: {"bytes": p.stat().st_size, "sha256": file_sha256(p)}
                 for p in sorted(tmp.iterdir()) if p.is_file()}
        (tmp / DONE).write_text(json.dumps({"stage": stage, "key": key, "version": __version__, "files": files},
                                           indent=1))
        shutil.rmtree(final, ignore_errors=True)
        os.replace(tmp, final)
        return final

    def cached(self, stage: str, key: str, compute: Callable[[], Any], save: Callable[[Any, Path], None],
               load: Callable[[Path], Any]) -> Any:
        """``load`` the stored stage when there is a valid one, else ``compute`` it and ``save`` it."""
        found, result = self._stored(stage, key, load)
        if found:
            return result
        result = compute()
        self.store(stage, key, lambda tmp: save(result, tmp))
        return result

    def cached_files(self, stage: str, key: str, write: Callable[[Path], None], load: Callable[[Path], Any]) -> Any:
        """Like :meth:`cached` for a stage that writes its files itself (``write(folder)``, e.g. arrays filled
        view by view through ``numpy.lib.format.open_memmap``), so its result is never whole in memory; the
        result is always ``load`` of the stored folder (memory-mapped, typically)."""
        found, result = self._stored(stage, key, load)
        return result if found else load(self.store(stage, key, write))

    def _stored(self, stage: str, key: str, load: Callable[[Path], Any]) -> tuple[bool, Any]:
        """(True, ``load(folder)``) for a valid stored stage, else (False, None); a stored stage that cannot be
        read is removed and named in the log."""
        folder = self.lookup(stage, key)
        if folder is None:
            return False, None
        try:
            result = load(folder)
        except Exception as exc:  # noqa: BLE001 - a stored stage we cannot read is recomputed
            self.log(f"stored {stage} stage {key} is not reused ({type(exc).__name__}: {exc}); recomputing it")
            shutil.rmtree(folder, ignore_errors=True)
            return False, None
        self.reused.append(stage)
        self.log(f"{stage}: reusing the stored stage ({key})")
        return True, result

    def nbytes(self) -> int:
        """Bytes stored in this run's work area (hard links counted once per link)."""
        if not self.work.exists():
            return 0
        return sum(p.stat().st_size for p in self.work.rglob("*") if p.is_file())

    def prune(self, keep: dict[str, str]) -> None:
        """Remove every stored stage of this work area except ``keep`` ({stage: key}), and temporary folders."""
        if not self.work.exists():
            return
        for stage_dir in self.work.iterdir():
            if not stage_dir.is_dir():
                continue
            for entry in stage_dir.iterdir():
                if keep.get(stage_dir.name) != entry.name:
                    shutil.rmtree(entry, ignore_errors=True) if entry.is_dir() else entry.unlink(missing_ok=True)
            if not any(stage_dir.iterdir()):
                stage_dir.rmdir()


def save_arrays(folder: Path, **arrays: np.ndarray) -> None:
    """One ``.npy`` per array (memory-mappable: ``load_arrays(..., mmap=True)``)."""
    for name, value in arrays.items():
        np.save(folder / f"{name}.npy", np.ascontiguousarray(value), allow_pickle=False)


def load_arrays(folder: Path, *names: str, mmap: bool = False) -> list[np.ndarray]:
    """The arrays ``save_arrays`` wrote; ``mmap``: memory-mapped copy-on-write (pages are read from disk when
    touched and the OS may drop them again; writing to one changes this process's copy, never the file)."""
    return [np.load(folder / f"{name}.npy", allow_pickle=False, mmap_mode="c" if mmap else None) for name in names]


def save_json(folder: Path, name: str, obj: Any) -> None:
    (folder / name).write_text(json.dumps(obj, indent=1, default=_json_default))


def load_json(folder: Path, name: str) -> Any:
    return json.loads((folder / name).read_text())


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)
