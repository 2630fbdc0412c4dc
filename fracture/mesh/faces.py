"""Per-triangle areas and unit normals in one compiled pass: the one normals function of the project."""

from __future__ import annotations

import numba
import numpy as np

from fracture.mesh import vec


@numba.njit(cache=True, inline="always")
def unit_normal_into(u, v, N, f):
    """Write the unit normal of the triangle with edge vectors ``u`` and ``v`` (3-tuples) into ``N[f]``
    (left as it is for a degenerate triangle); returns the length of u x v, twice the triangle's area."""
    n = vec.cross(u, v)
    t = vec.norm(n)
    if t > 0.0:
        N[f, 0], N[f, 1], N[f, 2] = n[0] / t, n[1] / t, n[2] / t
    return t


@numba.njit(cache=True, parallel=True)
def face_geometry(V, F):
    """Areas ``(m,)`` and unit normals ``(m, 3)`` (zero for degenerate triangles), on every thread."""
    m = F.shape[0]
    A = np.empty(m)
    N = np.zeros((m, 3))
    for f in numba.prange(m):
        a = vec.point(V, F[f, 0])
        A[f] = 0.5 * unit_normal_into(vec.sub(vec.point(V, F[f, 1]), a), vec.sub(vec.point(V, F[f, 2]), a), N, f)
    return A, N
