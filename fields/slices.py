"""Axis-aligned slices of grid fields, as arrays and as colour images."""

from __future__ import annotations

import numpy as np

from fields.colormap import colormap, to_uint8
from fields.grid import Grid

AXES = ("x", "y", "z")


def axis_index(axis: int | str) -> int:
    if isinstance(axis, str):
        if axis not in AXES:
            raise ValueError(f"axis must be one of x, y, z or 0, 1, 2, got {axis!r}")
        return AXES.index(axis)
    if axis not in (0, 1, 2):
        raise ValueError(f"axis must be one of x, y, z or 0, 1, 2, got {axis!r}")
    return int(axis)


def axis_slice(grid: Grid, values: np.ndarray, axis: int | str, offset: float = 0.5) -> tuple[np.ndarray, dict]:
    """The plane of a field at a relative position along an axis.

    Parameters
    ----------
    grid : Grid
    values : (nx, ny, nz) float
    axis : int or {"x", "y", "z"}
        Normal of the slice plane.
    offset : float
        Position in [0, 1] along ``axis`` (0 = the grid's low face); between
        two node planes the slice is linearly interpolated.

    Returns
    -------
    plane : (nu, nv) float
        Samples over the two remaining axes ``u < v`` (in x, y, z order).
    info : dict
        ``axis``, ``u``, ``v`` (axis numbers), ``position`` (material
        coordinate of the plane) and ``extent`` ``[[u0, u1], [v0, v1]]``.
    """
    a = axis_index(axis)
    if not 0.0 <= offset <= 1.0:
        raise ValueError(f"slice offset must be in [0, 1], got {offset}")
    values = np.asarray(values)
    if values.shape != tuple(grid.shape):
        raise ValueError(f"values have shape {values.shape}, expected the grid shape {tuple(grid.shape)}")
    n = grid.shape[a]
    f = offset * (n - 1)
    i = min(int(np.floor(f)), n - 2)
    t = f - i
    plane = (1.0 - t) * np.take(values, i, axis=a) + t * np.take(values, i + 1, axis=a)
    u, v = [b for b in range(3) if b != a]
    info = {
        "axis": a,
        "u": u,
        "v": v,
        "position": float(grid.origin[a] + f * grid.spacing[a]),
        "extent": [[float(grid.lo[u]), float(grid.hi[u])], [float(grid.lo[v]), float(grid.hi[v])]],
    }
    return plane, info


def slice_image(plane: np.ndarray, cmap: str = "viridis", vmin: float | None = None, vmax: float | None = None,
                scale: int = 1) -> np.ndarray:
    """An ``(nv * scale, nu * scale, 3)`` uint8 image of a slice, ``v`` pointing up.

    ``scale`` repeats pixels (nearest neighbour) so small grids stay legible.
    """
    img = to_uint8(colormap(np.asarray(plane).T[::-1], cmap, vmin, vmax))
    if scale > 1:
        img = np.repeat(np.repeat(img, scale, axis=0), scale, axis=1)
    return img
