"""From meshes to the strength pyramid: zeta, xi and psi on one grid."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from fields.grid import Grid, grid_shape_for_box, thinnest_extent
from fields.pyramid import StrengthPyramid
from fields.grain import Grain
from fields.strength import grain_of, strength_field
from fields.stress import distance_to_surface, modified_strength, stress_from_distance


@dataclass
class FieldSet:
    """The fields of one object, sampled on ``grid``.

    Attributes
    ----------
    grid : Grid
    zeta : (nx, ny, nz) float
        Material strength.
    distance : (nx, ny, nz) float
        Distance to the coarse fracture surface.
    xi : (nx, ny, nz) float
        Estimated stress.
    psi : (nx, ny, nz) float
        Modified strength, ``strength_weight * zeta - stress_weight * xi``.
    pyramid : StrengthPyramid
        Levels of psi and the level-averaged gradient.
    grain : Grain or None
        The fibres of a grain layer (:mod:`fields.grain`).
    """

    grid: Grid
    zeta: np.ndarray
    distance: np.ndarray
    xi: np.ndarray
    psi: np.ndarray
    pyramid: StrengthPyramid
    grain: Grain | None = None

    def field(self, name: str) -> np.ndarray:
        """``zeta``, ``xi``, ``psi`` or ``distance`` by name."""
        if name not in ("zeta", "xi", "psi", "distance"):
            raise ValueError(f"unknown field {name!r}, expected zeta, xi, psi or distance")
        return getattr(self, name)


def padded_bounds(V: np.ndarray, padding: float) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box of ``V`` grown by ``padding`` times its largest extent on every side."""
    lo, hi = V.min(axis=0), V.max(axis=0)
    pad = padding * float((hi - lo).max())
    return lo - pad, hi + pad


def grid_for(exterior_V: np.ndarray, resolution, padding: float, min_across: int = 0) -> Grid:
    """The grid :func:`build_fields` samples on: the object's padded box at ``resolution``; with one number,
    cubic cells small enough for ``min_across`` nodes across the object's thinnest extent (along its principal
    axes: a plank's thickness, turned any way) and, beyond that, ``resolution`` nodes along the box's longest
    axis."""
    lo, hi = padded_bounds(exterior_V, padding)
    if np.ndim(resolution) == 0 and min_across > 1:
        thin = thinnest_extent(exterior_V)
        h = min(float((hi - lo).max()) / (int(resolution) - 1), thin / (min_across - 1) if thin > 0 else np.inf)
        return Grid.from_bounds(lo, hi, tuple(int(max(4, round(e / h) + 1)) for e in hi - lo))
    return Grid.from_bounds(lo, hi, grid_shape_for_box(lo, hi, resolution))


def fields_memory(n_nodes: int, levels: int) -> int:
    """Peak bytes :func:`build_fields` needs for a grid of ``n_nodes`` (an estimate from above).

    Measured peaks are about 350 bytes a node with five pyramid levels (the
    strength layers' noise, the distance transform's indices, zeta, xi, psi
    and the pyramid, in float64); each level holds one more field.
    """
    return int(n_nodes * (160 + 40 * levels))


def build_fields(
    exterior_V: np.ndarray,
    fracture_V: np.ndarray,
    fracture_F: np.ndarray,
    *,
    resolution,
    padding: float,
    min_across: int = 0,
    layers: list[dict],
    seed: int,
    normalize: bool = True,
    stress_length: float = 0.1,
    strength_weight: float = 1.0,
    stress_weight: float = 1.0,
    levels: int = 5,
    sigma: float = 1.0,
    step: Callable[[str], None] | None = None,
    zeta: np.ndarray | None = None,
    distance: np.ndarray | None = None,
    pyramids: Callable[[str, Grid, np.ndarray], StrengthPyramid] | None = None,
) -> FieldSet:
    """Sample zeta, xi and psi over the object's box and build the pyramid.

    Parameters
    ----------
    exterior_V : (n, 3) float
        Vertices of the exterior surface B; their box (padded) is the grid box
        and the frame of the procedural strength.
    fracture_V, fracture_F : (m, 3) float, (k, 3) int
        The coarse fracture surface (the stress estimate's source).
    resolution : int or (3,) int
        See :func:`fields.grid.grid_shape_for_box`.
    min_across : int
        With one ``resolution`` number, at least this many nodes across the object's thinnest extent
        (:func:`grid_for`).
    padding : float
        Grid margin around the object, relative to its largest extent.
    layers, seed, normalize
        Strength layers, see :func:`fields.strength.strength_field`.
    stress_length : float
        Decay length of xi relative to the diagonal of the object's box.
    strength_weight, stress_weight : float
        Weights of psi, see :func:`fields.stress.modified_strength`.
    levels, sigma
        Pyramid, see :class:`fields.pyramid.StrengthPyramid`.
    step : callable, optional
        Called with the name of each finished step (progress reporting).
    zeta, distance : (nx, ny, nz) float, optional
        The strength field and the distances to the fracture surface on this
        grid, when known already (a cache): they depend neither on the stress
        nor on psi's weights nor on the pyramid.
    pyramids : callable, optional
        ``pyramids(name, grid, field)`` gives the pyramid of ``zeta`` or ``xi``
        (a cache may know it); by default it is built.

    Notes
    -----
    The pyramid of psi is combined from the pyramids of zeta and xi
    (:meth:`StrengthPyramid.combine`; the pyramid is linear), so that a new
    weighting of psi costs no smoothing.
    """
    step = step or (lambda name: None)
    obj_lo, obj_hi = exterior_V.min(axis=0), exterior_V.max(axis=0)
    grid = grid_for(exterior_V, resolution, padding, min_across)
    X = grid.points()

    if zeta is None:
        zeta = strength_field(X, (obj_lo, obj_hi), layers, seed, normalize).reshape(grid.shape)
    step("strength")
    if distance is None:
        distance = distance_to_surface(X, fracture_V, fracture_F).reshape(grid.shape)
    diagonal = float(np.linalg.norm(obj_hi - obj_lo))
    xi = stress_from_distance(distance, stress_length * diagonal)
    step("stress")
    psi = modified_strength(zeta, xi, strength_weight, stress_weight)
    make = pyramids or (lambda name, g, values: StrengthPyramid(g, values, levels=levels, sigma=sigma))
    pyramid = StrengthPyramid.combine([(strength_weight, make("zeta", grid, zeta)), (-stress_weight, make("xi", grid, xi))])
    step("pyramid")
    return FieldSet(grid, zeta, distance, xi, psi, pyramid, grain_of(layers, (obj_lo, obj_hi)))
