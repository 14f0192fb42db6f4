"""Training checkpoints: the whole state of :func:`neural.train.fit`'s loop, written atomically now and then,
so a killed run continues from the last one instead of from step 0.

Owns: :class:`TrainCheckpoint`.

Decisions:
- One file, ``torch.save`` of plain containers and tensors (model and skybox state dicts, the touched-texel
  masks, both optimisers' state, the batch generator's state, the step, the loop's elapsed seconds and its
  log entries), written to a temporary name and renamed: a kill leaves the previous checkpoint or the new
  one, never half of one. Read back with ``torch.load(weights_only=True)``: nothing is unpickled.
- The checkpoint carries an identity (the distill stage's cache key): one written for other inputs or
  settings is ignored with a line saying so, as is an unreadable one.
- Written every ``every_s`` seconds of training (30 by default: a checkpoint of a 1024^2 x 8 atlas with its
  Adam moments is ~100 MB and takes well under a second), never on the last step (the stage's own output
  follows at once).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import torch


class TrainCheckpoint:
    """Atomic save and restore of a training loop's state at ``path``.

    Args:
        path: the checkpoint file (its folder is created).
        identity: what the state belongs to (a cache key); a stored checkpoint with another one is ignored.
        every_s: seconds of training between checkpoints.
        log: one-line messages.
    """

    def __init__(self, path: str | Path, identity: str, every_s: float = 30.0, log=None):
        self.path, self.identity, self.every_s = Path(path), str(identity), float(every_s)
        self.log = log or (lambda msg: None)
        self._last = time.perf_counter()
        self.saved = 0

    def due(self) -> bool:
        return time.perf_counter() - self._last >= self.every_s

    def save(self, state: dict) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(f".{self.path.name}.tmp-{os.getpid()}")
        torch.save({"identity": self.identity, **state}, tmp)
        os.replace(tmp, self.path)
        self._last = time.perf_counter()
        self.saved += 1

    def load(self) -> dict | None:
        """The stored state, or None (none, unreadable, or written for something else: then it is removed)."""
        if not self.path.is_file():
            return None
        try:
            state = torch.load(self.path, map_location="cpu", weights_only=True)
        except Exception as exc:  # noqa: BLE001 - a checkpoint we cannot read is not resumed from
            self.log(f"training checkpoint {self.path.name} is unreadable ({type(exc).__name__}); training from "
                     "step 0")
            self.remove()
            return None
        if not isinstance(state, dict) or state.get("identity") != self.identity:
            self.log("training checkpoint belongs to other inputs or settings; training from step 0")
            self.remove()
            return None
        return state

    def remove(self) -> None:
        self.path.unlink(missing_ok=True)
