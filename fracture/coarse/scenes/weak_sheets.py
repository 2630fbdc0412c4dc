"""Synthetic weak sheets: strength fields whose weakest material is a known surface.

A thin weak layer (strength 0.1 on it, 1 away from it, a Gaussian profile of
``width`` voxels) along a flat, tilted or curved sheet through the unit cube,
or a plane through its centre turned ``angle`` degrees about z from the cut's
plane (``turned``: the sheet crosses the cut, in a box long enough in x that
the sheet meets B only on the faces the cut meets, so the pieces keep their
far ends), and a flat coarse cut ``offset`` voxels away from it. A refinement that finds
the weak material ends on the sheet; the distance to it says how well.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fields.grid import Grid
from fracture.mesh.primitives import box, sheet

SHEETS = ("flat", "tilted", "curved")
TURNED = "turned"


@dataclass
class WeakSheetCase:
    """One case: the grid, zeta on it, the exterior (unit cube), the coarse cut and the sheet."""

    kind: str
    offset: float  # voxels between the cut and the sheet (along x, at the centre)
    grid: Grid
    zeta: np.ndarray
    BV: np.ndarray
    BF: np.ndarray
    cut_V: np.ndarray
    cut_F: np.ndarray
    angle: float = 0.0  # degrees, for a turned sheet

    @property
    def h(self) -> float:
        return float(self.grid.spacing.min())

    def sheet_x(self, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """x of the sheet at ``(y, z)``."""
        return sheet_x(self.kind, y, z, self.angle)

    def distance_to_sheet(self, P: np.ndarray) -> np.ndarray:
        """Distance of points to the sheet, in voxels (exact for the flat and tilted sheets; for the
        curved one the distance along x times the cosine of the sheet's slope there)."""
        dx = P[:, 0] - self.sheet_x(P[:, 1], P[:, 2])
        return np.abs(dx) * _slope_cosine(self.kind, P[:, 1], P[:, 2], self.angle) / self.h


def sheet_x(kind: str, y, z, angle: float = 0.0):
    y, z = np.asarray(y, np.float64), np.asarray(z, np.float64)
    if kind == TURNED:
        return 0.5 - np.tan(np.radians(angle)) * (y - 0.5) + 0.0 * z
    if kind == "flat":
        return np.full(np.broadcast(y, z).shape, 0.5)
    if kind == "tilted":
        return 0.5 + 0.25 * (y - 0.5) + 0.1 * (z - 0.5)
    if kind == "curved":
        return 0.5 + 0.08 * np.sin(2.0 * np.pi * y) * np.cos(np.pi * (z - 0.5))
    raise ValueError(f"unknown sheet {kind!r}, expected one of {SHEETS + (TURNED,)}")


def _slope_cosine(kind, y, z, angle=0.0, eps=1e-5):
    gy = (sheet_x(kind, y + eps, z, angle) - sheet_x(kind, y - eps, z, angle)) / (2 * eps)
    gz = (sheet_x(kind, y, z + eps, angle) - sheet_x(kind, y, z - eps, angle)) / (2 * eps)
    return 1.0 / np.sqrt(1.0 + gy * gy + gz * gz)


def weak_sheet_case(kind: str = "flat", offset: float = 4.0, nodes: int = 41, width: float = 1.0,
                    cut_cells: int = 8, angle: float = 0.0) -> WeakSheetCase:
    """The case of a ``kind`` sheet with a flat cut ``offset`` voxels off (module notes).

    The grid spans the unit cube with ``nodes`` per axis and a voxel of margin
    (a turned sheet's box reaches ``tan(angle) + 0.25`` to either side of
    x = 0.5, with the same spacing); the cut is the plane ``x = 0.5 + offset h``
    meshed with ``cut_cells`` cells a side.
    """
    h = 1.0 / (nodes - 3)
    x0, x1 = 0.0, 1.0
    if kind == TURNED:
        reach = np.tan(np.radians(angle)) + 0.25
        cells = int(np.ceil(max(reach, 0.5) / h))
        x0, x1 = 0.5 - cells * h, 0.5 + cells * h
    nx = int(round((x1 - x0) / h)) + 3
    grid = Grid.from_bounds([x0 - h, -h, -h], [x1 + h, 1 + h, 1 + h], (nx, nodes, nodes))
    X = grid.points()
    dx = (X[:, 0] - sheet_x(kind, X[:, 1], X[:, 2], angle)) * _slope_cosine(kind, X[:, 1], X[:, 2], angle)
    zeta = (1.0 - 0.9 * np.exp(-0.5 * (dx / (width * h)) ** 2)).reshape(grid.shape)
    BV, BF = box([x0, 0, 0], [x1, 1, 1], (max(8, int(round(8 * (x1 - x0)))), 8, 8))
    x = 0.5 + offset * h
    V, F = sheet(lambda u, v: np.stack([np.full_like(u, x), u, v], 1), (0, 1), (0, 1), cut_cells + 1,
                 cut_cells + 1)
    return WeakSheetCase(kind, offset, grid, zeta, BV, BF, V, F, angle)
