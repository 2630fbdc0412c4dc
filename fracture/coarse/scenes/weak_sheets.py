"""Synthetic weak sheets: strength fields whose weakest material is a known surface.

A thin weak layer (strength 0.1 on it, 1 away from it, a Gaussian profile of
``width`` voxels) along a flat, tilted or curved sheet through the unit cube,
and a flat coarse cut ``offset`` voxels away from it. A refinement that finds
the weak material ends on the sheet; the distance to it says how well.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fields.grid import Grid
from fracture.mesh.primitives import box, sheet

SHEETS = ("flat", "tilted", "curved")


@dataclass
class WeakSheetCase:
    """One case: the grid, zeta on it, the exterior (unit cube), the coarse cut and the sheet."""

    kind: str
    offset: float  # voxels between the cut and the sheet (along x)
    grid: Grid
    zeta: np.ndarray
    BV: np.ndarray
    BF: np.ndarray
    cut_V: np.ndarray
    cut_F: np.ndarray

    @property
    def h(self) -> float:
        return float(self.grid.spacing.min())

    def sheet_x(self, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """x of the sheet at ``(y, z)``."""
        return sheet_x(self.kind, y, z)

    def distance_to_sheet(self, P: np.ndarray) -> np.ndarray:
        """Distance of points to the sheet, in voxels (exact for the flat and tilted sheets; for the
        curved one the distance along x times the cosine of the sheet's slope there)."""
        dx = P[:, 0] - self.sheet_x(P[:, 1], P[:, 2])
        return np.abs(dx) * _slope_cosine(self.kind, P[:, 1], P[:, 2]) / self.h


def sheet_x(kind: str, y, z):
    y, z = np.asarray(y, np.float64), np.asarray(z, np.float64)
    if kind == "flat":
        return np.full(np.broadcast(y, z).shape, 0.5)
    if kind == "tilted":
        return 0.5 + 0.25 * (y - 0.5) + 0.1 * (z - 0.5)
    if kind == "curved":
        return 0.5 + 0.08 * np.sin(2.0 * np.pi * y) * np.cos(np.pi * (z - 0.5))
    raise ValueError(f"unknown sheet {kind!r}, expected one of {SHEETS}")


def _slope_cosine(kind, y, z, eps=1e-5):
    gy = (sheet_x(kind, y + eps, z) - sheet_x(kind, y - eps, z)) / (2 * eps)
    gz = (sheet_x(kind, y, z + eps) - sheet_x(kind, y, z - eps)) / (2 * eps)
    return 1.0 / np.sqrt(1.0 + gy * gy + gz * gz)


def weak_sheet_case(kind: str = "flat", offset: float = 4.0, nodes: int = 41, width: float = 1.0,
                    cut_cells: int = 8) -> WeakSheetCase:
    """The case of a ``kind`` sheet with a flat cut ``offset`` voxels off (module notes).

    The grid spans the unit cube with ``nodes`` per axis and a voxel of margin;
    the cut is the plane ``x = 0.5 + offset h`` meshed with ``cut_cells`` cells a side.
    """
    h = 1.0 / (nodes - 3)
    grid = Grid.from_bounds([-h] * 3, [1 + h] * 3, (nodes, nodes, nodes))
    X = grid.points()
    dx = (X[:, 0] - sheet_x(kind, X[:, 1], X[:, 2])) * _slope_cosine(kind, X[:, 1], X[:, 2])
    zeta = (1.0 - 0.9 * np.exp(-0.5 * (dx / (width * h)) ** 2)).reshape(grid.shape)
    BV, BF = box([0, 0, 0], [1, 1, 1], (8, 8, 8))
    x = 0.5 + offset * h
    V, F = sheet(lambda u, v: np.stack([np.full_like(u, x), u, v], 1), (0, 1), (0, 1), cut_cells + 1,
                 cut_cells + 1)
    return WeakSheetCase(kind, offset, grid, zeta, BV, BF, V, F)
