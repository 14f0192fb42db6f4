"""Run folders: written in a temporary sibling, moved into place only when the run succeeded.

A folder we made carries a marker file; an existing folder without it (and not empty) is never touched.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

from ..errors import BadInputError, require

MARKER = ".neuras-distill-run"


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


class RunFolder:
    """Context manager: ``with RunFolder(out) as tmp: ...`` writes into ``tmp``; on success ``tmp`` replaces
    ``out`` (an older run of ours there is removed); on any exception ``tmp`` is deleted and ``out`` untouched."""

    def __init__(self, out: str | Path):
        self.out = Path(out).resolve()
        check_output_folder(self.out)
        self.tmp = self.out.parent / f".{self.out.name}.tmp-{os.getpid()}-{int(time.time() * 1000)}"

    def __enter__(self) -> Path:
        self.out.parent.mkdir(parents=True, exist_ok=True)
        self.tmp.mkdir()
        (self.tmp / MARKER).write_text(json.dumps({"tool": "neuras-distill", "created": time.time()}) + "\n")
        return self.tmp

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
            return False
        check_output_folder(self.out)  # it may have appeared while we ran
        old = None
        if self.out.exists():
            old = self.out.parent / f".{self.out.name}.old-{os.getpid()}"
            os.replace(self.out, old)
        os.replace(self.tmp, self.out)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return False
