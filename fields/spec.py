"""How a configurable value is declared: by the strength kinds here, and by the config
(:class:`fracture.pipeline.schema.Param` adds the checks)."""

from __future__ import annotations

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
