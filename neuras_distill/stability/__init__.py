"""Stability probes of a field before distillation (``neuras-distill check``, ``report.json["stability"]``).

* :mod:`.probe`: :func:`probe_field` samples a field cheaply and returns a :class:`StabilityReport`;
* :mod:`.report`: :class:`Item` and :class:`StabilityReport` (JSON and table);
* :mod:`.source`: ``synthetic:NAME`` / ``extreme:NAME`` / checkpoint path -> field (the CLI's SOURCE);
* :mod:`.extreme`: constructed stiff and extreme fields.

Importing this package imports torch only through its submodules (the CLI imports them lazily).
"""

from __future__ import annotations

__all__ = ["probe_field", "StabilityReport", "Item"]


def __getattr__(name):
    if name == "probe_field":
        from .probe import probe_field
        return probe_field
    if name in ("StabilityReport", "Item"):
        from . import report
        return getattr(report, name)
    raise AttributeError(name)
