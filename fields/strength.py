"""Procedural material strength fields zeta(x) (Section 4.2).

Every kind is a function ``kind(U, frame, rng, **params) -> (n,) float`` of
points in *unit coordinates* ``U = (X - lo) / L``, where ``lo`` is the low
corner of the object's bounding box and ``L`` its largest extent (both in
``frame``, a :class:`UnitFrame`): lengths and frequencies in
the parameters are relative to the object size, so a preset works on any mesh.
High values are strong material, low values weak. ``rng`` is a
``numpy.random.Generator`` derived from the run seed; it decides noise offsets
and random placements, so a seed reproduces a field exactly.

:data:`KINDS` registers each kind with its parameter specs, which the config
loader uses to validate ``strength.layers``; :data:`LAYER_TYPES` makes of each
kind's specs a frozen dataclass (a layer of that kind, what
:func:`strength_field` takes), so a layer is one of a union chosen by ``kind``.
"""

from __future__ import annotations

from pathlib import Path
from dataclasses import dataclass, field, fields, is_dataclass, make_dataclass
from typing import Any, Callable, Mapping

import noise
import numpy as np

from fields.grid import Grid
from fields.interpolate import trilinear
from fields.errors import InputError
from fields.spec import Spec, python_type, spec_field
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


def grain(U, frame, rng, *, fibres, axis, center, ratio):
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


def _p(default, type="float", **kw) -> Spec:
    return Spec(default, type, **kw)


_STRENGTH = dict(lo=-10.0, hi=10.0)

KINDS: dict[str, tuple[Callable, dict[str, Spec]]] = {
    "marble": (marble, {
        "vein_frequency": _p(2.5, lo=0.0, hi=100.0, doc="veins per unit length"),
        "vein_direction": _p([1.0, 0.35, 0.2], "vec3", doc="direction across the veins"),
        "turbulence": _p(4.0, lo=0.0, hi=50.0, doc="phase distortion of the veins"),
        "turbulence_frequency": _p(2.0, lo=0.0, hi=100.0),
        "hard_fraction": _p(0.75, lo=0.0, hi=1.0, doc="share of space in the hard, grainy region (the rest: soft veins)"),
        "edge_width": _p(0.15, lo=1e-3, hi=2.0, doc="softness of the region border (in sine units)"),
        "hard_strength": _p(0.85, **_STRENGTH),
        "grain_frequency": _p(24.0, lo=0.0, hi=400.0, doc="grain lattice frequency in the hard region"),
        "grain_octaves": _p(3, "int", lo=1, hi=8),
        "grain_contrast": _p(0.35, **_STRENGTH),
        "soft_strength": _p(0.25, **_STRENGTH),
        "soft_frequency": _p(3.0, lo=0.0, hi=400.0),
        "soft_contrast": _p(0.15, **_STRENGTH),
    }),
    "elongated": (elongated, {
        "axis": _p("z", "str", choices=_AXES, doc="direction of the elongated features"),
        "frequency": _p(12.0, lo=0.0, hi=400.0),
        "stretch": _p(6.0, lo=1.0, hi=1000.0, doc="feature length along the axis / across it"),
        "octaves": _p(3, "int", lo=1, hi=8),
        "mean": _p(0.5, **_STRENGTH),
        "contrast": _p(0.5, **_STRENGTH),
    }),
    "fibres": (fibres, {
        "axis": _p("z", "str", choices=_AXES, doc="direction of the fibres"),
        "bundle_size": _p(0.08, lo=1e-4, hi=10.0, doc="spacing of the fibre bundles across the axis"),
        "interface_width": _p(0.012, lo=1e-6, hi=1.0, doc="width of the weak layer between two bundles"),
        "interface_strength": _p(0.0, **_STRENGTH, doc="strength on the interfaces between bundles"),
        "bundle_strength": _p(1.0, **_STRENGTH, doc="mean strength inside a bundle"),
        "defect_length": _p(0.1, lo=1e-4, hi=100.0, doc="length along the axis of a bundle's weak and strong places"),
        "defect_contrast": _p(0.4, **_STRENGTH, doc="how much a bundle's strength varies along the axis"),
    }),
    "radial": (radial, {
        "axis": _p("z", "str", choices=_AXES),
        "center": _p(None, "vec3", nullable=True, doc="a point on the axis (unit coordinates); null: box centre"),
        "radius": _p(None, lo=1e-6, nullable=True, doc="unit coordinates; null: inscribed radius"),
        "inner": _p(0.2, **_STRENGTH, doc="strength on the axis"),
        "outer": _p(1.0, **_STRENGTH, doc="strength at the radius and beyond"),
        "exponent": _p(2.0, lo=0.01, hi=100.0),
    }),
    "bricks": (bricks, {
        "length_axis": _p("x", "str", choices=_AXES),
        "height_axis": _p("y", "str", choices=_AXES),
        "brick_length": _p(0.1, lo=1e-4, hi=10.0),
        "brick_height": _p(0.05, lo=1e-4, hi=10.0),
        "mortar": _p(0.01, lo=0.0, hi=1.0, doc="joint width"),
        "brick_strength": _p(1.0, **_STRENGTH),
        "mortar_strength": _p(0.8, **_STRENGTH),
        "interface_strength": _p(0.0, **_STRENGTH, doc="strength on brick-mortar boundaries"),
        "interface_width": _p(0.003, lo=1e-6, hi=1.0,
                              doc="width of the weak layer on each brick-mortar boundary; keep it under a third "
                                  "of the joint, so the mortar between two layers stays strong"),
        "noise_contrast": _p(0.05, **_STRENGTH),
        "noise_frequency": _p(20.0, lo=0.0, hi=400.0),
    }),
    "inclusions": (inclusions, {
        "count": _p(12, "int", lo=0, hi=10000),
        "size": _p(0.15, lo=1e-4, hi=10.0, doc="cube edge length"),
        "matrix_strength": _p(0.2, **_STRENGTH),
        "inclusion_strength": _p(1.0, **_STRENGTH),
        "softness": _p(0.01, lo=1e-6, hi=1.0),
        "noise_contrast": _p(0.05, **_STRENGTH),
        "noise_frequency": _p(6.0, lo=0.0, hi=400.0),
    }),
    "grain": (grain, {
        "fibres": _p("along", "str", choices=("along", "around"), doc="the fibres run along the axis or around it"),
        "axis": _p("z", "str", choices=_AXES),
        "center": _p(None, "vec3", nullable=True, doc="around: a point on the axis (unit coordinates); null: box centre"),
        "ratio": _p(3.0, lo=1.0, hi=20.0, doc="cost of a crack across the fibres over one along them"),
    }),
    "volume": (volume, {
        "path": _p(None, "path", doc=".npy file with a 3D array of strengths"),
        "bounds": _p(None, "bounds", nullable=True, doc="material-space box of the volume; null: the object's box"),
    }),
}

LAYER_COMMON = {"weight": _p(1.0, lo=-100.0, hi=100.0, doc="factor of this layer in the sum")}



def _layer_type(kind: str, specs: dict[str, Spec]) -> type:
    name = "".join(part.title() for part in kind.split("_")) + "Layer"
    body = [("kind", str, field(default=kind, metadata=dict(doc="the kind of this layer")))]
    for key, spec in {**LAYER_COMMON, **specs}.items():
        body.append((key, python_type(spec), spec_field(spec)))
    cls = make_dataclass(name, body, frozen=True)
    cls.__module__ = __name__
    cls.__doc__ = f"A {kind} layer of zeta: ``weight`` times :func:`{KINDS[kind][0].__name__}` of its parameters."
    return cls


#: A frozen dataclass per kind, chosen by a layer's ``kind``.
LAYER_TYPES: dict[str, type] = {kind: _layer_type(kind, specs) for kind, (_, specs) in KINDS.items()}


def as_layer(layer: Any):
    """A layer as its kind's dataclass (:data:`LAYER_TYPES`), from a mapping as the config holds it."""
    if is_dataclass(layer):
        return layer
    if not isinstance(layer, Mapping) or layer.get("kind") not in LAYER_TYPES:
        raise InputError(f"a strength layer must name its kind, one of {', '.join(LAYER_TYPES)}; got {layer!r}")
    return LAYER_TYPES[layer["kind"]](**layer)


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
        params = {f.name: getattr(layer, f.name) for f in fields(layer) if f.name not in ("kind", "weight")}
        zeta += layer.weight * KINDS[layer.kind][0](U, frame, np.random.default_rng([seed, i]), **params)
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
    _, layer = found[0]
    frame = UnitFrame(*(np.asarray(b, np.float64) for b in bounds))
    c = 0.5 * frame.extent if layer.center is None else np.asarray(layer.center, np.float64)
    return Grain(float(layer.ratio), layer.fibres, np.eye(3)[_axis(layer.axis)], frame.to_material(c))


def normalize01(values: np.ndarray) -> np.ndarray:
    """Affinely map values onto [0, 1]; a constant field maps to 0."""
    lo, hi = float(values.min()), float(values.max())
    if hi - lo < tol.field_range:
        return np.zeros_like(values)
    return (values - lo) / (hi - lo)
