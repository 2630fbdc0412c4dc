"""Experiment configs: YAML files layered on shared defaults, validated as a whole.

A config file is a YAML mapping. It may start with a ``defaults`` list of other
config files (paths relative to it, ``.yaml`` optional) that are merged first,
in order; the file's own keys are merged on top, then ``--set`` overrides.
Every key has a default in :data:`SCHEMA`, so an experiment lists only what it
changes. Mappings merge key by key; lists and scalars replace.

Loading validates everything before anything runs: an unknown key, a wrong type
or an out-of-range value raises :class:`~fracture.errors.ConfigError` naming
the file that set the value, the key path, what was given and what was
expected. YAML is read with ``yaml.safe_load`` (no object construction), and
paths are relative to the file that sets them.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Iterable

import yaml

from fields.colormap import NAMES as COLORMAPS
from fields.strength import KINDS, LAYER_COMMON
from fracture.refine.params import described_fields
from fracture.errors import ConfigError
from fracture.pipeline.schema import Layers, Param, schema_defaults, validate

SET_SOURCE = "--set"

SCHEMA: dict[str, Any] = {
    "name": Param(None, "str", nullable=True, doc="experiment name; null: the config file's name"),
    "seed": Param(0, "int", lo=0, hi=2**32 - 1, doc="seed of every random choice of the run"),
    "input": {
        "kind": Param("meshes", "str", choices=("meshes", "mesh_sequence", "usd", "scene"),
                      doc="meshes: exterior + coarse fracture surface files (no motion); mesh_sequence: "
                          "per-frame piece meshes; usd: one USD file of animated pieces; scene: a built-in example"),
        "scene": Param("wall", "str", choices=("bunny", "branch", "wall", "clay", "jello"),
                       doc="scene: which built-in example"),
        "frames": Param(40, "int", lo=4, hi=2000, doc="scene: frames of the coarse animation"),
        "exterior": Param(None, "path", nullable=True, doc="mesh file of the exterior surface B (closed)"),
        "fracture": Param(None, "path", nullable=True, doc="mesh file of the coarse fracture surface"),
        "path": Param(None, "dir", nullable=True, doc="mesh_sequence: folder of per-frame OBJ/PLY files"),
        "usd": Param(None, "path", nullable=True, doc="usd: the USD file (a mesh per piece, time-sampled transforms "
                     "or points, as Blender and Houdini write them)"),
        "glob": Param("*.obj", "str", doc="mesh_sequence: file name pattern of the frames (ordered by the number in their names)"),
        "up_axis": Param("auto", "str", choices=("auto", "x", "y", "z"),
                         doc="the axis pointing up (auto: a USD file's own, else the one the pieces fall down; "
                             "Blender's OBJ exporter writes y by default; z for meshes, a still object); the "
                             "viewer's cameras and the USD output use it"),
        "lattice": Param(2, "int", lo=2, hi=16,
                         doc="mesh_sequence: lattice nodes per axis fitted to a piece that deforms"),
        "separation": Param(1e-3, lo=1e-7, hi=0.5,
                            doc="distance at which two sides count as separated, relative to the box diagonal"),
    },
    "grid": {
        "resolution": Param(50, "int3", lo=4, hi=1024,
                            doc="nodes along the longest axis, or [nx, ny, nz] (e.g. [150, 50, 10])"),
        "padding": Param(0.05, lo=0.0, hi=1.0, doc="grid margin around the object, relative to its largest extent"),
        "max_memory_gb": Param(8.0, lo=0.01, hi=1e5,
                               doc="refuse a grid whose fields would need more memory than this (GB)"),
    },
    "strength": {
        "layers": Layers(
            kinds={name: {k: Param(*p) for k, p in spec.items()} for name, (_, spec) in KINDS.items()},
            common={k: Param(*p) for k, p in LAYER_COMMON.items()},
            default=({"kind": "marble"},),
        ),
        "normalize": Param(True, "bool", doc="rescale the summed layers to [0, 1]"),
    },
    "stress": {
        "length": Param(0.1, lo=1e-4, hi=10.0,
                        doc="decay length of the stress estimate, relative to the object's box diagonal"),
    },
    "psi": {
        "strength_weight": Param(1.0, lo=0.0, hi=100.0, doc="weight of zeta in psi"),
        "stress_weight": Param(0.4, lo=0.0, hi=100.0,
                               doc="weight of xi in psi; larger keeps the result closer to the coarse surface"),
    },
    "pyramid": {
        "levels": Param(5, "int", lo=1, hi=8, doc="Gaussian pyramid levels (the paper uses 4 to 6)"),
        "sigma": Param(1.0, lo=0.01, hi=64.0, doc="width of level 1 in voxels; doubles per level"),
    },
    "refine": {
        **{name: (Param(default, "str", choices=m["choices"], doc=m["doc"]) if kind is str else
                  Param(default, "int" if kind is int else "float", lo=m["lo"], hi=m["hi"], doc=m["doc"]))
           for name, kind, default, m in described_fields()},  # the code's own parameter type
        "snapshots": Param(True, "bool", doc="save every iteration for the viewer (refined/iterations.*)"),
    },
    "animate": {
        "obj_frames": Param(False, "bool", doc="also write frames/frame_NNNN.obj (one object per piece, faces in "
                            "the materials exterior and interior; the USD file holds every frame already)"),
        "ply_frames": Param(False, "bool", doc="also write frames/frame_NNNN.ply (all pieces, face property piece)"),
        "usd": Param(True, "bool", doc="write animation/pieces.usdc: one mesh per piece, points per frame, "
                     "interior and exterior materials (Blender: File > Import > Universal Scene Description)"),
        "fps": Param(24.0, lo=0.1, hi=1000.0, doc="frame rate recorded in the USD file"),
        "check_samples": Param(20000, "int", lo=1000, hi=10_000_000,
                               doc="random points at which the pieces' winding numbers are checked (their volumes, "
                                   "no overlap); every run checks its pieces"),
    },
    "view": {  # what `fracref view` and `fracref render` show first; nothing the pipeline reads
        "field": Param("psi", "str", choices=("psi", "zeta", "xi"), doc="material panel: the field sliced"),
        "axis": Param("z", "str", choices=("x", "y", "z"), doc="material panel: the slice's normal axis"),
        "offset": Param(0.5, lo=0.0, hi=1.0, doc="material panel: the slice's relative position"),
        "level": Param(0, "int", lo=0, hi=64, doc="material panel: psi's pyramid level (0 = finest)"),
        "cutaway": Param(False, "bool", doc="material panel: the pieces below the slice"),
        "iteration": Param(-1, "int", lo=-1, doc="iterations panel: the iteration shown (-1: the last)"),
        "color_by": Param("psi", "str", choices=("psi", "speed"), doc="iterations panel: the surface's colours"),
        "frame": Param(1, "int", lo=1, doc="animation panel: the frame shown (1 = the first)"),
        "overlay_coarse": Param(False, "bool", doc="animation panel: the coarse pieces see-through"),
        "cameras": {panel: {
            "eye": Param(None, "vec3", nullable=True, doc=f"{panel} panel: the camera's position; null: fitted"),
            "center": Param(None, "vec3", nullable=True, doc=f"{panel} panel: the point looked at"),
            "up": Param(None, "vec3", nullable=True, doc=f"{panel} panel: the screen's up"),
            "fov": Param(35.0, lo=1.0, hi=150.0, doc=f"{panel} panel: vertical field of view in degrees"),
        } for panel in ("material", "iterations", "animation")},
    },
    "sweep": {  # what `fracref sweep` runs; nothing a single run reads
        "grid": Param({}, "grid", doc="config keys and the values a sweep runs (every combination), e.g. "
                      "{psi.stress_weight: [0.2, 0.6, 2], seed: [0, 1, 2]}"),
    },
    "preview": {
        "axis": Param(None, "str", choices=("x", "y", "z"), nullable=True,
                      doc="normal of the preview slices; null: the axis with the fewest nodes"),
        "offset": Param(0.5, lo=0.0, hi=1.0, doc="relative position of the preview slices"),
        "colormap": Param("viridis", "str", choices=COLORMAPS),
    },
}


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a key given twice in one mapping (PyYAML keeps the last silently)."""

    def construct_mapping(self, node, deep=False):
        seen = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"key {key!r} given twice (first on line {seen[key] + 1}); expected each key once",
                    key_node.start_mark)
            seen[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep)



def read_yaml(path: Path) -> dict:
    """Read one YAML mapping safely, with errors that name the file and line."""
    if not path.is_file():
        raise ConfigError(str(path), "", "config file not found")
    try:
        data = yaml.load(path.read_text(encoding="utf-8"), Loader=_UniqueKeyLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark is not None else str(path)
        problem = getattr(exc, "problem", None) or str(exc)
        raise ConfigError(where, "", f"invalid YAML: {problem}") from None
    except UnicodeDecodeError:
        raise ConfigError(str(path), "", "not a UTF-8 text file") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(str(path), "", f"top level is a {type(data).__name__}, expected a mapping of keys")
    return data


class _Merged:
    """A config tree being merged, with the source of every key path."""

    def __init__(self):
        self.tree: dict = schema_defaults(SCHEMA)
        self.origins: dict[str, str] = {}

    def merge(self, update: dict, source: str, prefix: str = "", into: dict | None = None) -> None:
        into = self.tree if into is None else into
        for key, value in update.items():
            path = f"{prefix}.{key}" if prefix else str(key)
            if isinstance(value, dict) and isinstance(into.get(key), dict):
                self.merge(value, source, path, into[key])
            else:
                into[key] = value
                self.origins[path] = source
                for sub in [p for p in self.origins if p.startswith(path + ".") or p.startswith(path + "[")]:
                    self.origins[sub] = source

    def origin(self, key: str) -> str:
        """The source of ``key``: the file that set it or its closest parent."""
        while key:
            if key in self.origins:
                return self.origins[key]
            key = re.sub(r"(\.[^.\[]*|\[\d+\])$", "", key) if ("." in key or "[" in key) else ""
        return "defaults"


def _collect(path: Path, merged: _Merged, stack: tuple[Path, ...]) -> None:
    path = path.resolve()
    if path in stack:
        chain = " -> ".join(str(p) for p in stack + (path,))
        raise ConfigError(str(stack[-1]), "defaults", f"cycle of defaults: {chain}")
    data = read_yaml(path)
    includes = data.pop("defaults", [])
    if isinstance(includes, str):
        includes = [includes]
    if not isinstance(includes, list) or not all(isinstance(i, str) for i in includes):
        raise ConfigError(str(path), "defaults", f"got {includes!r}, expected a list of config file paths")
    for item in includes:
        target = path.parent / item
        if target.suffix not in (".yaml", ".yml"):
            target = target.with_name(target.name + ".yaml")
        if not target.is_file():
            raise ConfigError(str(path), "defaults", f"included config {item!r} not found (looked for {target})")
        _collect(target, merged, stack + (path,))
    merged.merge(data, str(path))


_KEY_TOKEN = re.compile(r"([^.\[\]]+)|\[(\d+)\]")


def parse_override(text: str) -> tuple[list[str | int], Any]:
    """Split ``key.path[0].name=value`` into key tokens and a YAML-parsed value."""
    if "=" not in text:
        raise ConfigError(SET_SOURCE, "", f"got {text!r}, expected key.path=value")
    key, raw = text.split("=", 1)
    tokens: list[str | int] = []
    pos = 0
    for m in _KEY_TOKEN.finditer(key):
        if m.start() != pos and key[pos:m.start()] != ".":
            break
        tokens.append(m.group(1) if m.group(1) is not None else int(m.group(2)))
        pos = m.end()
    if not key or pos != len(key) or not tokens or not isinstance(tokens[0], str):
        raise ConfigError(SET_SOURCE, key, f"got {text!r}, expected key.path=value (e.g. psi.stress_weight=2)")
    try:
        value = yaml.safe_load(raw) if raw.strip() else None
    except yaml.YAMLError:
        raise ConfigError(SET_SOURCE, key, f"cannot parse the value {raw!r} as YAML") from None
    return tokens, value


def _apply_override(merged: _Merged, text: str) -> None:
    tokens, value = parse_override(text)
    source = f"{SET_SOURCE} {text}"
    node: Any = merged.tree
    path = ""
    for i, tok in enumerate(tokens):
        last = i == len(tokens) - 1
        path = f"{path}[{tok}]" if isinstance(tok, int) else (f"{path}.{tok}" if path else tok)
        if isinstance(tok, int):
            if not isinstance(node, list) or not -len(node) <= tok < len(node):
                raise ConfigError(source, path, "no such list item")
        elif not isinstance(node, dict):
            raise ConfigError(source, path, "the parent key is not a mapping")
        if last:
            node[tok] = value
            merged.origins[path] = source
        else:
            if isinstance(tok, str) and tok not in node:
                node[tok] = {}
            node = node[tok]


def load_config(path: str | Path, overrides: Iterable[str] = ()) -> dict:
    """Load, merge and validate an experiment config.

    Parameters
    ----------
    path : str or Path
        The experiment's YAML file.
    overrides : iterable of str
        ``key.path=value`` strings (values parsed as YAML), applied last.

    Returns
    -------
    dict
        The fully resolved config: every key present, paths absolute,
        ``name`` filled in.

    Raises
    ------
    ConfigError
        On any problem, before anything is written.
    """
    path = Path(path)
    merged = _Merged()
    _collect(path, merged, ())
    for text in overrides:
        _apply_override(merged, text)
    return _finish(merged, path.stem)


def check_config(tree: dict, source: str) -> dict:
    """Validate a whole config that is not in a file (e.g. edited in the viewer) as :func:`load_config` would.

    Errors name ``source``; relative paths resolve against the working directory.
    """
    merged = _Merged()
    merged.merge(tree, source)
    return _finish(merged, "config", in_files=False)


def _finish(merged: _Merged, name: str, in_files: bool = True) -> dict:
    """Validate a merged tree: types and ranges, paths made absolute, the cross-key checks, ``name`` filled in."""

    def resolve(key: str, value: str, kind: str) -> str:
        source = merged.origin(key)
        from_cwd = not in_files or source.startswith(SET_SOURCE) or source == "defaults"
        target = ((Path.cwd() if from_cwd else Path(source).parent) / value).resolve()
        if kind == "dir" and not target.is_dir():
            raise ConfigError(source, key, f"directory not found: {value!r} (resolved to {target})")
        if kind == "path" and not target.is_file():
            raise ConfigError(source, key, f"file not found: {value!r} (resolved to {target})")
        return str(target)

    cfg = validate(merged.tree, SCHEMA, merged.origin, resolve)
    if cfg["input"]["kind"] == "mesh_sequence" and cfg["input"]["path"] is None:
        raise ConfigError(merged.origin("input.kind"), "input.path",
                          "input.kind is mesh_sequence, expected input.path: the folder of frame files")
    if cfg["input"]["kind"] == "usd" and cfg["input"]["usd"] is None:
        raise ConfigError(merged.origin("input.kind"), "input.usd",
                          "input.kind is usd, expected input.usd: the USD file of the animated pieces")
    if cfg["name"] is None:
        cfg["name"] = name
    elif not _plain_name(cfg["name"]):
        raise ConfigError(merged.origin("name"), "name", f"{cfg['name']!r} is not a plain name (runs go to "
                          "runs/<name>); expected letters, digits, '.', '-' or '_', no path separators; use --out "
                          "for another directory")
    return cfg


def _plain_name(name: str) -> bool:
    return bool(re.fullmatch(r"[\w.\-]+", name)) and name not in (".", "..")


def dump_config(cfg: dict) -> str:
    """The resolved config as YAML that :func:`load_config` reads back unchanged."""
    return yaml.safe_dump(cfg, sort_keys=False, default_flow_style=None, width=100)


def explain(key: str) -> str:
    """What a config key means: its default, what it accepts and its description; for a section (or
    ``strength.layers``, ``strength.layers.KIND``) every key in it, one per line. A strength layer's
    key is named by its kind (``strength.layers.bricks.mortar``). Raises :class:`ConfigError` for an
    unknown key. The viewer's tooltips say the same."""
    parts = [p for p in key.replace("[", ".").replace("]", "").split(".") if p]
    node: Any = SCHEMA
    for i, part in enumerate(parts):
        if isinstance(node, Layers) and part in node.kinds:
            node = {**node.common, **node.kinds[part]}
        elif isinstance(node, Layers) and part in node.common:
            node = node.common[part]
        elif isinstance(node, dict) and part in node:
            node = node[part]
        else:
            keys = list(node.kinds) + list(node.common) if isinstance(node, Layers) else list(node) if isinstance(
                node, dict) else []
            raise ConfigError("--explain", key, f"unknown key {part!r}"
                              + (f" after {'.'.join(parts[:i])}" if i else "")
                              + (f"; expected one of {', '.join(keys)}" if keys else ""))
    name = ".".join(parts)
    if isinstance(node, Param):
        return _explain_param(name, node)
    if isinstance(node, Layers):
        return "\n".join([f"{name}: {node.expected()}"]
                         + [f"{name}.{kind}: --explain {name}.{kind} lists its keys" for kind in node.kinds])
    return "\n".join(explain(f"{name}.{k}" if name else k) for k in node)


def _explain_param(name: str, p: Param) -> str:
    text = f"{name} = {p.default!r}: {p.expected()}"
    return text + (f". {p.doc[0].upper()}{p.doc[1:]}" if p.doc else "")
