"""Which torch device a run computes on: ``--device auto|cpu|cuda[:N]`` and ``nd.distill(device=...)``.

This module owns the parsing of a device string into a :class:`torch.device` (one clear
:class:`~neuras_distill.errors.BadInputError` for a string that is not a device, a CUDA request on a torch or a
machine without CUDA, an index that does not exist), moving a field's tensors and modules onto a device
(:func:`move_field`), honest timing (:func:`synchronize` before a clock is read), free memory
(:func:`free_bytes`), the words the report uses for a device (:func:`describe`), and turning a GPU running out of
memory into one line saying what to change (:func:`out_of_memory_message`).

What runs on the chosen device: the field (adapters' modules, synthetic fields' tensors), the teacher and the
held-out field renders (rays, occupancy grid, compositing), grid sampling for marching cubes, training and the
quantizer. Numpy appears only at stage boundaries (stored stages, G-buffers, images). The bundle is played by
OpenGL, whichever device that is (``playback.context.gl_info``).
"""

from __future__ import annotations

import re
from typing import Any

import torch

from .errors import BadInputError

#: What torch raises when a GPU runs out of memory (``torch.OutOfMemoryError`` since torch 2.5).
OUT_OF_MEMORY = getattr(torch, "OutOfMemoryError", torch.cuda.OutOfMemoryError)

#: The device strings the command line and ``nd.distill`` take.
DEVICE_CHOICES = "auto, cpu, cuda or cuda:N"

#: Field attributes that stay on the host whatever the device: metadata every stage reads there (the box, the
#: constant background, the cameras). A field's own code that computes with them moves them to its inputs.
HOST_ATTRIBUTES = ("aabb", "background_color", "cameras")

_PATTERN = re.compile(r"^(auto|cpu|cuda)(?::(\d+))?$")


def resolve_device(spec: str | torch.device | None = "auto") -> torch.device:
    """The :class:`torch.device` a device string names, checked against this torch and machine.

    Args:
        spec: ``"auto"`` (the first CUDA device when torch sees one, else the CPU), ``"cpu"``, ``"cuda"``
            (device 0), ``"cuda:N"``, a :class:`torch.device`, or None (= auto).
    Raises:
        BadInputError: the string is not a device; CUDA was asked for and this torch has no CUDA (a CPU build)
            or sees no GPU; the index is not one of this machine's GPUs.
    """
    if spec is None:
        spec = "auto"
    text = str(spec).strip().lower()
    match = _PATTERN.match(text)
    if match is None or (match.group(1) != "cuda" and match.group(2) is not None):
        raise BadInputError(f"device {str(spec)!r} is not a device; use {DEVICE_CHOICES}")
    kind, index = match.group(1), match.group(2)
    if kind == "auto":
        return torch.device("cuda", 0) if torch.cuda.is_available() else torch.device("cpu")
    if kind == "cpu":
        return torch.device("cpu")
    if not torch.cuda.is_available():
        why = ("this torch is a CPU build" if torch.version.cuda is None
               else f"torch {torch.__version__} (CUDA {torch.version.cuda}) sees no GPU on this machine")
        raise BadInputError(f"device {text!r}: {why}; install a CUDA build of torch into .venv (see the README, "
                            f"'On a GPU') or use --device cpu")
    count = torch.cuda.device_count()
    i = int(index or 0)
    if i >= count:
        raise BadInputError(f"device {text!r} does not exist: this machine has {count} CUDA device"
                            f"{'s' if count != 1 else ''} (cuda:0{f' .. cuda:{count - 1}' if count > 1 else ''})")
    return torch.device("cuda", i)


def synchronize(device: torch.device | str | None) -> None:
    """Wait for the work queued on ``device`` (a no-op on the CPU): call it before reading a clock."""
    if device is not None and torch.device(device).type == "cuda":
        torch.cuda.synchronize(device)


def free_bytes(device: torch.device | str | None) -> int | None:
    """Free memory on a CUDA device in bytes (``torch.cuda.mem_get_info``), None on the CPU."""
    if device is None or torch.device(device).type != "cuda":
        return None
    free, _total = torch.cuda.mem_get_info(device)
    return int(free)


def chunk_for_memory(default: int, bytes_per_item: int, device: torch.device | str | None,
                     share: float = 0.25, free: int | None = None, max_items: int | None = None) -> int:
    """How many items to process at once: ``default`` on the CPU; on a GPU at most ``share`` of its free memory
    (``free`` overrides the measured free bytes) divided by ``bytes_per_item``, at least 1024 and at most
    ``max_items`` (default 8x ``default``). Chunking is what keeps GPU memory bounded at any resolution."""
    free = free if free is not None else free_bytes(device)
    if free is None:
        return int(default)
    fits = int(free * share) // max(1, int(bytes_per_item))
    cap = 8 * int(default) if max_items is None else int(max_items)
    return int(max(1024, min(cap, fits)))


def describe(device: torch.device | str) -> str:
    """The device in the report's words: ``"GPU: NVIDIA H100 80GB HBM3 (cuda:0), torch 2.x, CUDA 12.x"`` or
    ``"CPU: <model name> (N threads), torch 2.x"``."""
    device = torch.device(device)
    if device.type == "cuda":
        index = device.index or 0
        return (f"GPU: {torch.cuda.get_device_name(index)} (cuda:{index}), torch {torch.__version__}, "
                f"CUDA {torch.version.cuda}")
    return f"CPU: {cpu_name()} ({torch.get_num_threads()} threads), torch {torch.__version__}"


def cpu_name() -> str:
    """The processor's model name (``/proc/cpuinfo``), or what ``platform`` knows."""
    import platform
    from pathlib import Path

    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def move_field(field: Any, device: torch.device) -> Any:
    """Put a field's parameters and tensors on ``device``, in place; returns the field.

    A field with its own ``to(device)`` (a ``torch.nn.Module``, the NeuS adapters) is moved by it; otherwise
    every tensor, module and nested plain object among its attributes is moved (synthetic fields hold their
    tables as plain tensors). :data:`HOST_ATTRIBUTES` (``aabb``, ``background_color``, ``cameras``) stay
    where they are: metadata every stage reads on the host. Nothing is done on the CPU when the field
    is already there, so a CPU run is exactly today's.
    """
    device = torch.device(device)
    if device.type == "cpu" and not _has_tensor_off(field, device):
        return field
    aabb = getattr(field, "aabb", None)
    mover = getattr(field, "to", None)
    if callable(mover):
        moved = mover(device)
        field = moved if moved is not None else field
    else:
        _move_attributes(field, device, seen=set())
    if isinstance(aabb, torch.Tensor):
        try:
            field.aabb = aabb.cpu()
        except AttributeError:          # a read-only property: the field computes it
            pass
    return field


def _move_attributes(obj: Any, device: torch.device, seen: set) -> None:
    if id(obj) in seen or not hasattr(obj, "__dict__"):
        return
    seen.add(id(obj))
    for name, value in list(vars(obj).items()):
        if name in HOST_ATTRIBUTES:
            continue
        if isinstance(value, (torch.Tensor, torch.nn.Module)):
            setattr(obj, name, value.to(device))
        elif isinstance(value, (list, tuple)) and any(isinstance(v, torch.Tensor) for v in value):
            setattr(obj, name, type(value)(v.to(device) if isinstance(v, torch.Tensor) else v for v in value))
        elif is_package_object(value):
            _move_attributes(value, device, seen)


def _has_tensor_off(obj: Any, device: torch.device) -> bool:
    """Whether any tensor among ``obj``'s parameters, buffers or attributes is on another device type."""
    if isinstance(obj, torch.nn.Module):
        return any(t.device.type != device.type for t in (*obj.parameters(), *obj.buffers()))
    values = vars(obj).values() if hasattr(obj, "__dict__") else ()
    return any(isinstance(v, torch.Tensor) and v.device.type != device.type for v in values)


def out_of_memory_message(device: torch.device | str, stage: str | None = None) -> str:
    """One line for a GPU that ran out of memory: where, how much was free, what to change."""
    free = free_bytes(device)
    where = f" during {stage}" if stage else ""
    have = f" ({free / 2**30:.1f} GiB free now)" if free is not None else ""
    return (f"the GPU ran out of memory{where}{have}; close other GPU programs, lower --eval-width or the "
            f"training batch (train.batch_patches in a --config file), or run with --device cpu; the finished "
            f"stages are kept and the same command reuses them")


def field_device(field: Any) -> torch.device:
    """The device a field computes on: that of its first parameter, buffer or tensor attribute (the CPU when it
    holds none, e.g. an analytic field)."""
    if isinstance(field, torch.nn.Module):
        for t in (*field.parameters(), *field.buffers()):
            return t.device
    for name, value in (vars(field).items() if hasattr(field, "__dict__") else ()):
        if name not in HOST_ATTRIBUTES and isinstance(value, torch.Tensor):
            return value.device
        if isinstance(value, torch.nn.Module) or is_package_object(value):
            found = field_device(value)
            if found.type != "cpu":
                return found
    return torch.device("cpu")


def is_package_object(value: Any) -> bool:
    """Whether ``value`` is a plain object of this package or its adapters (a field's frame, a wrapped field)."""
    return hasattr(value, "__dict__") and not isinstance(value, type) and \
        type(value).__module__.split(".")[0] in ("neuras_distill", "neuras_distill_adapters", "adapters")


def peak_memory_mb(device: torch.device | str = "cpu") -> dict:
    """``{"peak_rss_mb": this process's peak resident memory, "peak_rss_children_mb": the largest of its
    finished children (xatlas, workers), "peak_gpu_mb": torch's peak allocation on a CUDA device, else None}``."""
    import resource

    kib = 1024.0                                    # Linux reports ru_maxrss in KiB
    device = torch.device(device)
    gpu = None
    if device.type == "cuda" and torch.cuda.is_available():
        gpu = torch.cuda.max_memory_allocated(device) / 2**20
    return {"peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / kib,
            "peak_rss_children_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / kib,
            "peak_gpu_mb": gpu}
