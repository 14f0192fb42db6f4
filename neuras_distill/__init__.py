"""neuras-distill: turn a trained NeRF / SDF field into a mesh + neural textures + GLSL bundle.

Importing the package is cheap: heavy modules (torch, moderngl, libigl, ...) load on first use of the
attribute that needs them.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

_LAZY = {
    "Cameras": ("neuras_distill.render.cameras", "Cameras"),
    "BadInputError": ("neuras_distill.errors", "BadInputError"),
    "distill": ("neuras_distill.pipeline.run", "distill"),
    "DistillConfig": ("neuras_distill.config", "DistillConfig"),
    "load_config": ("neuras_distill.config", "load_config"),
    "load_field": ("neuras_distill.registry", "load_field"),
    "load_bundle": ("neuras_distill.bake.bundle", "load_bundle"),
    "make_scene": ("neuras_distill.scenes.synthetic", "make_scene"),
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str):
    if name in _LAZY:
        module, attr = _LAZY[name]
        value = getattr(importlib.import_module(module), attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'neuras_distill' has no attribute {name!r}")
