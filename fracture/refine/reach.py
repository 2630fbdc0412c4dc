"""Where each piece may grow in the global search: the band's grid nodes within a radius of the coarse
sheets the piece lies on (:mod:`fracture.refine.search`, module notes 2).

Every coarse triangle marks the nodes of its box (grown by the radius) that
lie within the radius of it, for both pieces on its sides: a compiled loop
over the triangles on every core. libigl's point-to-mesh distance asked once
per sheet (the clay's 40 sheets) built a tree per sheet and took 0.12-0.16 s
on the clay's band; this reads each node once per triangle whose box holds it
and answers the same nodes (the same squared distance to the same triangles).
"""

from __future__ import annotations

import numba
import numpy as np

from fracture.mesh import vec
from fracture.refine.collide import point_triangle_distance2


def nodes_near_sheets(where: np.ndarray, origin, spacing, V: np.ndarray, F: np.ndarray, sides: np.ndarray,
                      radius: float, count: int) -> dict[int, np.ndarray]:
    """Per piece, the nodes within ``radius`` of a coarse triangle it lies on.

    ``where`` (the grid's shape) numbers the nodes asked ``0..count-1`` and holds -1 elsewhere; the grid's
    node ``(i, j, k)`` lies at ``origin + (i, j, k) * spacing``; ``V, F, sides`` is the coarse surface (the
    pieces on either side of each triangle). Returns ``{piece: sorted numbers of its nodes}`` for every
    piece of ``sides`` (an empty array for a piece with none)."""
    pieces = np.unique(sides)
    if not len(F) or not count:
        return {int(c): np.zeros(0, np.int64) for c in pieces}
    near = _mark(np.ascontiguousarray(where, np.int64), np.asarray(origin, np.float64),
                 np.asarray(spacing, np.float64), np.ascontiguousarray(V, np.float64),
                 np.ascontiguousarray(F, np.int64), np.ascontiguousarray(sides, np.int64),
                 float(radius), int(sides.max()) + 1, int(count))
    return {int(c): np.flatnonzero(near[c]) for c in pieces}


@numba.njit(cache=True, parallel=True)
def _mark(where, origin, spacing, V, F, sides, radius, n_pieces, count):
    """``near[c, n]``: node number ``n`` lies within ``radius`` of a triangle with piece ``c`` on a side.
    Threads write only True, so two triangles marking one node in two threads agree."""
    near = np.zeros((n_pieces, count), np.bool_)
    shape = where.shape
    r2 = radius * radius
    for t in numba.prange(F.shape[0]):
        a, b, c = vec.point(V, F[t, 0]), vec.point(V, F[t, 1]), vec.point(V, F[t, 2])
        s0, s1 = sides[t, 0], sides[t, 1]
        lo = np.empty(3, np.int64)
        hi = np.empty(3, np.int64)
        for d in range(3):
            least = min(a[d], b[d], c[d]) - radius - origin[d]
            most = max(a[d], b[d], c[d]) + radius - origin[d]
            lo[d] = max(int(np.ceil(least / spacing[d])) - 1, 0)  # a node of margin: rounding
            hi[d] = min(int(np.floor(most / spacing[d])) + 1, shape[d] - 1)
        for i in range(lo[0], hi[0] + 1):
            for j in range(lo[1], hi[1] + 1):
                for k in range(lo[2], hi[2] + 1):
                    n = where[i, j, k]
                    if n < 0 or (near[s0, n] and near[s1, n]):
                        continue
                    p = (origin[0] + i * spacing[0], origin[1] + j * spacing[1], origin[2] + k * spacing[2])
                    if point_triangle_distance2(p, a, b, c) <= r2:
                        near[s0, n] = True
                        near[s1, n] = True
    return near
