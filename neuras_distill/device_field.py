"""A field computing on a chosen device and precision: what every stage of a GPU or half-precision run holds.

This module owns :class:`DeviceField` (the wrapper) and :func:`on_device` (which returns the field itself where no
wrapper is needed). Moving tensors is :mod:`neuras_distill.device`'s; what half precision changes is
:mod:`neuras_distill.precision`'s.
"""

from __future__ import annotations

import copy
from typing import Any

import torch

from .device import move_field
from .precision import autocast, check_precision, half_tables


class DeviceField:
    """A field computing on ``device`` for callers on any device: what every stage of a GPU run holds.

    The wrapped field's tensors are moved there once (:func:`move_field`); ``geometry``, ``radiance`` and
    ``background`` move their inputs to the device, run with ``device`` as torch's default device (so constants a
    field builds per call, ``torch.tensor([...])``, land there too) and return on the caller's device: the
    renderer's device tensors stay on the device, a host caller (a probe, the skybox's background check) gets
    host tensors. Every other member is the wrapped field's. On the CPU no wrapper is used (:func:`on_device`).
    """

    def __init__(self, field: Any, device: torch.device, precision: str = "fp32"):
        if check_precision(precision) == "fp16":
            field = copy.deepcopy(field)        # half tables must not change the caller's field
        self.__dict__["_field"] = move_field(field, device)
        self.__dict__["device"] = torch.device(device)
        self.__dict__["precision"] = precision
        self.__dict__["half_tables"] = half_tables(self._field) if precision == "fp16" else 0

    def __getattr__(self, name: str) -> Any:
        value = getattr(self.__dict__["_field"], name)
        if name == "background" and callable(value):
            return lambda d: self._call(value, d)
        return value

    def __setattr__(self, name: str, value: Any) -> None:
        setattr(self.__dict__["_field"], name, value)

    def __repr__(self) -> str:
        return f"{self._field!r} on {self.device}"

    @property
    def wrapped(self) -> Any:
        """The field itself (its tensors on ``device``)."""
        return self._field

    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        """As the field's: x (N, 3) world points -> (N,), on x's device."""
        return self._call(self._field.geometry, x)

    def radiance(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """As the field's: x, d (N, 3) -> (N, 3) colour, on x's device."""
        return self._call(self._field.radiance, x, d)

    def _call(self, fn, *tensors: torch.Tensor) -> torch.Tensor:
        back = tensors[0].device
        with torch.device(self.device), autocast(self.device, self.precision):
            out = fn(*(t.to(self.device) for t in tensors))
        if self.precision != "fp32":
            out = out.float()                   # compositing and everything after stay in float32
        return out.to(back)


def on_device(field: Any, device: torch.device, precision: str = "fp32") -> Any:
    """The field to run the stages with: the field itself on the CPU in float32 (nothing changes), else a
    :class:`DeviceField` on ``device`` evaluating in ``precision`` (``neuras_distill.precision``)."""
    device = torch.device(device)
    if device.type == "cpu" and precision == "fp32":
        return field
    return DeviceField(field, device, precision)
