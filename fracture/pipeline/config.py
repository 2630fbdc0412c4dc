"""Experiment configs: YAML files layered on shared defaults, validated as a whole.

A config file is a YAML mapping. It may start with a ``defaults`` list of other
config files (paths relative to it, ``.yaml`` optional; a name found nowhere
there is looked up among the package's presets, :mod:`fracture.pipeline.presets`)
that are merged first, in order; the file's own keys are merged on top, then ``--set`` overrides.
Every key has a default in the schema (:class:`~fracture.pipeline.schema.Config`),
so an experiment lists only what it changes. Mappings merge key by key; lists and scalars replace.

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

from fracture.errors import ConfigError
from fracture.pipeline import presets
from fracture.pipeline.schema import Config, defaults, explain, resolve_paths, validate

SET_SOURCE = "--set"


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a key given twice in one mapping (PyYAML keeps the last silently), and
    reading ``1e-3`` as the number YAML 1.2 and every other tool take it for (YAML 1.1, which PyYAML
    follows, wants ``1.0e-3`` and reads ``1e-3`` as a string)."""

    def construct_mapping(self, node, deep=False):
        seen = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # "<<: *base": its keys may be given again here
                continue
            key = self.construct_object(key_node, deep=deep)
            try:
                hash(key)
            except TypeError:  # "? [a, b]": YAML allows it, a config has names
                raise yaml.constructor.ConstructorError(
                    None, None, f"a key is a {type(key).__name__}; expected a name", key_node.start_mark) from None
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"key {key!r} given twice (first on line {seen[key] + 1}); expected each key once",
                    key_node.start_mark)
            seen[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep)

    def get_single_data(self):
        node = self.get_single_node()
        if node is None:
            return None
        if _expanded_size(node) > _MOST_NODES:  # aliases of aliases: a small file of billions of values
            raise yaml.constructor.ConstructorError(
                None, None, f"its aliases expand to more than {_MOST_NODES:,} values; expected a config",
                node.start_mark)
        return self.construct_document(node)


# Values a config file may expand to through its aliases (configs hold hundreds).
_MOST_NODES = 1_000_000

# A number in scientific notation without a decimal point (1e-3, -2E5): a float, as YAML 1.2 reads it. The
# resolver is added to the loader's own copy of the table (PyYAML copies it for a subclass), not SafeLoader's.
_UniqueKeyLoader.add_implicit_resolver("tag:yaml.org,2002:float", re.compile(r"^[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+$"),
                                       list("-+0123456789"))


def load_yaml(text: str) -> Any:
    """YAML text as the config files are read (:class:`_UniqueKeyLoader`): safe, each key once, ``1e-3`` a
    number."""
    return yaml.load(text, Loader=_UniqueKeyLoader)


def _expanded_size(node, sizes: dict | None = None) -> int:
    """How many values a YAML node stands for with its aliases expanded (each node's size counted once); a
    ConstructorError for a node that holds itself (``a: &x [*x]``: a value with no end)."""
    sizes = {} if sizes is None else sizes
    if id(node) in sizes:
        if sizes[id(node)] is None:  # still being counted: reached again from within itself
            raise yaml.constructor.ConstructorError(
                None, None, "a value holds itself through an alias; expected a config of plain values", node.start_mark)
        return sizes[id(node)]
    sizes[id(node)] = None
    if isinstance(node, yaml.SequenceNode):
        n = 1 + sum(_expanded_size(child, sizes) for child in node.value)
    elif isinstance(node, yaml.MappingNode):
        n = 1 + sum(_expanded_size(k, sizes) + _expanded_size(v, sizes) for k, v in node.value)
    else:
        n = 1
    sizes[id(node)] = n
    return n



def read_yaml(path: Path) -> dict:
    """Read one YAML mapping safely, with errors that name the file and line."""
    if path.is_dir():
        raise ConfigError(str(path), "", "is a directory; expected a YAML config file (configs/example.yaml, say)")
    if not path.is_file():
        raise ConfigError(str(path), "", "config file not found")
    try:
        data = load_yaml(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark is not None else str(path)
        problem = getattr(exc, "problem", None) or str(exc)
        raise ConfigError(where, "", f"invalid YAML: {problem}") from None
    except UnicodeDecodeError:
        raise ConfigError(str(path), "", "not a UTF-8 text file") from None
    except RecursionError:  # thousands of nested brackets: PyYAML's parser recurses
        raise ConfigError(str(path), "", "nests values too deeply to be read; expected a config") from None
    if data is None:  # read as all defaults, a run would fail far from here, not naming the file
        raise ConfigError(str(path), "", "holds no settings (the file is empty or only comments); expected a mapping "
                          "of keys (configs/example.yaml, say)")
    if not isinstance(data, dict):
        raise ConfigError(str(path), "", f"top level is a {type(data).__name__}, expected a mapping of keys")
    return data


class _Merged:
    """A config tree being merged, with the source of every key path."""

    def __init__(self):
        self.tree: dict = defaults()
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
        """The source of ``key``: the file that set it, else the last that set a key inside it (a section a file
        filled in part), else so for its closest parent."""
        while key:
            if key in self.origins:
                return self.origins[key]
            inner = [s for k, s in self.origins.items() if k.startswith((key + ".", key + "["))]
            if inner:
                return inner[-1]
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
        if not Path(item).name:  # "", "/", ".": no file
            raise ConfigError(str(path), "defaults", f"got {item!r}, expected the path of a config file or a preset's "
                              f"name: {', '.join(presets.names())}")
        target = path.parent / item
        if target.suffix not in (".yaml", ".yml"):
            target = target.with_name(target.name + ".yaml")
        if not target.is_file():  # a preset of the package (fracture/pipeline/presets.py)
            target = presets.find(item) or target
        if not target.is_file():
            raise ConfigError(str(path), "defaults", f"included config {item!r} not found (looked for {target} and "
                              f"for a preset of that name); expected a file or one of the presets: "
                              f"{', '.join(presets.names())}")
        _collect(target, merged, stack + (path,))
    merged.merge(data, str(path))


_KEY_TOKEN = re.compile(r"([^.\[\]]+)|\[(\d+)\]")


def parse_override(text: str) -> tuple[list[str | int], Any]:
    """Split ``key.path[0].name=value`` into key tokens and a YAML-parsed value."""
    if "=" not in text:
        raise ConfigError(SET_SOURCE, "", f"got {text!r}, expected key.path=value")
    key, raw = text.split("=", 1)
    key = key.strip()  # "psi.stress_weight = 2", as one writes it in YAML
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
        value = load_yaml(raw) if raw.strip() else None
    except yaml.YAMLError:
        # not YAML (a glob such as *.ply: a star starts an alias): the words as they are; the schema then says
        # whether a string may go there
        if raw.lstrip().startswith(("[", "{")):  # a list or mapping that does not parse is a mistake, not words
            raise ConfigError(SET_SOURCE, key, f"cannot parse the value {raw!r} as YAML") from None
        value = raw
    return tokens, value


def _apply_override(merged: _Merged, text: str) -> None:
    tokens, value = parse_override(text)
    source = f"{SET_SOURCE} {text}"
    node: Any = merged.tree
    path = ""
    for i, tok in enumerate(tokens):
        last = i == len(tokens) - 1
        parent = path  # the key that holds ``node``
        path = f"{path}[{tok}]" if isinstance(tok, int) else (f"{path}.{tok}" if path else tok)
        if isinstance(tok, int):
            if not isinstance(node, list) or not -len(node) <= tok < len(node):
                raise ConfigError(source, path, "no such list item")
        elif isinstance(node, list):  # layers.2.ratio for layers[2].ratio
            example = f"{parent}[{tok}]" if tok.isdigit() else f"{parent}[0]"
            raise ConfigError(source, path, f"{parent} is a list; name an item of it by its index in brackets, "
                              f"e.g. {example}")
        elif not isinstance(node, dict):
            raise ConfigError(source, path, f"{parent} is a value ({node!r}), not a mapping: it has no key {tok!r}")
        if last:
            node[tok] = value
            merged.origins[path] = source
        else:
            if isinstance(tok, str) and tok not in node:
                node[tok] = {}
                merged.origins[path] = source  # a key the override made: an error about it names the override
            node = node[tok]


def load_config(path: str | Path, overrides: Iterable[str] = ()) -> Config:
    """Load, merge and validate an experiment config.

    Parameters
    ----------
    path : str or Path
        The experiment's YAML file.
    overrides : iterable of str
        ``key.path=value`` strings (values parsed as YAML), applied last.

    Returns
    -------
    Config
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


def check_config(tree: dict, source: str) -> Config:
    """Validate a whole config that is not in a file (e.g. edited in the viewer) as :func:`load_config` would.

    Errors name ``source``; relative paths resolve against the working directory.
    """
    merged = _Merged()
    merged.merge(tree, source)
    return _finish(merged, "config", in_files=False)


def _finish(merged: _Merged, name: str, in_files: bool = True) -> Config:
    """Validate a merged tree: types and ranges, paths made absolute, the cross-key checks, ``name`` filled in."""

    def resolve(key: str, value: str, kind: str) -> str:
        source = merged.origin(key)
        from_cwd = not in_files or source.startswith(SET_SOURCE) or source == "defaults"
        target = ((Path.cwd() if from_cwd else Path(source).parent) / value).resolve()
        if kind == "dir" and not target.is_dir():
            what = "a file, expected a directory" if target.is_file() else "directory not found"
            raise ConfigError(source, key, f"{what}: {value!r} (resolved to {target})")
        if kind == "path" and not target.is_file():
            what = "a directory, expected a file" if target.is_dir() else "file not found"
            raise ConfigError(source, key, f"{what}: {value!r} (resolved to {target})")
        return str(target)

    cfg = resolve_paths(validate(merged.tree, merged.origin), resolve)
    if cfg.input.kind == "mesh_sequence" and cfg.input.path is None:
        raise ConfigError(merged.origin("input.kind"), "input.path",
                          "input.kind is mesh_sequence, expected input.path: the folder of frame files")
    if cfg.input.kind == "usd" and cfg.input.usd is None:
        raise ConfigError(merged.origin("input.kind"), "input.usd",
                          "input.kind is usd, expected input.usd: the USD file of the animated pieces")
    if cfg.name is None:
        cfg = cfg.model_copy(update={"name": name})
    elif not _plain_name(cfg.name):
        raise ConfigError(merged.origin("name"), "name", f"{cfg.name!r} is not a plain name (runs go to "
                          "runs/<name>); expected letters, digits, '.', '-' or '_', no path separators; use --out "
                          "for another directory")
    return cfg


def _plain_name(name: str) -> bool:
    return bool(re.fullmatch(r"[\w.\-]+", name)) and name not in (".", "..")


def dump_config(cfg: Config | dict) -> str:
    """The resolved config as YAML that :func:`load_config` reads back unchanged."""
    tree = cfg.tree() if isinstance(cfg, Config) else cfg
    return yaml.safe_dump(tree, sort_keys=False, default_flow_style=None, width=100)


__all__ = ["Config", "check_config", "dump_config", "explain", "load_config", "parse_override", "read_yaml"]
