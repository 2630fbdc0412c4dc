"""How a configurable value is declared: by the strength kinds here, and by the config
(:class:`fracture.pipeline.schema.Param` adds the checks); and the dataclass field that holds it
(the layer types of :mod:`fields.strength` and the typed config are made of such fields)."""

from __future__ import annotations

import copy
from dataclasses import field
from typing import Any, NamedTuple


class Spec(NamedTuple):
    """A configurable value as it is declared: its default, type word, inclusive range, allowed strings, whether null is
    allowed, and one line of description."""

    default: Any
    type: str = "float"
    lo: float | None = None
    hi: float | None = None
    choices: tuple[str, ...] | None = None
    nullable: bool = False
    doc: str = ""


# Python types of the type words (vectors and bounds stay lists, as a YAML file gives them)
_PYTHON_TYPES = {"float": float, "int": int, "bool": bool, "str": str, "path": str, "dir": str, "vec3": list,
                 "int3": Any, "bounds": list, "grid": dict}


def python_type(spec: Spec):
    """The Python type of a spec's values (``| None`` where null is allowed)."""
    kind = _PYTHON_TYPES[spec.type]
    return kind | None if spec.nullable and kind is not Any else kind


def spec_field(spec: Spec):
    """A dataclass field of a spec: its default (copied, for lists and mappings), and its type word,
    range, choices and description in the field's metadata."""
    meta = dict(type=spec.type, lo=spec.lo, hi=spec.hi, choices=spec.choices, nullable=spec.nullable, doc=spec.doc)
    if isinstance(spec.default, (list, dict)):
        return field(default_factory=lambda d=spec.default: copy.deepcopy(d), metadata=meta)
    return field(default=spec.default, metadata=meta)
