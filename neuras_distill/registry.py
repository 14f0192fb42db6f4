"""Adapter registry: finds field adapters through the ``neuras_distill.adapters`` entry-point group.

An adapter is a class with ``name`` (str), ``sniff(path: Path) -> bool`` (decides from the file's content,
never its extension, reading only a small header) and ``load(path: Path, **options) -> field``. Our own
adapters register exactly as a third party's would (see ``pyproject.toml``).

The entry points are found and loaded once per process, on first use (:func:`_scan`, cached): a lookup then
costs no metadata scan and no import. A plug-in whose module fails to import is skipped, and its reason is
kept to name it when that adapter is asked for (:func:`broken_adapters`). :func:`reload_adapters` forgets
the cache (a plug-in installed into the running process; tests that fake the entry points).
"""

from __future__ import annotations

import functools
from importlib.metadata import entry_points
from pathlib import Path

from .errors import BadInputError, require

GROUP = "neuras_distill.adapters"


def available_adapters() -> dict:
    """name -> adapter class, for every installed adapter that imports cleanly (see :func:`broken_adapters`).
    A new dict each call (the cache behind it is not the caller's to change)."""
    return dict(_scan()[0])


def broken_adapters() -> dict:
    """name -> one-line reason, for installed adapters whose module fails to import (a new dict each call)."""
    return dict(_scan()[1])


def reload_adapters() -> None:
    """Forget the loaded adapters: the next lookup finds and loads the entry points again."""
    _scan.cache_clear()


@functools.lru_cache(maxsize=1)
def _scan() -> tuple[dict, dict]:
    """(name -> adapter class, name -> reason it failed to import): every entry point of :data:`GROUP` loaded
    once (cached until :func:`reload_adapters`)."""
    adapters, broken = {}, {}
    for ep in entry_points(group=GROUP):
        try:
            adapters[ep.name] = ep.load()
        except Exception as exc:  # noqa: BLE001 - one broken plug-in must not take the others down
            broken[ep.name] = f"{type(exc).__name__}: {exc}"
    return adapters, broken


def load_field(path, adapter: str | None = None, **options):
    """Load a field from ``path`` with the named adapter, or the first adapter whose ``sniff`` accepts it.

    ``path`` may also be ``synthetic:NAME`` or ``synthetic:NAME:KIND`` for the embedded scenes.
    """
    adapters, broken = _scan()
    text = str(path)
    if text.startswith("synthetic:"):
        adapter, path = "synthetic", text
    else:
        path = Path(path)
        require(path.exists(), f"{path} does not exist; give the path of a trained field's checkpoint")
        require(path.is_file(), f"{path} is a directory; give the checkpoint file inside it")
    if adapter is not None:
        require(adapter not in broken, f"adapter {adapter!r} is installed but fails to import ({broken.get(adapter)})")
        require(adapter in adapters, f"unknown adapter {adapter!r}; installed: {', '.join(sorted(adapters))}")
        return adapters[adapter]().load(path, **options)
    for cls in adapters.values():
        if cls().sniff(path):
            return cls().load(path, **options)
    raise BadInputError(f"{path} is not a checkpoint any installed adapter reads "
                        f"(tried: {', '.join(sorted(adapters))}); pass adapter=... if you know its format")
