"""Procedural material strength fields zeta(x) (Section 4.2).

Every kind is a function ``kind(U, frame, rng, **params) -> (n,) float`` of
points in *unit coordinates* ``U = (X - lo) / L``, where ``lo`` is the low
corner of the object's bounding box and ``L`` its largest extent (both in
``frame``, a :class:`UnitFrame`): lengths and frequencies in
the parameters are relative to the object size, so a preset works on any mesh.
High values are strong material, low values weak. ``rng`` is a
``numpy.random.Generator`` derived from the run seed; it decides noise offsets
and random placements, so a seed reproduces a field exactly.

:data:`KINDS` registers each kind with its function and the type of its
layers (a :class:`fields.params.Section`: its parameters' defaults, ranges and
descriptions, which the config validates ``strength.layers`` with); a layer is
one of a union chosen by ``kind`` (:data:`StrengthLayer`), what
:func:`strength_field` takes.
"""

from __future__ import annotations

from pathlib import Path
from dataclasses import dataclass
from typing import Annotated, Any, Callable, Literal, Mapping, Union

import noise
import numpy as np
from pydantic import Field, TypeAdapter, ValidationInfo, field_validator

from fields.grid import Grid
from fields.interpolate import trilinear
from fields.errors import InputError
from fields.npy import is_npy
from fields.params import (Bounds, Section, Vec3, bounds, choice, file, integer, number, parameters, refuse, text,
                           vec3)
from fields.tolerances import tol

_AXES = ("x", "y", "z")
# Offsets into the Perlin lattice are drawn below this (the noise package
# repeats every 1024 lattice units).
_NOISE_OFFSET_RANGE = 256.0


@dataclass(frozen=True)
class UnitFrame:
    """The object's bounding box ``[lo, hi]``, mapping material points ``X`` to
    unit coordinates ``U = (X - lo) / L`` with ``L`` the largest extent."""

    lo: np.ndarray
    hi: np.ndarray

    @property
    def L(self) -> float:
        return float((self.hi - self.lo).max())

    @property
    def extent(self) -> np.ndarray:
        """The box's extent in unit coordinates (largest component 1)."""
        return (self.hi - self.lo) / self.L

    def to_unit(self, X: np.ndarray) -> np.ndarray:
        return (np.asarray(X, np.float64) - self.lo) / self.L

    def to_material(self, U: np.ndarray) -> np.ndarray:
        return self.lo + np.asarray(U, np.float64) * self.L


def perlin(U: np.ndarray, frequency, rng: np.random.Generator, octaves: int = 1,
           persistence: float = 0.5, lacunarity: float = 2.0) -> np.ndarray:
    """Perlin (fBm) noise of the ``noise`` package at points.

    Parameters
    ----------
    U : (n, 3) float
        Points in unit coordinates.
    frequency : float or (3,) float
        Lattice cells per unit length, per axis (anisotropic noise).
    rng : numpy.random.Generator
        Draws the lattice offset, which plays the role of the seed.
    octaves, persistence, lacunarity : fBm parameters.

    Returns
    -------
    (n,) float
        Roughly in [-1, 1], zero mean.

    Notes
    -----
    ``noise.pnoise3`` takes one point per call; a generator over the points
    is fine for fields sampled once per run (``benchmarks/bench_fields.py``).
    """
    offset = rng.uniform(0.0, _NOISE_OFFSET_RANGE, 3)
    Q = np.asarray(U, np.float64) * np.asarray(frequency, np.float64) + offset
    f = noise.pnoise3
    return np.fromiter(
        (f(x, y, z, octaves, persistence, lacunarity) for x, y, z in Q.tolist()),
        dtype=np.float64,
        count=Q.shape[0],
    )


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _axis(name: str) -> int:
    return _AXES.index(name)


def marble(U, frame, rng, *, vein_frequency, vein_direction, turbulence, turbulence_frequency, hard_fraction,
           edge_width, hard_strength, grain_frequency, grain_octaves, grain_contrast, soft_strength,
           soft_frequency, soft_contrast):
    """Marble: a hard body of fine grains crossed by smooth, soft veins (Figure 1).

    A turbulent sine ``t = sin(2 pi f (u . d) + a * fbm(u))`` splits space
    into a hard region (``t`` above a threshold chosen so that about
    ``hard_fraction`` of space is hard; the paper's blue region) filled with
    high-frequency, multi-octave noise, and soft veins (the white region)
    filled with low-frequency noise. With most of the stone hard, the veins
    are thin bands that cracks follow.
    """
    d = np.asarray(vein_direction, np.float64)
    d = d / max(np.linalg.norm(d), tol.zero)
    turb = perlin(U, turbulence_frequency, rng, octaves=4)
    t = np.sin(2.0 * np.pi * vein_frequency * (U @ d) + turbulence * turb)
    threshold = np.cos(np.pi * hard_fraction)  # P(sin > threshold) = hard_fraction for a uniform phase
    mask = smoothstep(threshold - edge_width, threshold + edge_width, t)
    hard = hard_strength + grain_contrast * perlin(U, grain_frequency, rng, octaves=grain_octaves)
    soft = soft_strength + soft_contrast * perlin(U, soft_frequency, rng)
    return mask * hard + (1.0 - mask) * soft


def elongated(U, frame, rng, *, axis, frequency, stretch, octaves, mean, contrast):
    """Noise stretched along an axis (wood grain, the tree branch).

    The lattice frequency along ``axis`` is ``frequency / stretch``: features
    are ``stretch`` times longer along the axis than across it, so fracture
    surfaces prefer to run along it.
    """
    freq = np.full(3, float(frequency))
    freq[_axis(axis)] /= stretch
    return mean + contrast * perlin(U, freq, rng, octaves=octaves)


def fibres(U, frame, rng, *, axis, bundle_size, interface_width, interface_strength, bundle_strength,
           defect_length, defect_contrast):
    """Wood as bundles of fibres along an axis, with weak interfaces between them (the tree branch, Figure 9).

    The bundles are the Voronoi cells of a jittered lattice of seeds of spacing ``bundle_size`` in the
    section across ``axis`` (a cell is a bundle, constant along the axis). With ``d`` the distance to the
    bisector between a point's nearest and second nearest seeds (the interface),
    ``zeta = base - (base - interface_strength) * exp(-(d / interface_width)^2)``, where
    ``base = bundle_strength + defect_contrast * n_k(u)`` varies along the axis by each bundle's own noise
    ``n_k`` (its lattice offset drawn per bundle) with features ``defect_length`` long: every bundle has its
    weak places at other heights. A crack that crosses each bundle where it is weakest and runs between
    them along the weak interfaces is a splintered one.
    """
    from scipy.spatial import cKDTree

    a = _axis(axis)
    across = [i for i in range(3) if i != a]
    extent = frame.extent[across]
    n = np.ceil(extent / bundle_size).astype(int) + 3
    ii, jj = np.meshgrid(np.arange(n[0]) - 1.0, np.arange(n[1]) - 1.0, indexing="ij")
    lattice = np.column_stack([ii.ravel(), jj.ravel()])
    seeds = (lattice + rng.uniform(0.0, 1.0, lattice.shape)) * bundle_size
    Q = U[:, across]
    dist, nearest = cKDTree(seeds).query(Q, k=2)
    s0, s1 = seeds[nearest[:, 0]], seeds[nearest[:, 1]]
    gap = np.maximum(np.linalg.norm(s1 - s0, axis=1), tol.zero)
    d = (dist[:, 1] ** 2 - dist[:, 0] ** 2) / (2.0 * gap)  # to the bisector of the two nearest seeds
    offsets = rng.uniform(0.0, _NOISE_OFFSET_RANGE, (len(seeds), 2))
    k = nearest[:, 0]
    phase = np.column_stack([U[:, a] / defect_length, offsets[k]])
    defect = perlin(phase, 1.0, rng, octaves=2)
    base = bundle_strength + defect_contrast * defect
    return base - (base - interface_strength) * np.exp(-((d / interface_width) ** 2))


def radial(U, frame, rng, *, axis, center, radius, inner, outer, exponent):
    """Strength growing with the distance from an axis: soft core, hard shell.

    ``zeta = inner + (outer - inner) * min(r / R, 1) ** exponent`` with ``r``
    the distance from the line through ``center`` along ``axis``. ``center``
    defaults to the middle of the box and ``R`` to half its smaller extent
    across the axis (the radius of an inscribed cylinder).
    """
    a = _axis(axis)
    extent = frame.extent
    across = [i for i in range(3) if i != a]
    c = 0.5 * np.asarray(extent) if center is None else np.asarray(center, np.float64)
    R = 0.5 * min(extent[i] for i in across) if radius is None else radius
    r = np.linalg.norm(U[:, across] - c[across], axis=1) / max(R, tol.zero)
    return inner + (outer - inner) * np.minimum(r, 1.0) ** exponent


def grain(U, frame, rng, *, fibres, axis, center, ratio, path, bounds):
    """Grain (:mod:`fields.grain`): fibres along or around an axis that make a crack across them ``ratio``
    times dearer than one along them. It adds nothing to zeta (its weight does not matter): the fields
    take it out of the layers with :func:`grain_of`."""
    return np.zeros(U.shape[0])


def bricks(U, frame, rng, *, length_axis, height_axis, brick_length, brick_height, mortar, brick_strength,
           mortar_strength, interface_strength, interface_width, noise_contrast, noise_frequency):
    """Running-bond brick wall: strong bricks and mortar, weak interfaces (Figure 10).

    Cells of ``brick_length`` x ``brick_height`` (unit coordinates) are laid
    along ``length_axis`` in courses along ``height_axis``, every other
    course shifted by half a brick. Each cell has a mortar joint of width
    ``mortar`` on its low sides. With ``d`` the distance to the nearest
    brick-mortar interface inside the cell,
    ``zeta = base - (base - interface_strength) * exp(-(d / interface_width)^2)``
    where ``base`` is the brick or mortar strength.
    """
    s_ax, t_ax = _axis(length_axis), _axis(height_axis)
    if s_ax == t_ax:
        raise ValueError(f"bricks: length_axis and height_axis must differ, both are {length_axis!r}")
    t_full = U[:, t_ax]
    course = np.floor(t_full / brick_height)
    s = np.mod(U[:, s_ax] + 0.5 * brick_length * np.mod(course, 2.0), brick_length)
    t = np.mod(t_full, brick_height)
    in_bed = t < mortar  # horizontal joint
    in_head = (~in_bed) & (s < mortar)  # vertical joint
    in_brick = ~(in_bed | in_head)
    d = np.where(
        in_brick,
        np.minimum.reduce([s - mortar, brick_length - s, t - mortar, brick_height - t]),
        np.where(in_bed, np.minimum(t, mortar - t), np.minimum(s, mortar - s)),
    )
    base = np.where(in_brick, brick_strength, mortar_strength)
    zeta = base - (base - interface_strength) * np.exp(-((d / interface_width) ** 2))
    return zeta + noise_contrast * perlin(U, noise_frequency, rng, octaves=2)


def inclusions(U, frame, rng, *, count, size, matrix_strength, inclusion_strength, softness, noise_contrast,
               noise_frequency):
    """Hard cubes embedded in a soft matrix (the Jell-O with fruit).

    ``count`` cubes of edge ``size`` with random centres inside the box and
    random orientations; the indicator is a logistic function of the cube's
    signed distance with width ``softness``, so the field stays smooth
    enough for finite differences.
    """
    from scipy.spatial.transform import Rotation

    extent = frame.extent
    margin = np.minimum(0.5 * size, 0.5 * extent)
    centres = rng.uniform(margin, extent - margin, size=(count, 3))
    rotations = Rotation.random(count, random_state=rng).as_matrix()  # (count, 3, 3)
    occupancy = np.zeros(U.shape[0])
    for c, R in zip(centres, rotations):  # a loop over the few cubes, vectorised over points
        local = np.abs((U - c) @ R) - 0.5 * size
        outside = np.linalg.norm(np.maximum(local, 0.0), axis=1)
        inside = np.minimum(local.max(axis=1), 0.0)
        sdf = outside + inside
        occupancy = np.maximum(occupancy, 1.0 / (1.0 + np.exp(np.clip(sdf / softness, -60.0, 60.0))))
    zeta = matrix_strength + (inclusion_strength - matrix_strength) * occupancy
    return zeta + noise_contrast * perlin(U, noise_frequency, rng, octaves=2)


def load_volume(path: str | Path) -> np.ndarray:
    """Read a user strength volume from a ``.npy`` file and check it.

    Raises
    ------
    InputError
        Naming the file, when it is not a finite 3D array with at least two
        samples per axis.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: strength volume not found (expected a .npy file with a 3D array)")
    if not is_npy(path):
        raise InputError(f"{path}: not a .npy file (NumPy's np.save writes one); expected a 3D array of strengths")
    try:
        values = np.load(path, allow_pickle=False)
    except Exception as exc:  # numpy raises several kinds for a damaged file
        raise InputError(f"{path}: cannot read as a .npy array ({exc})") from None
    if values.ndim != 3 or min(values.shape) < 2:
        raise InputError(f"{path}: strength volume has shape {values.shape}, expected a 3D array with >= 2 samples per axis")
    if not np.issubdtype(values.dtype, np.number) or np.issubdtype(values.dtype, np.complexfloating):
        raise InputError(f"{path}: strength volume has dtype {values.dtype}, expected real numbers")
    values = values.astype(np.float64)
    if not np.all(np.isfinite(values)):
        raise InputError(f"{path}: strength volume has {int((~np.isfinite(values)).sum())} NaN or infinite samples")
    return values


def volume(U, frame, rng, *, path, bounds):
    """A user-supplied volume: a ``.npy`` grid spanning ``bounds`` (material units).

    Sampled by trilinear interpolation, clamped outside its bounds. Without
    ``bounds`` the volume spans the object's bounding box.
    """
    values = load_volume(path)
    lo, hi = (frame.lo, frame.hi) if bounds is None else bounds
    return trilinear(Grid.from_bounds(lo, hi, values.shape), values, frame.to_material(U))


_STRENGTH = dict(lo=-10.0, hi=10.0)
Axis = Literal["x", "y", "z"]


class Layer(Section):
    """A layer of zeta: ``weight`` times its kind's function of its parameters."""

    kind: str = text("", "the kind of this layer")
    weight: float = number(1.0, -100.0, 100.0, "factor of this layer in the sum")


class MarbleLayer(Layer):
    """Marble: a hard, grainy body and soft veins (:func:`marble`)."""

    kind: Literal["marble"] = choice("marble", "the kind of this layer")
    vein_frequency: float = number(2.5, 0.0, 100.0, "veins per unit length")
    vein_direction: Vec3 = vec3([1.0, 0.35, 0.2], "direction across the veins")
    turbulence: float = number(4.0, 0.0, 50.0, "phase distortion of the veins")
    turbulence_frequency: float = number(2.0, 0.0, 100.0)
    hard_fraction: float = number(0.75, 0.0, 1.0, "share of space in the hard, grainy region (the rest: soft veins)")
    edge_width: float = number(0.15, 1e-3, 2.0, "softness of the region border (in sine units)")
    hard_strength: float = number(0.85, **_STRENGTH)
    grain_frequency: float = number(24.0, 0.0, 400.0, "grain lattice frequency in the hard region")
    grain_octaves: int = integer(3, 1, 8)
    grain_contrast: float = number(0.35, **_STRENGTH)
    soft_strength: float = number(0.25, **_STRENGTH)
    soft_frequency: float = number(3.0, 0.0, 400.0)
    soft_contrast: float = number(0.15, **_STRENGTH)

    @field_validator("vein_direction")
    @classmethod
    def _a_direction(cls, value: list[float]) -> list[float]:
        if not any(value):
            raise refuse("a direction of non-zero length")
        return value


class ElongatedLayer(Layer):
    """Noise stretched along an axis (:func:`elongated`)."""

    kind: Literal["elongated"] = choice("elongated", "the kind of this layer")
    axis: Axis = choice("z", "direction of the elongated features")
    frequency: float = number(12.0, 0.0, 400.0)
    stretch: float = number(6.0, 1.0, 1000.0, "feature length along the axis / across it")
    octaves: int = integer(3, 1, 8)
    mean: float = number(0.5, **_STRENGTH)
    contrast: float = number(0.5, **_STRENGTH)


class FibresLayer(Layer):
    """Bundles of fibres along an axis with weak interfaces between them (:func:`fibres`)."""

    kind: Literal["fibres"] = choice("fibres", "the kind of this layer")
    axis: Axis = choice("z", "direction of the fibres")
    bundle_size: float = number(0.08, 1e-4, 10.0, "spacing of the fibre bundles across the axis")
    interface_width: float = number(0.012, 1e-6, 1.0, "width of the weak layer between two bundles")
    interface_strength: float = number(0.0, doc="strength on the interfaces between bundles", **_STRENGTH)
    bundle_strength: float = number(1.0, doc="mean strength inside a bundle", **_STRENGTH)
    defect_length: float = number(0.1, 1e-4, 100.0, "length along the axis of a bundle's weak and strong places")
    defect_contrast: float = number(0.4, doc="how much a bundle's strength varies along the axis", **_STRENGTH)


class RadialLayer(Layer):
    """Strength growing with the distance to an axis (:func:`radial`)."""

    kind: Literal["radial"] = choice("radial", "the kind of this layer")
    axis: Axis = choice("z")
    center: Vec3 | None = vec3(None, "a point on the axis (unit coordinates); null: box centre")
    radius: float | None = number(None, 1e-6, doc="unit coordinates; null: inscribed radius")
    inner: float = number(0.2, doc="strength on the axis", **_STRENGTH)
    outer: float = number(1.0, doc="strength at the radius and beyond", **_STRENGTH)
    exponent: float = number(2.0, 0.01, 100.0)


class BricksLayer(Layer):
    """Bricks in a running bond, mortar joints and weak brick-mortar boundaries (:func:`bricks`)."""

    kind: Literal["bricks"] = choice("bricks", "the kind of this layer")
    length_axis: Axis = choice("x")
    height_axis: Axis = choice("y")
    brick_length: float = number(0.1, 1e-4, 10.0)
    brick_height: float = number(0.05, 1e-4, 10.0)
    mortar: float = number(0.01, 0.0, 1.0, "joint width")
    brick_strength: float = number(1.0, **_STRENGTH)
    mortar_strength: float = number(0.8, **_STRENGTH)
    interface_strength: float = number(0.0, doc="strength on brick-mortar boundaries", **_STRENGTH)
    interface_width: float = number(0.003, 1e-6, 1.0, "width of the weak layer on each brick-mortar boundary; keep "
                                    "it under a third of the joint, so the mortar between two layers stays strong")
    noise_contrast: float = number(0.05, **_STRENGTH)
    noise_frequency: float = number(20.0, 0.0, 400.0)

    @field_validator("height_axis")
    @classmethod
    def _across(cls, value: str, info: ValidationInfo) -> str:
        if value == info.data.get("length_axis"):
            raise refuse(f"an axis other than length_axis ({value!r}): the courses stack across the bricks")
        return value


class InclusionsLayer(Layer):
    """Strong cubes in a weak matrix (:func:`inclusions`)."""

    kind: Literal["inclusions"] = choice("inclusions", "the kind of this layer")
    count: int = integer(12, 0, 10000)
    size: float = number(0.15, 1e-4, 10.0, "cube edge length")
    matrix_strength: float = number(0.2, **_STRENGTH)
    inclusion_strength: float = number(1.0, **_STRENGTH)
    softness: float = number(0.01, 1e-6, 1.0)
    noise_contrast: float = number(0.05, **_STRENGTH)
    noise_frequency: float = number(6.0, 0.0, 400.0)


class GrainLayer(Layer):
    """The direction of a material's fibres, which makes cracks across them dear (:func:`grain`)."""

    kind: Literal["grain"] = choice("grain", "the kind of this layer")
    fibres: Literal["along", "around", "volume"] = choice(
        "along", "the fibres run along the axis, around it, or as the direction volume (path) gives them")
    axis: Axis = choice("z")
    center: Vec3 | None = vec3(None, "around: a point on the axis (unit coordinates); null: box centre")
    ratio: float = number(3.0, 1.0, 20.0, "cost of a crack across the fibres over one along them")
    path: str | None = file(None, "volume: .npy file with a fibre direction per node, (nx, ny, nz, 3)")
    bounds: Bounds | None = bounds(None, "volume: material-space box of the directions; null: the object's box")

    @field_validator("center", "path", "bounds")
    @classmethod
    def _read_by_its_fibres(cls, value, info: ValidationInfo):
        # a key the chosen fibres do not read is a mistake to say, not to ignore
        reader = "around" if info.field_name == "center" else "volume"
        if value is not None and info.data.get("fibres", reader) != reader:
            raise refuse(f"null: only fibres: {reader} reads {info.field_name} (these fibres are "
                         f"{info.data['fibres']!r})")
        return value


class VolumeLayer(Layer):
    """Strengths read from a 3D array (:func:`volume`)."""

    kind: Literal["volume"] = choice("volume", "the kind of this layer")
    path: str = file(..., ".npy file with a 3D array of strengths")
    bounds: Bounds | None = bounds(None, "material-space box of the volume; null: the object's box")


#: Each kind's function and the type of its layers.
KINDS: dict[str, tuple[Callable, type[Layer]]] = {
    "marble": (marble, MarbleLayer),
    "elongated": (elongated, ElongatedLayer),
    "fibres": (fibres, FibresLayer),
    "radial": (radial, RadialLayer),
    "bricks": (bricks, BricksLayer),
    "inclusions": (inclusions, InclusionsLayer),
    "grain": (grain, GrainLayer),
    "volume": (volume, VolumeLayer),
}

#: The type of a layer of each kind.
LAYER_TYPES: dict[str, type[Layer]] = {kind: cls for kind, (_, cls) in KINDS.items()}

#: A layer of any kind, chosen by its ``kind``.
StrengthLayer = Annotated[Union[tuple(LAYER_TYPES.values())], Field(discriminator="kind")]
_LAYER = TypeAdapter(StrengthLayer)


def as_layer(layer: Any) -> Layer:
    """A layer as its kind's type (:data:`LAYER_TYPES`), from a mapping as a config file holds it."""
    if isinstance(layer, Layer):
        return layer
    if not isinstance(layer, Mapping) or layer.get("kind") not in LAYER_TYPES:
        raise InputError(f"a strength layer must name its kind, one of {', '.join(LAYER_TYPES)}; got {layer!r}")
    return _LAYER.validate_python(dict(layer))


def strength_field(X: np.ndarray, bounds, layers: list, seed: int, normalize: bool = True) -> np.ndarray:
    """zeta at points: the weighted sum of the configured layers.

    Parameters
    ----------
    X : (n, 3) float
        Material-space points.
    bounds : ((3,), (3,)) float
        The object's bounding box, which defines the unit coordinates.
    layers : list
        Layers of :data:`LAYER_TYPES`, or mappings ``{"kind": name, "weight": w, **params}`` as the
        config holds them (:func:`as_layer`).
    seed : int
        Run seed; layer ``i`` draws from ``default_rng([seed, i])``.
    normalize : bool
        Rescale the sum to [0, 1] over the given points.

    Returns
    -------
    (n,) float
    """
    frame = UnitFrame(*(np.asarray(b, np.float64) for b in bounds))
    U = frame.to_unit(X)
    zeta = np.zeros(U.shape[0])
    for i, layer in enumerate(map(as_layer, layers)):
        params = {k: v for k, v in parameters(layer).items() if k not in ("kind", "weight")}
        try:
            zeta += layer.weight * KINDS[layer.kind][0](U, frame, np.random.default_rng([seed, i]), **params)
        except InputError as exc:  # a layer's file: said with the layer's key
            raise InputError(f"strength.layers[{i}] ({layer.kind}): {exc}") from None
    if normalize:
        zeta = normalize01(zeta)
    return zeta


def grain_of(layers: list, bounds):
    """The :class:`~fields.grain.Grain` of the layers (None without a grain layer); more than one is
    refused."""
    from fields.grain import Grain

    found = [(i, layer) for i, layer in enumerate(map(as_layer, layers)) if layer.kind == "grain"]
    if not found:
        return None
    if len(found) > 1:
        raise InputError(f"strength.layers[{found[1][0]}]: a second grain layer; expected at most one (the fibres "
                         f"of layer {found[0][0]})")
    i, layer = found[0]
    frame = UnitFrame(*(np.asarray(b, np.float64) for b in bounds))
    c = 0.5 * frame.extent if layer.center is None else np.asarray(layer.center, np.float64)
    field = None
    if layer.fibres == "volume":
        from fields.grain import DirectionField, load_directions

        key = f"strength.layers[{i}].path"
        if layer.path is None:
            raise InputError(f"{key}: fibres: volume needs the .npy file of fibre directions; expected a path")
        d = load_directions(layer.path, key)
        lo, hi = (frame.lo, frame.hi) if layer.bounds is None else (np.asarray(b, np.float64) for b in layer.bounds)
        field = DirectionField(Grid.from_bounds(lo, hi, d.shape[:3]), d)
    return Grain(float(layer.ratio), layer.fibres, np.eye(3)[_axis(layer.axis)], frame.to_material(c), field)


def normalize01(values: np.ndarray) -> np.ndarray:
    """Affinely map values onto [0, 1]; a constant field maps to 0."""
    lo, hi = float(values.min()), float(values.max())
    if hi - lo < tol.field_range:
        return np.zeros_like(values)
    return (values - lo) / (hi - lo)
