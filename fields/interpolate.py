"""Trilinear interpolation of grid data at arbitrary points.

The hot path of the refinement evaluates psi and grad psi at every vertex and
sample of every iteration (10^5-10^6 points), so the gather is a compiled loop:
NumPy would need eight fancy-indexing passes and temporaries of the full
query size, numba does it in one pass over the points.
"""

from __future__ import annotations

import numba
import numpy as np

from fields.grid import Grid


@numba.njit(cache=True, fastmath=False, nogil=True)
def _trilinear(data, origin, inv_spacing, P, out):
    nx, ny, nz, nc = data.shape
    for p in range(P.shape[0]):
        # Continuous index, clamped so that points outside the grid take the
        # value of the nearest boundary point (constant extrapolation).
        fx = min(max((P[p, 0] - origin[0]) * inv_spacing[0], 0.0), nx - 1.0)
        fy = min(max((P[p, 1] - origin[1]) * inv_spacing[1], 0.0), ny - 1.0)
        fz = min(max((P[p, 2] - origin[2]) * inv_spacing[2], 0.0), nz - 1.0)
        i = min(int(fx), nx - 2)
        j = min(int(fy), ny - 2)
        k = min(int(fz), nz - 2)
        tx = fx - i
        ty = fy - j
        tz = fz - k
        for c in range(nc):
            c00 = data[i, j, k, c] * (1 - tx) + data[i + 1, j, k, c] * tx
            c10 = data[i, j + 1, k, c] * (1 - tx) + data[i + 1, j + 1, k, c] * tx
            c01 = data[i, j, k + 1, c] * (1 - tx) + data[i + 1, j, k + 1, c] * tx
            c11 = data[i, j + 1, k + 1, c] * (1 - tx) + data[i + 1, j + 1, k + 1, c] * tx
            c0 = c00 * (1 - ty) + c10 * ty
            c1 = c01 * (1 - ty) + c11 * ty
            out[p, c] = c0 * (1 - tz) + c1 * tz


def trilinear(grid: Grid, values: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Interpolate grid values at points.

    Parameters
    ----------
    grid : Grid
    values : (nx, ny, nz) or (nx, ny, nz, c) float
        Samples at the grid nodes.
    P : (n, 3) float
        Query points; points outside the grid box are clamped to it.

    Returns
    -------
    (n,) or (n, c) float64
        Interpolated values (reproduces any field that is linear in x, y, z).
    """
    values = np.asarray(values)
    scalar = values.ndim == 3
    data = values[..., None] if scalar else values
    if data.shape[:3] != tuple(grid.shape):
        raise ValueError(f"values have grid shape {data.shape[:3]}, expected {tuple(grid.shape)}")
    P = np.ascontiguousarray(P, np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"query points must have shape (n, 3), got {P.shape}")
    out = np.empty((P.shape[0], data.shape[3]), np.float64)
    _trilinear(np.ascontiguousarray(data, np.float64), grid.origin, 1.0 / grid.spacing, P, out)
    return out[:, 0] if scalar else out
