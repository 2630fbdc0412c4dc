"""The config's schema: one pydantic model per section, each key declared once.

Every key is a field of a :class:`fields.params.Section` with its type, default,
range and description; the strength layers are a union chosen by ``kind``
(:data:`fields.strength.StrengthLayer`), and the ``refine`` section is the
refinement's own :class:`~fracture.refine.params.RefineParams` with the
pipeline's key added. :func:`validate` turns a merged YAML tree into a
:class:`Config`, or raises :class:`~fracture.errors.ConfigError` naming the
file that set the value, the key path, what was given and what was expected;
:func:`explain` says what a key means (``fracref config --explain`` and the
viewer's tooltips).
"""

from __future__ import annotations

from typing import Any, Callable, Literal, Mapping

from pydantic import BaseModel, Field, ValidationError

from fields.colormap import NAMES as COLORMAPS
from fields.params import (Int3, KeyGrid, Section, Vec3, choice, describe, expected, field_meta, file, flag, folder,
                           int3, integer, key_grid, number, text, vec3)
from fields.strength import LAYER_TYPES, Layer, MarbleLayer, StrengthLayer
from fracture.errors import ConfigError
from fracture.refine.params import RefineParams

Axis = Literal["x", "y", "z"]


class InputSection(Section):
    """The coarse fracture animation to refine."""

    kind: Literal["meshes", "mesh_sequence", "usd", "scene"] = choice(
        "meshes", "meshes: exterior + coarse fracture surface files (no motion); mesh_sequence: per-frame piece "
        "meshes; usd: one USD file of animated pieces; scene: a built-in example")
    scene: Literal["bunny", "branch", "wall", "clay", "jello"] = choice("wall", "scene: which built-in example")
    frames: int = integer(40, 4, 2000, "scene: frames of the coarse animation")
    exterior: str | None = file(None, "mesh file of the exterior surface B (closed)")
    fracture: str | None = file(None, "mesh file of the coarse fracture surface")
    path: str | None = folder(None, "mesh_sequence: folder of per-frame OBJ/PLY files")
    usd: str | None = file(None, "usd: the USD file (a mesh per piece, time-sampled transforms or points, as Blender "
                           "and Houdini write them)")
    glob: str = text("*.obj", "mesh_sequence: file name pattern of the frames (ordered by the number in their names)")
    up_axis: Literal["auto", "x", "y", "z"] = choice(
        "auto", "the axis pointing up (auto: a USD file's own, else the one the pieces fall down; Blender's OBJ "
        "exporter writes y by default; z for meshes, a still object); the viewer's cameras and the USD output use it")
    lattice: int = integer(2, 2, 16, "mesh_sequence: lattice nodes per axis fitted to a piece that deforms")
    separation: float = number(1e-3, 1e-7, 0.5, "distance at which two sides count as separated, relative to the box "
                               "diagonal")


class GridSection(Section):
    """The field grid."""

    resolution: Int3 = int3(50, 4, 1024, "nodes along the longest axis, or [nx, ny, nz] (e.g. [150, 50, 10])")
    min_across: int = integer(8, 0, 1024, "with one resolution number: at least this many nodes across the object's "
                              "thinnest extent (along its principal axes: a plank's thickness); the cells shrink for "
                              "them (0: off)")
    padding: float = number(0.05, 0.0, 1.0, "grid margin around the object, relative to its largest extent")
    max_memory_gb: float = number(8.0, 0.01, 1e5, "refuse a grid whose fields would need more memory than this (GB)")


class StrengthSection(Section):
    """The material strength zeta (Section 4.2)."""

    layers: list[StrengthLayer] = Field(default_factory=lambda: [MarbleLayer()], min_length=1,
                                        description="layers of zeta, each of its kind's type")
    normalize: bool = flag(True, "rescale the summed layers to [0, 1]")


class StressSection(Section):
    """The stress estimate xi (Section 4.3)."""

    length: float = number(0.1, 1e-4, 10.0, "decay length of the stress estimate, relative to the object's box "
                           "diagonal")


class PsiSection(Section):
    """psi = strength_weight zeta - stress_weight xi."""

    strength_weight: float = number(1.0, 0.0, 100.0, "weight of zeta in psi")
    stress_weight: float = number(0.4, 0.0, 100.0, "weight of xi in psi; larger keeps the result closer to the "
                                  "coarse surface")


class PyramidSection(Section):
    """The Gaussian pyramid of psi."""

    levels: int = integer(5, 1, 8, "Gaussian pyramid levels (the paper uses 4 to 6)")
    sigma: float = number(1.0, 0.01, 64.0, "width of level 1 in voxels; doubles per level")


class RefineSection(RefineParams):
    """The refinement's parameters and the pipeline's keys of its stage."""

    snapshots: bool = flag(True, "save every iteration for the viewer (refined/iterations.*)")
    draw: int = integer(0, 0, 2**32 - 1, "which draw of the refinement's random choices (where it splits edges "
                        "and triangles; the material keeps the run's seed): a run whose refined surface yields no "
                        "sound pieces refines again with the next two draws, with a note")

    def params(self) -> RefineParams:
        """The refinement's own parameters (without the pipeline's keys)."""
        return RefineParams(**{k: getattr(self, k) for k in RefineParams.model_fields})


class AnimateSection(Section):
    """The high-resolution pieces and their motion (Section 5)."""

    obj_frames: bool = flag(False, "also write frames/frame_NNNN.obj (one object per piece, faces in the materials "
                            "exterior and interior; the USD file holds every frame already)")
    ply_frames: bool = flag(False, "also write frames/frame_NNNN.ply (all pieces, face property piece)")
    usd: bool = flag(True, "write animation/pieces.usdc: one mesh per piece, points per frame, interior and exterior "
                     "materials (Blender: File > Import > Universal Scene Description)")
    fps: float | None = number(None, 0.1, 1000.0, "frame rate recorded in the USD file; null: the input's (a USD "
                               "file's time codes per second), else 24")
    check_samples: int = integer(20000, 1000, 10_000_000, "random points at which the pieces' winding numbers are "
                                 "checked (their volumes, no overlap); every run checks its pieces")


def _camera(panel: str) -> type[Section]:
    class Camera(Section):
        eye: Vec3 | None = vec3(None, f"{panel} panel: the camera's position; null: fitted")
        center: Vec3 | None = vec3(None, f"{panel} panel: the point looked at")
        up: Vec3 | None = vec3(None, f"{panel} panel: the screen's up")
        fov: float = number(35.0, 1.0, 150.0, f"{panel} panel: vertical field of view in degrees")

    Camera.__name__ = Camera.__qualname__ = f"{panel.title()}Camera"
    Camera.__doc__ = f"The {panel} panel's camera."
    return Camera


MaterialCamera, IterationsCamera, AnimationCamera = (_camera(p) for p in ("material", "iterations", "animation"))


class CamerasSection(Section):
    """Each panel's camera."""

    material: MaterialCamera = Field(default_factory=MaterialCamera)
    iterations: IterationsCamera = Field(default_factory=IterationsCamera)
    animation: AnimationCamera = Field(default_factory=AnimationCamera)


class ViewSection(Section):
    """What ``fracref view`` and ``fracref render`` show first; nothing the pipeline reads."""

    field: Literal["psi", "zeta", "xi"] = choice("psi", "material panel: the field sliced")
    axis: Axis = choice("z", "material panel: the slice's normal axis")
    offset: float = number(0.5, 0.0, 1.0, "material panel: the slice's relative position")
    level: int = integer(0, 0, 64, "material panel: psi's pyramid level (0 = finest)")
    cutaway: bool = flag(False, "material panel: the pieces below the slice")
    iteration: int = integer(-1, -1, doc="iterations panel: the iteration shown (-1: the last)")
    color_by: Literal["psi", "speed"] = choice("psi", "iterations panel: the surface's colours")
    frame: int = integer(1, 1, doc="animation panel: the frame shown (1 = the first)")
    overlay_coarse: bool = flag(False, "animation panel: the coarse pieces see-through")
    cameras: CamerasSection = Field(default_factory=CamerasSection)


class SweepSection(Section):
    """What ``fracref sweep`` runs; nothing a single run reads."""

    grid: KeyGrid = key_grid({}, "config keys and the values a sweep runs (every combination), e.g. "
                             "{psi.stress_weight: [0.2, 0.6, 2], seed: [0, 1, 2]}")


class PreviewSection(Section):
    """The fields stage's preview images."""

    axis: Axis | None = choice(None, "normal of the preview slices; null: the axis with the fewest nodes")
    offset: float = number(0.5, 0.0, 1.0, "relative position of the preview slices")
    colormap: Literal[COLORMAPS] = choice("viridis", "colour map of the preview slices")


class Config(Section):
    """An experiment: every key of every section (a file lists only what it changes)."""

    name: str | None = text(None, "experiment name; null: the config file's name")
    seed: int = integer(0, 0, 2**32 - 1, "seed of every random choice of the run")
    input: InputSection = Field(default_factory=InputSection)
    grid: GridSection = Field(default_factory=GridSection)
    strength: StrengthSection = Field(default_factory=StrengthSection)
    stress: StressSection = Field(default_factory=StressSection)
    psi: PsiSection = Field(default_factory=PsiSection)
    pyramid: PyramidSection = Field(default_factory=PyramidSection)
    refine: RefineSection = Field(default_factory=RefineSection)
    animate: AnimateSection = Field(default_factory=AnimateSection)
    view: ViewSection = Field(default_factory=ViewSection)
    sweep: SweepSection = Field(default_factory=SweepSection)
    preview: PreviewSection = Field(default_factory=PreviewSection)

    def tree(self) -> dict:
        """The config as the plain tree a YAML file holds (what is saved beside a run and hashed)."""
        return self.model_dump(mode="python")


# -- validation --------------------------------------------------------------------------------------------
def _shown(value: Any) -> str:
    if value is None:
        return "null"
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{text} ({type(value).__name__})"


def _section_type(annotation) -> type[Section] | None:
    return annotation if isinstance(annotation, type) and issubclass(annotation, BaseModel) else None


def _is_layers(model: type[BaseModel], name: str) -> bool:
    return model is StrengthSection and name == "layers"


def _layers_expected() -> str:
    return "a list of at least 1 sections, each with kind: one of " + ", ".join(repr(k) for k in LAYER_TYPES)


def _lists(value: Any) -> Any:
    """Tuples as lists (a tree made in code holds tuples where a YAML file has lists)."""
    if isinstance(value, Mapping):
        return {k: _lists(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_lists(v) for v in value]
    return value


def _problem(error: dict, tree: Any, model: type[BaseModel], origin: Callable[[str], str], prefix: str
             ) -> ConfigError:
    """The user's words for one of pydantic's errors: which key, set where, what was given and expected."""
    loc = list(error["loc"])
    key, node, i = prefix, tree, 0

    def join(key: str, part) -> str:
        return f"{key}[{part}]" if isinstance(part, int) else (f"{key}.{part}" if key else str(part))

    while i < len(loc):
        part = loc[i]
        if part not in model.model_fields:  # a key the section does not know
            allowed = ", ".join(sorted(model.model_fields))
            where = join(key, part)
            return ConfigError(origin(where), where, f"unknown key; expected one of: {allowed}")
        key = join(key, part)
        node = node.get(part) if isinstance(node, Mapping) else None
        sub = _section_type(model.model_fields[part].annotation)
        if _is_layers(model, part) and i + 1 < len(loc) and isinstance(loc[i + 1], int):
            index = loc[i + 1]
            item = node[index] if isinstance(node, list) and index < len(node) else None
            key_i = join(key, index)
            if error["type"] == "union_tag_invalid":
                kind = item.get("kind") if isinstance(item, Mapping) else item
                return ConfigError(origin(key_i), f"{key_i}.kind", f"got {_shown(kind)}, expected one of "
                                   + ", ".join(repr(k) for k in LAYER_TYPES))
            if error["type"] in ("union_tag_not_found", "model_attributes_type", "dict_type"):
                return ConfigError(origin(key_i), key_i, f"got {_shown(item)}, expected a section with a 'kind' key")
            # (layers, index, kind, field...): on into the layer's own type; a list is set by one file as a whole
            model, node, key, i = LAYER_TYPES[loc[i + 2]], item, key_i, i + 3
            continue
        if _is_layers(model, part):
            return ConfigError(origin(key), key, f"got {_shown(node)}, expected {_layers_expected()}")
        if sub is not None and i + 1 < len(loc):
            model, i = sub, i + 1
            continue
        if sub is not None:
            return ConfigError(origin(key), key, f"got {_shown(node)}, expected a mapping of keys")
        if error["type"] == "missing":
            return ConfigError(origin(key), key, f"missing, expected {expected(model, part)}")
        if error["type"] == "relation":  # a rule between keys (fields.params.refuse): its own words
            return ConfigError(origin(key), key, f"got {_shown(node)}, expected {error['msg']}")
        return ConfigError(origin(key), key, f"got {_shown(node)}, expected {expected(model, part)}")
    where = prefix or "(top level)"
    return ConfigError(origin(prefix), where, f"got {_shown(tree)}, expected a mapping of keys")


def validate(tree: Any, origin: Callable[[str], str], model: type[Section] = Config, prefix: str = "") -> Section:
    """``tree`` (a merged YAML tree) as ``model``; raises :class:`ConfigError` for the first problem found,
    unknown keys first. ``origin`` maps a dotted key path to the file (or ``--set``) that set it; ``prefix``
    is the tree's own key path in a whole config."""
    tree = _lists(tree)
    if not isinstance(tree, Mapping):
        raise ConfigError(origin(prefix), prefix or "(top level)", f"got {_shown(tree)}, expected a mapping of keys")
    try:
        return model.model_validate(tree)
    except ValidationError as exc:
        errors = sorted(exc.errors(), key=lambda e: e["type"] != "extra_forbidden")
        raise _problem(errors[0], tree, model, origin, prefix) from None


def resolve_paths(section: Section, resolve: Callable[[str, str, str], str], prefix: str = "") -> Section:
    """``section`` with every file and directory path made absolute by ``resolve(key, value, kind)``."""
    update = {}
    for name, f in type(section).model_fields.items():
        value = getattr(section, name)
        key = f"{prefix}.{name}" if prefix else name
        word = field_meta(type(section), name).get("word")
        if word in ("path", "dir") and value is not None:
            update[name] = resolve(key, value, word)
        elif isinstance(value, Section):
            update[name] = resolve_paths(value, resolve, key)
        elif isinstance(value, list) and value and all(isinstance(v, Layer) for v in value):
            update[name] = [resolve_paths(v, lambda _k, v, w, k=key: resolve(k, v, w), f"{key}[{j}]")
                            for j, v in enumerate(value)]
    return section.model_copy(update=update)


def defaults() -> dict:
    """The tree of every default."""
    return Config().tree()


# -- explanations ------------------------------------------------------------------------------------------
def explain(key: str) -> str:
    """What a config key means: its default, what it accepts and its description; for a section (or
    ``strength.layers``, ``strength.layers.KIND``) every key in it, one per line. A strength layer's
    key is named by its kind (``strength.layers.bricks.mortar``). Raises :class:`ConfigError` for an
    unknown key. The viewer's tooltips say the same."""
    parts = [p for p in key.replace("[", ".").replace("]", "").split(".") if p]
    model: type[BaseModel] = Config
    leaf: str | None = None
    layers = False  # at strength.layers, before a kind
    for i, part in enumerate(parts):
        if leaf is not None:
            raise ConfigError("--explain", key, f"unknown key {part!r} after {'.'.join(parts[:i])}")
        if layers and part in LAYER_TYPES:
            model, layers = LAYER_TYPES[part], False
        elif layers and part in Layer.model_fields:
            leaf, model, layers = part, Layer, False
        elif not layers and part in model.model_fields:
            sub = _section_type(model.model_fields[part].annotation)
            if _is_layers(model, part):
                layers = True
            elif sub is not None:
                model = sub
            else:
                leaf = part
        else:
            keys = (list(LAYER_TYPES) + list(Layer.model_fields)) if layers else list(model.model_fields)
            raise ConfigError("--explain", key, f"unknown key {part!r}"
                              + (f" after {'.'.join(parts[:i])}" if i else "")
                              + (f"; expected one of {', '.join(keys)}" if keys else ""))
    name = ".".join(parts)
    if leaf is not None:
        return describe(model, leaf, name)
    if layers:
        return "\n".join([f"{name}: {_layers_expected()}"]
                         + [f"{name}.{kind}: --explain {name}.{kind} lists its keys" for kind in LAYER_TYPES])
    keys = [k for k in model.model_fields if not (issubclass(model, Layer) and k == "kind")]
    return "\n".join(explain(f"{name}.{k}" if name else k) for k in keys)


__all__ = ["Config", "explain", "validate", "resolve_paths", "defaults"]
