"""The bench's bundle variants: each a change to the run's own configuration (``DistillConfig`` sections as
nested dicts), so a variant differs from the default in exactly one setting.

Every variant trains for the run's own number of steps at the run's atlas side (unless it changes the side),
so the differences come from the setting, not from another training plan. What each re-computes follows from
the stage keys (``pipeline.run``): MLP, view-input and VQ variants re-train only; atlas variants re-unwrap,
re-rasterize and re-train; face-budget variants also re-mesh. The teacher renders and the field's held-out
renders are always reused.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from ..errors import BadInputError


@dataclass(frozen=True)
class RunFacts:
    """What the variants are relative to: the run's atlas side, training steps, face budget and MLP, and
    whether its shader takes the view direction."""

    side: int
    steps: int
    face_budget: int
    hidden: int
    num_layers: int
    view_input: bool = True


@dataclass(frozen=True)
class Variant:
    """A named change: ``changes(facts)`` -> nested config overrides (``{"texture": {"hidden": 8}}``);
    ``same_as_run(facts)`` -> why the variant would be the run's own bundle (it is then skipped), or None."""

    name: str
    description: str
    changes: Callable[[RunFacts], dict]
    same_as_run: Callable[[RunFacts], str | None] = lambda f: None


VARIANTS = (
    Variant("atlas-half", "atlas side x1/2", lambda f: {"texture": {"resolution": max(16, f.side // 2)}}),
    Variant("atlas-double", "atlas side x2", lambda f: {"texture": {"resolution": min(8192, 2 * f.side)}}),
    Variant("mlp-8", "MLP hidden width 8", lambda f: {"texture": {"hidden": 8}}),
    Variant("mlp-16", "MLP hidden width 16", lambda f: {"texture": {"hidden": 16}},
            lambda f: "the run's shader is already 16 wide: this variant would be the default bundle"
            if f.hidden == 16 else None),
    Variant("mlp-two-hidden", "MLP with two hidden layers instead of one",
            lambda f: {"texture": {"num_layers": f.num_layers + 1}}),
    Variant("no-view", "no view-direction input", lambda f: {"texture": {"view_dependence": "off"}},
            lambda f: None if f.view_input else "the run's shader already has no view input (its field's colour "
            "barely changes with the view): this variant would be the default bundle"),
    Variant("no-vq", "no vector quantization (every distinct texel feature stored)",
            lambda f: {"texture": {"quantize": False}}),
    Variant("faces-quarter", "face budget x1/4", lambda f: {"geometry": {"face_budget": max(4, f.face_budget // 4)}}),
    Variant("faces-half", "face budget x1/2", lambda f: {"geometry": {"face_budget": max(4, f.face_budget // 2)}}),
)

VARIANT_NAMES = tuple(v.name for v in VARIANTS)


def pick_variants(names: list[str] | None) -> list[Variant]:
    """The variants named (all when None), in the catalogue's order; an unknown name is refused."""
    if names is None:
        return list(VARIANTS)
    unknown = [n for n in names if n not in VARIANT_NAMES]
    if unknown:
        raise BadInputError(f"unknown bench variant {unknown[0]!r}; available: {', '.join(VARIANT_NAMES)}")
    return [v for v in VARIANTS if v.name in names]


def variant_overrides(variant: Variant, facts: RunFacts) -> dict:
    """The run's pinned training length and atlas side, then the variant's own change on top."""
    out: dict = {"train": {"steps": facts.steps}, "texture": {"resolution": facts.side}}
    for section, values in variant.changes(facts).items():
        out.setdefault(section, {}).update(values)
    return out
