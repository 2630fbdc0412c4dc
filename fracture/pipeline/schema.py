"""Declarative parameter specs and their validation.

A config schema is a nested ``dict`` whose leaves are :class:`Param` (a single
value) or :class:`Layers` (a list of tagged sub-sections, each validated by the
spec of its ``kind``). :func:`validate` walks a user tree against a schema and
raises :class:`ConfigError` naming the file, the key path, what was given and
what was expected.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

from fields.spec import Spec
from fracture.errors import ConfigError

_TYPE_WORDS = {
    "float": "a number",
    "int": "an integer",
    "bool": "true or false",
    "str": "a string",
    "path": "a file path (string)",
    "dir": "a directory path (string)",
    "vec3": "a list of 3 numbers",
    "int3": "an integer or a list of 3 integers",
    "bounds": "a list of two points [[x0, y0, z0], [x1, y1, z1]] with x0 < x1, y0 < y1, z0 < z1",
    "grid": "a mapping of config keys (e.g. psi.stress_weight) to non-empty lists of values",
}


def _describe(value: Any) -> str:
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{text} ({type(value).__name__})"


class Param(Spec):
    """One configurable value (the fields of :class:`fields.spec.Spec`, with its checks).

    Parameters
    ----------
    default : Any
        Value used when no config sets it.
    type : str
        One of ``float int bool str path vec3 int3 bounds``.
    lo, hi : float, optional
        Inclusive range for numbers (each component for vectors).
    choices : tuple of str, optional
        Allowed values for strings.
    nullable : bool
        Whether ``null`` is allowed (meaning "automatic" or "none").
    doc : str
        One line for ``fracref config --explain`` and the viewer's tooltips.
    """

    __slots__ = ()

    def expected(self) -> str:
        text = _TYPE_WORDS[self.type]
        if self.choices:
            text = "one of " + ", ".join(repr(c) for c in self.choices)
        elif self.lo is not None and self.hi is not None:
            text += f" in [{self.lo:g}, {self.hi:g}]"
        elif self.lo is not None:
            text += f" >= {self.lo:g}"
        elif self.hi is not None:
            text += f" <= {self.hi:g}"
        if self.nullable:
            text += " (or null)"
        return text

    def check(self, value: Any, where: str, key: str) -> Any:
        """Return ``value`` converted to its canonical Python form, or raise."""
        if value is None:
            if self.nullable:
                return None
            raise ConfigError(where, key, f"got null, expected {self.expected()}")
        try:
            out = _CONVERT[self.type](value)
        except (TypeError, ValueError):
            raise ConfigError(where, key, f"got {_describe(value)}, expected {self.expected()}") from None
        if self.choices is not None and out not in self.choices:
            raise ConfigError(where, key, f"got {_describe(value)}, expected {self.expected()}")
        numbers = out if isinstance(out, list) else [out]
        if self.type == "bounds":
            numbers = [c for point in out for c in point]
        for x in numbers:
            if isinstance(x, (int, float)) and not isinstance(x, bool):
                if (self.lo is not None and x < self.lo) or (self.hi is not None and x > self.hi):
                    raise ConfigError(where, key, f"got {_describe(value)}, expected {self.expected()}")
        return out


def _number(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError
    if not math.isfinite(value):
        raise ValueError
    return float(value)


def _integer(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError
    return int(value)


def _boolean(value: Any) -> bool:
    if not isinstance(value, bool):
        raise TypeError
    return value


def _string(value: Any) -> str:
    if not isinstance(value, str) or not value:
        raise TypeError
    return value


def _vec3(value: Any) -> list[float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise TypeError
    return [_number(v) for v in value]


def _int3(value: Any) -> int | list[int]:
    if isinstance(value, (list, tuple)):
        if len(value) != 3:
            raise TypeError
        return [_integer(v) for v in value]
    return _integer(value)


def _bounds(value: Any) -> list[list[float]]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise TypeError
    lo, hi = _vec3(value[0]), _vec3(value[1])
    if not all(a < b for a, b in zip(lo, hi)):
        raise ValueError
    return [lo, hi]


def _grid(value: Any) -> dict[str, list]:
    if not isinstance(value, Mapping):
        raise TypeError
    for key, values in value.items():
        if not isinstance(key, str) or not key or not isinstance(values, list) or not values:
            raise TypeError
    return {k: list(v) for k, v in value.items()}


_CONVERT: dict[str, Callable[[Any], Any]] = {
    "float": _number,
    "int": _integer,
    "bool": _boolean,
    "str": _string,
    "path": _string,
    "dir": _string,
    "vec3": _vec3,
    "int3": _int3,
    "bounds": _bounds,
    "grid": _grid,
}


@dataclass(frozen=True)
class Layers:
    """A list of sections, each tagged by ``kind`` and validated by that kind's schema.

    Every item may also carry the keys of ``common`` (e.g. a ``weight``).
    """

    kinds: Mapping[str, Mapping[str, Param]]
    common: Mapping[str, Param] = field(default_factory=dict)
    default: tuple = ()
    min_items: int = 1

    def expected(self) -> str:
        return f"a list of at least {self.min_items} sections, each with kind: one of " + ", ".join(
            repr(k) for k in self.kinds
        )


def schema_defaults(schema: Mapping[str, Any]) -> dict:
    """The tree of default values of a schema."""
    out: dict = {}
    for key, spec in schema.items():
        if isinstance(spec, Param):
            out[key] = spec.default
        elif isinstance(spec, Layers):
            out[key] = [dict(item) for item in spec.default]
        else:
            out[key] = schema_defaults(spec)
    return out


def validate(
    tree: Any,
    schema: Mapping[str, Any],
    origin: Callable[[str], str],
    resolve_path: Callable[[str, str, str], str] | None = None,
    prefix: str = "",
) -> dict:
    """Check ``tree`` against ``schema`` and return a new, fully populated tree.

    Parameters
    ----------
    tree : dict
        User values (already merged over the defaults).
    schema : dict
        Nested dict of :class:`Param` / :class:`Layers` / dict.
    origin : callable
        Maps a dotted key path to the file (or ``--set``) that set it.
    resolve_path : callable, optional
        ``resolve_path(key, value, type)`` turns a ``path`` or ``dir`` param
        into an absolute path (relative to the file that set it).
    prefix : str
        Key path of ``tree`` inside the whole config.
    """
    if not isinstance(tree, Mapping):
        raise ConfigError(origin(prefix), prefix or "(top level)", f"got {_describe(tree)}, expected a mapping of keys")
    unknown = [k for k in tree if k not in schema]
    if unknown:
        key = f"{prefix}.{unknown[0]}" if prefix else str(unknown[0])
        allowed = ", ".join(sorted(schema))
        raise ConfigError(origin(key), key, f"unknown key; expected one of: {allowed}")
    out = {}
    for key, spec in schema.items():
        path = f"{prefix}.{key}" if prefix else key
        value = tree.get(key, schema_defaults({key: spec})[key])
        if isinstance(spec, Param):
            value = spec.check(value, origin(path), path)
            if spec.type in ("path", "dir") and value is not None and resolve_path is not None:
                value = resolve_path(path, value, spec.type)
            out[key] = value
        elif isinstance(spec, Layers):
            out[key] = _validate_layers(value, spec, origin, resolve_path, path)
        else:
            out[key] = validate(value, spec, origin, resolve_path, path)
    return out


def _validate_layers(
    value: Any,
    spec: Layers,
    origin: Callable[[str], str],
    resolve_path: Callable[[str, str, str], str] | None,
    path: str,
) -> list[dict]:
    # A list is set as a whole by one file: its items report (and resolve
    # their paths against) that file.
    if not isinstance(value, list) or len(value) < spec.min_items:
        raise ConfigError(origin(path), path, f"got {_describe(value)}, expected {spec.expected()}")
    items = []
    for i, item in enumerate(value):
        key = f"{path}[{i}]"
        if not isinstance(item, Mapping) or "kind" not in item:
            raise ConfigError(origin(path), key, f"got {_describe(item)}, expected a section with a 'kind' key")
        kind = item["kind"]
        if kind not in spec.kinds:
            raise ConfigError(origin(path), f"{key}.kind", f"got {_describe(kind)}, expected one of " + ", ".join(repr(k) for k in spec.kinds))
        sub_schema = {**spec.common, **spec.kinds[kind]}
        body = {k: v for k, v in item.items() if k != "kind"}
        item_resolve = None if resolve_path is None else (lambda _k, v, kind, p=path: resolve_path(p, v, kind))
        checked = validate(body, sub_schema, lambda _k, p=path: origin(p), item_resolve, key)
        items.append({"kind": kind, **checked})
    return items
