"""Mixed precision for field evaluation (``teacher.precision = "fp16"``, ``--precision fp16``).

This module owns what half precision changes, as Instant-NGP / tiny-cuda-nn do it: hash-grid tables stored and
interpolated in float16 (half the table bytes a lookup reads), the MLPs' matrix products under
``torch.autocast(float16)``; densities and colours come back as float32, and ray marching, compositing and
everything after stay in float32. Analytic fields have no tables and few matrix products: for them it changes
little.

Where it applies: every evaluation of the field in a run (the teacher's renders, marching-cubes sampling, the
held-out "before" renders and their timing), on any device (CPU autocast supports float16 too, slowly: it is
for GPUs). The teacher's image against float32 is checked by ``tests/test_precision.py`` (stated tolerance:
:data:`FP16_TEACHER_MIN_PSNR_DB` on the Instant-NGP fixture).

Tables converted: :class:`neuras_distill.components.tcnn.HashGridEncoding` (Instant-NGP, instant-nsr-pl,
nerfstudio's tcnn layout) and nerfstudio's torch-layout table (any module with a ``hash_table`` buffer).
"""

from __future__ import annotations

import contextlib
from typing import Any

import torch

from .device import is_package_object
from .errors import require

PRECISIONS = ("fp32", "fp16")
#: The fp16 teacher image must stay this close (PSNR against the fp32 one) on the Instant-NGP fixture.
FP16_TEACHER_MIN_PSNR_DB = 45.0


def check_precision(name: str) -> str:
    require(name in PRECISIONS, f"precision {name!r} is not one of {', '.join(PRECISIONS)}; use --precision fp32 "
                                "(exact) or fp16 (half tables and MLPs, as Instant-NGP evaluates)")
    return name


def half_tables(field: Any) -> int:
    """Store the field's hash-grid tables in float16, in place; returns how many tables were converted."""
    from .components.tcnn import HashGridEncoding

    count = 0
    for module in _modules(field, seen=set()):
        if isinstance(module, HashGridEncoding):
            module.params.data = module.params.data.half()
            count += 1
        elif isinstance(getattr(module, "hash_table", None), torch.Tensor) and module.hash_table.is_floating_point():
            module.hash_table = module.hash_table.half()
            count += 1
    return count


def autocast(device: torch.device, precision: str):
    """The context field calls run in: float16 autocast for "fp16", nothing for "fp32"."""
    if precision != "fp16":
        return contextlib.nullcontext()
    return torch.autocast(torch.device(device).type, dtype=torch.float16)


def _modules(obj: Any, seen: set):
    """Every ``torch.nn.Module`` reachable from a field: its own submodules and those of its attributes."""
    if id(obj) in seen:
        return
    seen.add(id(obj))
    if isinstance(obj, torch.nn.Module):
        yield from obj.modules()
        return
    if not is_package_object(obj):
        return
    for value in vars(obj).values():
        if isinstance(value, (list, tuple)):
            for v in value:
                yield from _modules(v, seen)
        else:
            yield from _modules(value, seen)
