"""Resolve what ``neuras-distill check SOURCE`` names into a field and its cameras.

SOURCE is ``synthetic:NAME`` (an embedded scene, :func:`~neuras_distill.scenes.synthetic.make_scene`),
``extreme:NAME`` (a constructed stiff field, :mod:`~neuras_distill.stability.extreme`), or a checkpoint path
loaded exactly as ``from-ngp`` / ``from-sdf`` load it (adapter chosen by sniffing the content, or named).
"""

from __future__ import annotations

from pathlib import Path

from ..errors import BadInputError, require

#: Options each adapter accepts (the others are refused with a hint, never silently dropped).
ADAPTER_OPTIONS = {"instant_ngp": {"latent_view", "foreground_box"},
                   "neus": {"density", "cameras", "width", "height", "config"}}


def load_source(source: str, *, kind: str | None = None, cameras_path: str | None = None,
                adapter: str | None = None, options: dict | None = None):
    """(field, cameras or None) for a SOURCE string; ``options`` are adapter options (``from-ngp``/``from-sdf``)."""
    options = dict(options or {})
    if source.startswith("synthetic:"):
        from ..scenes.synthetic import make_scene
        return make_scene(source.split(":", 1)[1], kind=kind), None
    if source.startswith("extreme:"):
        from .extreme import make_extreme
        return make_extreme(source.split(":", 1)[1]), None
    from ..registry import available_adapters
    from ..render.cameras import Cameras

    path = Path(source)
    require(path.exists(), f"{path} does not exist; give a checkpoint path, synthetic:NAME or extreme:NAME")
    require(path.is_file(), f"{path} is a directory; give the checkpoint file inside it")
    cameras = None
    if cameras_path is not None:
        cam_file = Path(cameras_path)
        require(cam_file.is_file(), f"--cameras {cameras_path}: no such file")
        if cam_file.suffix.lower() == ".json":
            cameras = Cameras.from_transforms(cam_file)
        else:
            options["cameras"] = str(cam_file)
    adapters = available_adapters()
    if adapter is None:
        for name, cls in adapters.items():
            if name != "synthetic" and cls().sniff(path):
                adapter = name
                break
    if adapter is None:
        raise BadInputError(f"{path} is not a checkpoint any installed adapter reads "
                            f"(tried: {', '.join(sorted(adapters))}); check the file is a complete Instant-NGP "
                            "snapshot or NeuS/instant-nsr-pl checkpoint")
    require(adapter in adapters, f"unknown adapter {adapter!r}; installed: {', '.join(sorted(adapters))}")
    allowed = ADAPTER_OPTIONS.get(adapter)
    if allowed is not None:
        extra = sorted(set(options) - allowed)
        require(not extra, f"{path} is read by the {adapter} adapter, which takes no "
                           f"{', '.join('--' + e.replace('_', '-') for e in extra)} option")
    field = adapters[adapter]().load(path, **options)
    return field, cameras
