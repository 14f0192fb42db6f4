"""Run folders: written in a hidden sibling, moved into place in one rename only when the run succeeded.

A folder we made carries a marker file; an existing folder without it (and not empty) is never touched.

The sibling has a fixed name, ``.<name>.partial``, and holds the run's work area (``work/``, the stored
stages of :mod:`pipeline.cache`) beside the outputs being written. A run that is killed leaves it behind; the
same command finds it and reuses its finished stages and training checkpoint. While a run writes into it, it
is locked (``flock``; the lock dies with the process), so a second run into the same folder is refused
instead of mixing outputs. After success the work area travels inside the run folder (``<out>/work``), where
the next run into the same folder (a changed setting, the trade-off bench) reuses it; ``keep_work=False``
drops it. Leftovers of older versions (``.<name>.tmp-<pid>-...``, ``.<name>.old-<pid>``) whose process is
gone are removed.
"""

from __future__ import annotations

import fcntl
import json
import os
import re
import shutil
import time
from pathlib import Path

from ..errors import BadInputError, require

MARKER = ".neuras-distill-run"
WORK = "work"


def check_output_folder(out: Path) -> None:
    """Raise BadInputError unless ``out`` is absent, empty, or a run folder of ours."""
    if not out.exists():
        require(out.parent.exists() or not out.parent.is_file(),
                f"cannot create output folder {out}: its parent is a file")
        return
    require(out.is_dir(), f"output path {out} exists and is a file; choose another --out")
    if any(out.iterdir()) and not (out / MARKER).exists():
        raise BadInputError(f"output folder {out} exists and was not written by neuras-distill; "
                            "choose another --out or remove it")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_leftovers(out: Path) -> list[Path]:
    """Remove ``.<name>.tmp-<pid>-...`` / ``.<name>.old-<pid>`` folders of ours beside ``out`` whose process is
    gone (what runs of earlier versions left when killed). Returns what was removed."""
    removed = []
    pattern = re.compile(rf"^\.{re.escape(out.name)}\.(?:tmp|old)-(\d+)(?:-\d+)?$")
    if not out.parent.is_dir():
        return removed
    for path in out.parent.iterdir():
        m = pattern.match(path.name)
        if m and path.is_dir() and (path / MARKER).exists() and not _alive(int(m.group(1))):
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
    return removed


class RunFolder:
    """Context manager: ``with RunFolder(out) as tmp: ...`` writes into ``tmp`` (``.<name>.partial``, its
    work area in ``tmp / "work"``); on success ``tmp`` replaces ``out`` (an older run of ours there is
    removed). On an exception the outputs written so far are removed; the work area stays for the next
    attempt when it holds a finished stage, else the whole folder goes.

    Attributes (after entering): ``work`` (this run's work area), ``previous_work`` (the work area of the
    run folder being replaced, when there is one: stages are reused from it), ``resumed_folder`` (whether a
    killed run's folder was found), ``removed_leftovers``.
    """

    def __init__(self, out: str | Path, *, keep_work: bool = True):
        self.out = Path(out).resolve()
        check_output_folder(self.out)
        self.tmp = self.out.parent / f".{self.out.name}.partial"
        self.work = self.tmp / WORK
        self.previous_work = self.out / WORK
        self.keep_work = keep_work
        self.resumed_folder = False
        self.removed_leftovers: list[Path] = []
        self._lock_fd: int | None = None

    def __enter__(self) -> Path:
        self.out.parent.mkdir(parents=True, exist_ok=True)
        self.removed_leftovers = remove_stale_leftovers(self.out)
        if self.tmp.exists():
            require(self.tmp.is_dir() and (self.tmp / MARKER).exists(),
                    f"{self.tmp} exists and was not written by neuras-distill; remove it or choose another --out")
            self.resumed_folder = True
        else:
            self.tmp.mkdir()
            (self.tmp / MARKER).write_text(json.dumps({"tool": "neuras-distill", "created": time.time()}) + "\n")
        fd = os.open(self.tmp, os.O_RDONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise BadInputError(f"another neuras-distill run is writing {self.out} (its folder {self.tmp.name} is "
                                "locked); wait for it to finish or choose another --out") from None
        self._lock_fd = fd
        self._clear_outputs()
        return self.tmp

    def _clear_outputs(self) -> None:
        """Remove everything but the marker and the work area (outputs of a killed attempt)."""
        for path in self.tmp.iterdir():
            if path.name in (MARKER, WORK):
                continue
            shutil.rmtree(path, ignore_errors=True) if path.is_dir() else path.unlink(missing_ok=True)

    def _unlock(self) -> None:
        if self._lock_fd is not None:
            os.close(self._lock_fd)          # closing the descriptor releases the flock
            self._lock_fd = None

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            if exc_type is not None:
                self._clear_outputs()
                finished = self.work.is_dir() and any(self.work.glob("*/*/done.json"))
                if not finished:
                    shutil.rmtree(self.tmp, ignore_errors=True)
                return False
            if not self.keep_work:
                shutil.rmtree(self.work, ignore_errors=True)
            check_output_folder(self.out)  # it may have appeared while we ran
            old = None
            if self.out.exists():
                old = self.out.parent / f".{self.out.name}.old-{os.getpid()}"
                os.replace(self.out, old)
            os.replace(self.tmp, self.out)
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
            return False
        finally:
            self._unlock()
