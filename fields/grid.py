"""Regular sampling grids over a material-space box."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fields.tolerances import tol


@dataclass(frozen=True)
class Grid:
    """Nodes ``origin + (i, j, k) * spacing`` for ``0 <= (i, j, k) < shape``.

    The first node sits on ``lo`` and the last on ``hi``: the grid covers the
    box exactly. Arrays sampled on it have shape ``shape`` in ``(x, y, z)``
    index order (C order, ``x`` slowest).

    Attributes
    ----------
    origin : (3,) float
    spacing : (3,) float
    shape : tuple of 3 int
    """

    origin: np.ndarray
    spacing: np.ndarray
    shape: tuple[int, int, int]

    @classmethod
    def from_bounds(cls, lo, hi, shape) -> "Grid":
        """Grid with ``shape`` nodes spanning the box ``[lo, hi]``."""
        lo = np.asarray(lo, np.float64).reshape(3)
        hi = np.asarray(hi, np.float64).reshape(3)
        shape = tuple(int(n) for n in shape)
        if len(shape) != 3 or min(shape) < 2:
            raise ValueError(f"grid shape must be 3 integers >= 2, got {shape}")
        if np.any(hi - lo <= tol.extent * max(1.0, float(np.abs(hi - lo).max()))):
            raise ValueError(f"grid box must have positive extent on every axis, got lo={lo}, hi={hi}")
        spacing = (hi - lo) / (np.asarray(shape) - 1)
        return cls(lo, spacing, shape)

    @property
    def lo(self) -> np.ndarray:
        return self.origin

    @property
    def hi(self) -> np.ndarray:
        return self.origin + self.spacing * (np.asarray(self.shape) - 1)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    def axes(self) -> list[np.ndarray]:
        """Node coordinates along x, y and z."""
        return [self.origin[a] + self.spacing[a] * np.arange(self.shape[a]) for a in range(3)]

    def points(self) -> np.ndarray:
        """All nodes as an ``(size, 3)`` array, in the C order of the field arrays."""
        X, Y, Z = np.meshgrid(*self.axes(), indexing="ij")
        return np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)

    def to_dict(self) -> dict:
        return {
            "origin": self.origin.tolist(),
            "spacing": self.spacing.tolist(),
            "shape": list(self.shape),
            "bounds": [self.lo.tolist(), self.hi.tolist()],
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Grid":
        return cls(np.asarray(d["origin"], np.float64), np.asarray(d["spacing"], np.float64), tuple(d["shape"]))


def thinnest_extent(V: np.ndarray) -> float:
    """The extent of the points ``V`` along their least principal axis: a plank's thickness, turned any way."""
    X = np.asarray(V, np.float64) - np.mean(V, axis=0)
    axis = np.linalg.eigh(X.T @ X)[1][:, 0]  # eigenvalues ascending: the direction of least spread
    return float(np.ptp(X @ axis))


def grid_shape_for_box(lo, hi, resolution) -> tuple[int, int, int]:
    """Node counts for a box.

    Parameters
    ----------
    lo, hi : (3,) float
        The box.
    resolution : int or sequence of 3 int
        Three integers are used as they are (e.g. the paper's 150 x 50 x 10).
        A single integer ``n`` gives ``n`` nodes along the longest axis and
        proportionally fewer (at least 4) along the others, so voxels are
        close to cubes.
    """
    if np.ndim(resolution) == 0:
        extent = np.asarray(hi, np.float64) - np.asarray(lo, np.float64)
        h = extent.max() / (int(resolution) - 1)
        return tuple(int(max(4, round(e / h) + 1)) for e in extent)
    return tuple(int(n) for n in resolution)
