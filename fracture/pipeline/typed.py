"""The config as typed records: frozen dataclasses generated from :data:`~fracture.pipeline.config.SCHEMA`.

The schema declares every key once (default, type, range, description);
:func:`~fracture.pipeline.config.load_config` merges and validates the YAML
files into a plain tree (what is hashed, saved beside a run and edited by the
viewer), and :func:`typed_config` gives the same values as a :class:`Config`:
one frozen dataclass per section, each field carrying its schema entry in its
metadata, and ``strength.layers`` a tuple of the layer types of
:data:`fields.strength.LAYER_TYPES` (a union chosen by ``kind``). The stages
read this record; the refinement's own parameter type
(:class:`~fracture.refine.params.RefineParams`) is the ``refine`` section
without the pipeline's keys (:func:`refine_params`).
"""

from __future__ import annotations

from dataclasses import field, fields, is_dataclass, make_dataclass
from typing import Any, Mapping

from fields.spec import python_type, spec_field
from fields.strength import as_layer
from fracture.pipeline.config import SCHEMA
from fracture.pipeline.schema import Layers, Param
from fracture.refine.params import RefineParams


def _section_type(name: str, node: Mapping[str, Any]) -> type:
    body = []
    for key, spec in node.items():
        if isinstance(spec, Param):
            body.append((key, python_type(spec), spec_field(spec)))
        elif isinstance(spec, Layers):
            defaults = tuple(as_layer(layer) for layer in spec.default)
            body.append((key, tuple, field(default=defaults, metadata=dict(doc="layers of zeta, each of its kind's type"))))
        else:
            section = _section_type(name + "".join(part.title() for part in key.split("_")), spec)
            body.append((key, section, field(default_factory=section)))
    cls = make_dataclass(name, body, frozen=True)
    cls.__module__ = __name__
    cls.__doc__ = f"The config's {'sections' if name == 'Config' else name[len('Config'):].lower() + ' section'}."
    return cls


#: The whole config; ``Config()`` holds every default.
Config = _section_type("Config", SCHEMA)


def typed_config(cfg: Mapping[str, Any] | Config) -> Config:
    """The values of a validated config tree (:func:`~fracture.pipeline.config.load_config`) as a
    :class:`Config`; a :class:`Config` is returned as it is."""
    if isinstance(cfg, Config):
        return cfg

    def build(cls: type, values: Mapping[str, Any]):
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:  # load_config refuses them; a tree edited since must not lose one silently
            raise TypeError(f"unknown config key {', '.join(map(repr, unknown))} in {cls.__name__}; "
                            f"expected one of {', '.join(sorted(known))}")
        out = {}
        for f in fields(cls):
            value = values[f.name]
            if is_dataclass(f.type):
                value = build(f.type, value)
            elif f.type is tuple:
                value = tuple(as_layer(layer) for layer in value)
            out[f.name] = value
        return cls(**out)

    return build(Config, cfg)


# keys of the config's refine section that are the pipeline's, not the refinement's
_PIPELINE_KEYS = ("snapshots",)


def refine_params(cfg: Mapping[str, Any] | Config) -> RefineParams:
    """The refinement's parameters: every key of the config's ``refine`` section but the pipeline's own."""
    section = typed_config(cfg).refine
    return RefineParams(**{f.name: getattr(section, f.name) for f in fields(section) if f.name not in _PIPELINE_KEYS})


#: The types of the sections the code names.
ConfigInput = Config.__dataclass_fields__["input"].type
