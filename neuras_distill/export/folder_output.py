"""Writing an export's output folder whole or not at all.

Owns: :func:`check_replaceable` (an existing output is replaced only when it carries the export's marker),
:func:`write_folder` (build it under a temporary sibling name, then rename it into place), which the web,
three.js and tileset outputs share, and :func:`write_file` (one file the same way: the glb export, tile plans).
"""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

from ..errors import BadInputError


def check_replaceable(out: Path, marker: str, what: str) -> None:
    """BadInputError unless ``out`` is absent or a folder (not a link) holding the file ``marker``: a ``what``
    (e.g. "web folder") neuras-distill wrote."""
    if out.exists() or out.is_symlink():
        if not out.is_dir() or out.is_symlink() or not (out / marker).is_file():
            raise BadInputError(f"output {out} exists and is not a {what} written by neuras-distill; "
                                "choose another --out or remove it")


def write_folder(out: Path, files: dict[str, bytes]) -> Path:
    """Write ``files`` ({relative path: bytes}) as the folder ``out``: built beside it under a temporary name
    and renamed into place (an existing ``out`` is moved aside first and removed after); on any error nothing is
    left behind. Returns ``out``."""
    out.parent.mkdir(parents=True, exist_ok=True)
    stamp = f"{os.getpid()}-{int(time.time() * 1000)}"
    tmp, old = out.parent / f".{out.name}.tmp-{stamp}", out.parent / f".{out.name}.old-{stamp}"
    try:
        for name, data in files.items():
            path = tmp / name
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
        if out.exists():
            os.replace(out, old)
        os.replace(tmp, out)
    finally:
        for leftover in (tmp, old):
            if leftover.exists():
                shutil.rmtree(leftover)
    return out


def write_file(path: Path, data: bytes) -> Path:
    """Write ``data`` as the file ``path``: under a temporary name beside it, then renamed into place; on any
    error nothing is left behind. Returns ``path``."""
    tmp = path.parent / f".{path.name}.tmp-{os.getpid()}-{int(time.time() * 1000)}"
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


__all__ = ["check_replaceable", "write_file", "write_folder"]
