"""Adapter for the embedded synthetic scenes.

Reads ``synthetic:NAME[:KIND]`` references and small JSON scene files of the form
``{"neuras_synthetic": {"scene": "bunny", "kind": "sdf"}}`` (recognised by that key, not the extension).
"""

from __future__ import annotations

import json
from pathlib import Path

from neuras_distill.errors import BadInputError, require

MAGIC = b'"neuras_synthetic"'


class SyntheticAdapter:
    name = "synthetic"

    def sniff(self, path) -> bool:
        if str(path).startswith("synthetic:"):
            return True
        try:
            with open(path, "rb") as f:
                head = f.read(4096)
        except OSError:
            return False
        return MAGIC in head

    def load(self, path, kind: str | None = None, **options):
        from neuras_distill.scenes.synthetic import make_scene

        text = str(path)
        if text.startswith("synthetic:"):
            parts = text.split(":")
            require(len(parts) in (2, 3) and parts[1], f"{text!r}: write synthetic:NAME or synthetic:NAME:KIND")
            scene, file_kind = parts[1], (parts[2] if len(parts) == 3 else None)
        else:
            try:
                spec = json.loads(Path(path).read_text())["neuras_synthetic"]
                scene, file_kind = spec["scene"], spec.get("kind")
            except (ValueError, KeyError, TypeError, UnicodeDecodeError):
                raise BadInputError(f"{path}: not a valid synthetic scene file "
                                    '(expected {"neuras_synthetic": {"scene": NAME, "kind": "sdf"}})') from None
        return make_scene(scene, kind=kind or file_kind, **options)  # None: the scene's own kind
