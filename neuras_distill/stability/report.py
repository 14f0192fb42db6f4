"""The result of a stability probe: :class:`Item` (one probe) and :class:`StabilityReport` (all of them).

A report is plain data: ``to_json()`` gives a JSON-serialisable dict (for ``report.json["stability"]`` and
``check --json``), ``to_table()`` a fixed-width text table for the terminal. Verdicts per item:

* ``fine``: nothing to do;
* ``adapted``: the field distills once a setting changes; ``adaptations`` names the config keys
  (``section.key`` of :class:`~neuras_distill.config.DistillConfig`) and their values;
* ``refused``: it cannot be distilled; ``explanation`` is one line saying what is wrong and what to change.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

VERDICTS = ("fine", "adapted", "refused")


def _clean(v):
    """JSON-safe copy: numpy scalars to Python, non-finite floats to strings ("nan", "inf", "-inf")."""
    if isinstance(v, dict):
        return {str(k): _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    if hasattr(v, "item") and callable(v.item) and getattr(v, "ndim", 0) == 0:
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
    return v


@dataclass
class Item:
    """One probe: ``name`` (e.g. ``density.stiffness``), ``family`` (density, sdf, scale, cameras, colour,
    finiteness), ``values`` (what was measured), ``verdict``, ``explanation`` (one line: what it means and
    what was changed) and ``adaptations`` (config key -> value, only for ``adapted``)."""

    name: str
    family: str
    values: dict
    verdict: str
    explanation: str
    adaptations: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.verdict not in VERDICTS:
            raise ValueError(f"verdict must be one of {VERDICTS}, got {self.verdict!r}")

    def to_json(self) -> dict:
        return _clean({"name": self.name, "family": self.family, "values": self.values, "verdict": self.verdict,
                       "explanation": self.explanation, "adaptations": self.adaptations})


def _merge_adaptations(items: list[Item]) -> dict:
    """Union of the items' adaptations; for a key set by several items the largest number wins."""
    out: dict = {}
    for it in items:
        for k, v in it.adaptations.items():
            if k in out and isinstance(v, (int, float)) and isinstance(out[k], (int, float)):
                out[k] = max(out[k], v)
            else:
                out[k] = v
    return out


@dataclass
class StabilityReport:
    """All probes of one field. ``verdict``: refused if any item is, else adapted if any item is, else fine."""

    source: str
    kind: str
    items: list[Item]
    seconds: float = 0.0
    settings: dict = field(default_factory=dict)

    @property
    def verdict(self) -> str:
        verdicts = {it.verdict for it in self.items}
        return "refused" if "refused" in verdicts else "adapted" if "adapted" in verdicts else "fine"

    @property
    def adaptations(self) -> dict:
        return _merge_adaptations(self.items)

    @property
    def refusals(self) -> list[Item]:
        return [it for it in self.items if it.verdict == "refused"]

    def reason(self) -> str:
        """One line: why the field is refused (the first refused item), or '' when it is not."""
        ref = self.refusals
        return f"{ref[0].name}: {ref[0].explanation}" if ref else ""

    def item(self, name: str) -> Item:
        for it in self.items:
            if it.name == name:
                return it
        raise KeyError(name)

    def to_json(self) -> dict:
        return _clean({"source": self.source, "kind": self.kind, "verdict": self.verdict,
                       "adaptations": self.adaptations, "seconds": round(self.seconds, 3),
                       "settings": self.settings, "items": [it.to_json() for it in self.items]})

    def to_table(self, width: int = 110) -> str:
        """Fixed-width table: probe | verdict | measured | what it means / what changes."""
        rows = [("probe", "verdict", "measured", "explanation")]
        for it in self.items:
            rows.append((it.name, it.verdict, _short_values(it.values), it.explanation))
        w0 = max(len(r[0]) for r in rows)
        w1 = max(len(r[1]) for r in rows)
        w2 = min(max(len(r[2]) for r in rows), 58)
        lines = [f"stability of {self.source} ({self.kind} field): {self.verdict.upper()} "
                 f"({self.seconds:.1f} s)"]
        for i, (a, b, c, d) in enumerate(rows):
            c = c if len(c) <= w2 else c[:w2 - 1] + "~"
            lines.append(f"  {a:<{w0}}  {b:<{w1}}  {c:<{w2}}  {d}")
            if i == 0:
                lines.append("  " + "-" * min(width, w0 + w1 + w2 + 6 + 11))
        if self.adaptations:
            lines.append("  adaptations: " + ", ".join(f"{k} = {v}" for k, v in self.adaptations.items()))
        if self.verdict == "refused":
            lines.append("  refused: " + self.reason())
        return "\n".join(lines)


def _fmt(v) -> str:
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        return f"{v:.3g}"
    if isinstance(v, (list, tuple)):
        return "[" + ",".join(_fmt(x) for x in v) + "]"
    return str(v)


def _short_values(values: dict) -> str:
    return " ".join(f"{k}={_fmt(v)}" for k, v in values.items() if not isinstance(v, dict))
