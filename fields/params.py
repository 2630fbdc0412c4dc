"""How a configurable value is declared: a field of a pydantic model, once.

Every parameter of the project (the strength kinds here, the refinement's
:class:`~fracture.refine.params.RefineParams`, the config's sections in
:mod:`fracture.pipeline.schema`) is a field of a :class:`Section`: its Python
type in the annotation (a ``Literal`` for a choice of words, ``| None`` where
null is allowed), and its default, inclusive range, kind of value and one line
of description from the helpers below. From that one declaration come the
validation, the messages that say what was expected (:func:`expected`),
``fracref config --explain``, the viewer's tooltips and the stage cache's keys.

Values are taken as YAML gives them (``strict``: no string read as a number,
no number as a flag; an integer is a number), never infinite or NaN; a section
refuses keys it does not know and cannot be changed once made.
"""

from __future__ import annotations

import types
import typing
from typing import Annotated, Any, Literal, Union

from annotated_types import Len
from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator
from pydantic_core import PydanticCustomError

# What each kind of value accepts, in the messages' words.
_WORDS = {
    "float": "a number",
    "int": "an integer",
    "bool": "true or false",
    "str": "a string",
    "choice": "a string",
    "path": "a file path (string)",
    "dir": "a directory path (string)",
    "vec3": "a list of 3 numbers",
    "int3": "an integer or a list of 3 integers",
    "bounds": "a list of two points [[x0, y0, z0], [x1, y1, z1]] with x0 < x1, y0 < y1, z0 < z1",
    "grid": "a mapping of config keys (e.g. psi.stress_weight) to non-empty lists of values",
}

#: Three numbers (a point or a direction).
Vec3 = Annotated[list[float], Len(3, 3)]
#: Nodes along the longest axis, or along each.
Int3 = Union[int, Annotated[list[int], Len(3, 3)]]
#: A box: its low and high corners.
Bounds = Annotated[list[Vec3], Len(2, 2)]
#: Config keys and the values a sweep gives them.
KeyGrid = dict[str, list]


class Section(BaseModel):
    """A group of parameters: strict, closed to unknown keys, frozen; each field's range and kind checked
    (:func:`expected` says what it accepts)."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True, allow_inf_nan=False)

    @field_validator("*", mode="after")
    @classmethod
    def _in_range(cls, value: Any, info: ValidationInfo) -> Any:
        meta = field_meta(cls, info.field_name)
        word, lo, hi = meta.get("word"), meta.get("lo"), meta.get("hi")
        if value is None:
            return value
        if word in ("str", "path", "dir") and value == "":
            raise PydanticCustomError("empty", "an empty string")
        if word == "bounds" and not all(a < b for a, b in zip(*value)):
            raise PydanticCustomError("bounds_order", "a box whose low corner is not below its high one")
        if word == "grid" and not all(key and isinstance(v, list) and v for key, v in value.items()):
            raise PydanticCustomError("grid", "an empty key or list")
        for x in _numbers(value):
            if (lo is not None and x < lo) or (hi is not None and x > hi):
                raise PydanticCustomError("out_of_range", "out of range")
        return value


def refuse(expected: str) -> PydanticCustomError:
    """The error of a value that breaks a rule between the keys of one section (two axes that must
    differ, a path that only one choice reads); ``expected`` says, in the user's words, what would do."""
    return PydanticCustomError("relation", "{expected}", {"expected": expected})


def _numbers(value: Any):
    if isinstance(value, bool):
        return
    if isinstance(value, (int, float)):
        yield value
    elif isinstance(value, list):
        for v in value:
            yield from _numbers(v)


def _field(default, word: str, doc: str, lo=None, hi=None, **kw):
    extra = {"word": word, **({"lo": lo} if lo is not None else {}), **({"hi": hi} if hi is not None else {})}
    if isinstance(default, (list, dict)):
        return Field(default_factory=lambda d=default: _copy(d), description=doc, json_schema_extra=extra, **kw)
    return Field(default, description=doc, json_schema_extra=extra, **kw)


def _copy(value):
    return [_copy(v) for v in value] if isinstance(value, list) else (
        {k: _copy(v) for k, v in value.items()} if isinstance(value, dict) else value)


def number(default, lo: float | None = None, hi: float | None = None, doc: str = ""):
    """A real number in ``[lo, hi]`` (either end open when None)."""
    return _field(default, "float", doc, lo, hi)


def integer(default, lo: int | None = None, hi: int | None = None, doc: str = ""):
    """An integer in ``[lo, hi]``."""
    return _field(default, "int", doc, lo, hi)


def flag(default: bool, doc: str = ""):
    """true or false."""
    return _field(default, "bool", doc)


def text(default, doc: str = ""):
    """A non-empty string."""
    return _field(default, "str", doc)


def choice(default, doc: str = ""):
    """One of the words of the field's ``Literal`` annotation."""
    return _field(default, "choice", doc)


def vec3(default, doc: str = "", lo: float | None = None, hi: float | None = None):
    """Three numbers, each in ``[lo, hi]``."""
    return _field(default, "vec3", doc, lo, hi)


def int3(default, lo: int | None = None, hi: int | None = None, doc: str = ""):
    """An integer or three, each in ``[lo, hi]``."""
    return _field(default, "int3", doc, lo, hi)


def bounds(default, doc: str = ""):
    """A box ``[[x0, y0, z0], [x1, y1, z1]]`` with its low corner below its high one."""
    return _field(default, "bounds", doc)


def file(default, doc: str = ""):
    """A file's path (relative to the config file that names it)."""
    return _field(default, "path", doc)


def folder(default, doc: str = ""):
    """A directory's path (relative to the config file that names it)."""
    return _field(default, "dir", doc)


def key_grid(default, doc: str = ""):
    """Config keys, each with a non-empty list of values."""
    return _field(default, "grid", doc)


def field_meta(model: type[BaseModel], name: str) -> dict:
    """The kind of value (``word``) and range (``lo``, ``hi``) declared for a field."""
    extra = model.model_fields[name].json_schema_extra
    return extra if isinstance(extra, dict) else {}


def _args(annotation) -> tuple:
    origin = typing.get_origin(annotation)
    if origin in (Union, types.UnionType):
        return typing.get_args(annotation)
    return (annotation,)


def nullable(model: type[BaseModel], name: str) -> bool:
    """Whether null is allowed for the field (its annotation has ``| None``)."""
    return type(None) in _args(model.model_fields[name].annotation)


def choices(model: type[BaseModel], name: str) -> tuple | None:
    """The words a choice field accepts (its ``Literal``), else None."""
    for arg in _args(model.model_fields[name].annotation):
        if typing.get_origin(arg) is Literal:
            return typing.get_args(arg)
    return None


def _bound(x) -> str:
    """A range's end as written: an integer in full (a seed's 4294967295, not 4.29497e+09), a number short."""
    return str(x) if isinstance(x, int) else f"{x:g}"


def expected(model: type[BaseModel], name: str) -> str:
    """What a field accepts, in words: ``a number in [0, 1]``, ``one of 'x', 'y', 'z' (or null)``."""
    meta = field_meta(model, name)
    word = meta.get("word", "str")
    words = choices(model, name)
    out = ("one of " + ", ".join(repr(c) for c in words)) if words else _WORDS[word]
    lo, hi = meta.get("lo"), meta.get("hi")
    if not words:
        if lo is not None and hi is not None:
            out += f" in [{_bound(lo)}, {_bound(hi)}]"
        elif lo is not None:
            out += f" >= {_bound(lo)}"
        elif hi is not None:
            out += f" <= {_bound(hi)}"
    if nullable(model, name):
        out += " (or null)"
    return out


def describe(model: type[BaseModel], name: str, key: str | None = None) -> str:
    """One line for ``--explain`` and the tooltips: ``key = default: what it accepts. Description``."""
    f = model.model_fields[name]
    if f.is_required():
        line = f"{key or name} (required): {expected(model, name)}"
    else:
        line = f"{key or name} = {f.get_default(call_default_factory=True)!r}: {expected(model, name)}"
    doc = f.description or ""
    return line + (f". {doc[0].upper()}{doc[1:]}" if doc else "")


def parameters(section: BaseModel) -> dict[str, Any]:
    """A section's values by field name, as they are (not copied, not dumped)."""
    return {name: getattr(section, name) for name in type(section).model_fields}
