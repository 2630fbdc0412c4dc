"""Per-triangle areas and unit normals in one compiled pass: the one normals function of the project."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, inline="always")
def unit_normal_into(ux, uy, uz, vx, vy, vz, N, f):
    """Write the unit normal of the triangle with edge vectors u and v into ``N[f]`` (left as it is
    for a degenerate triangle); returns the length of u x v, twice the triangle's area."""
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    t = np.sqrt(nx * nx + ny * ny + nz * nz)
    if t > 0.0:
        N[f, 0], N[f, 1], N[f, 2] = nx / t, ny / t, nz / t
    return t


@numba.njit(cache=True)
def face_geometry(V, F):
    """Areas ``(m,)`` and unit normals ``(m, 3)`` (zero for degenerate triangles)."""
    m = F.shape[0]
    A = np.empty(m)
    N = np.zeros((m, 3))
    for f in range(m):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        A[f] = 0.5 * unit_normal_into(V[b, 0] - V[a, 0], V[b, 1] - V[a, 1], V[b, 2] - V[a, 2],
                                       V[c, 0] - V[a, 0], V[c, 1] - V[a, 1], V[c, 2] - V[a, 2], N, f)
    return A, N
