"""Resolve what ``neuras-distill check SOURCE`` names into a field and its cameras.

SOURCE is ``synthetic:NAME`` (an embedded scene, :func:`~neuras_distill.scenes.synthetic.make_scene`),
``extreme:NAME`` (a constructed stiff field, :mod:`~neuras_distill.stability.extreme`), or a checkpoint path.
Checkpoints and scenes resolve exactly as the run commands resolve them (``registry.load_field``: the adapter
chosen by sniffing the content; ``run_inputs.cameras_option``: a ``--cameras`` transforms.json).
"""

from __future__ import annotations

from pathlib import Path


def load_source(source: str, *, kind: str | None = None, cameras_path: str | None = None,
                adapter: str | None = None, options: dict | None = None):
    """(field, cameras or None) for a SOURCE string; ``options`` are adapter options (``from-ngp``/``from-sdf``).
    A ``cameras_path`` that is not a transforms.json (a NeuS cameras_sphere.npz) goes to the adapter."""
    if source.startswith("extreme:"):
        from .extreme import make_extreme
        return make_extreme(source.split(":", 1)[1]), None
    from ..registry import load_field
    from ..run_inputs import cameras_option

    options = dict(options or {})
    if source.startswith("synthetic:"):
        return load_field(source, kind=kind), None
    cameras = cameras_option(cameras_path)
    if cameras_path is not None and cameras is None:
        options["cameras"] = str(cameras_path)
    return load_field(Path(source), adapter=adapter, **options), cameras
