"""Vertex and triangle orders that keep neighbours near in memory (numba): each iteration of the
refinement touches every vertex and triangle of a surface that grows to 10^5 triangles."""

from __future__ import annotations

import numba
import numpy as np

from fracture.mesh import morton


@numba.njit(cache=True)
def _faces_by_first_vertex(F, new, n):
    """Triangles renumbered by ``new`` (old vertex -> new) and ordered by their lowest new vertex (counting sort)."""
    m = F.shape[0]
    start = np.zeros(n + 1, np.int64)
    for f in range(m):
        start[min(new[F[f, 0]], new[F[f, 1]], new[F[f, 2]]) + 1] += 1
    for v in range(n):
        start[v + 1] += start[v]
    order = np.empty(m, np.int64)
    for f in range(m):
        k = min(new[F[f, 0]], new[F[f, 1]], new[F[f, 2]])
        order[start[k]] = f
        start[k] += 1
    return order


def spatial_order(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertex and triangle orders that keep neighbours near in memory.

    Vertices go along a Morton (Z-order) curve through their bounding box,
    triangles by their lowest vertex in that order. Returns ``(vorder,
    forder)``: new vertex ``i`` is old vertex ``vorder[i]``, new triangle
    ``j`` old triangle ``forder[j]``.
    """
    V = np.ascontiguousarray(V, np.float64)
    vorder = np.argsort(morton.codes(V), kind="stable") if len(V) else np.zeros(0, np.int64)
    new = np.empty(len(V), np.int64)
    new[vorder] = np.arange(len(V))
    return vorder, _faces_by_first_vertex(np.ascontiguousarray(F, np.int64), new, len(V))
