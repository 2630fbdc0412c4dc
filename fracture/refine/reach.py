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


# The pieces' masks of nodes take at most this many bytes at once, or one piece's if that is more (a Cell
# Fracture export of a hundred pieces and a band of a million nodes is marked in a few rounds).
_MASK_BYTES = 1 << 26


def nodes_near_sheets(where: np.ndarray, origin, spacing, V: np.ndarray, F: np.ndarray, sides: np.ndarray,
                      radius: float, count: int) -> dict[int, np.ndarray]:
    """Per piece, the nodes within ``radius`` of a coarse triangle it lies on.

    ``where`` (the grid's shape) numbers the nodes asked ``0..count-1`` and holds -1 elsewhere; the grid's
    node ``(i, j, k)`` lies at ``origin + (i, j, k) * spacing``; ``V, F, sides`` is the coarse surface (the
    pieces on either side of each triangle). Returns ``{piece: sorted numbers of its nodes}`` for every
    piece of ``sides`` (an empty array for a piece with none)."""
    pieces = np.unique(sides)
    out = {int(c): np.zeros(0, np.int64) for c in pieces}
    if not len(F) or not count:
        return out
    args = (np.ascontiguousarray(where, np.int64), np.asarray(origin, np.float64), np.asarray(spacing, np.float64),
            np.ascontiguousarray(V, np.float64))
    # a mask of the nodes per piece, for as many pieces at a time as _MASK_BYTES hold
    for group in np.array_split(pieces, min(-(-len(pieces) * count // _MASK_BYTES), len(pieces))):
        local = np.full(int(sides.max()) + 1, -1, np.int64)
        local[group] = np.arange(len(group))
        mine = np.flatnonzero((local[sides] >= 0).any(axis=1))
        near = _mark(*args, np.ascontiguousarray(F[mine], np.int64), local[sides[mine]], float(radius), len(group),
                     int(count))
        out.update({int(c): np.flatnonzero(near[k]) for k, c in enumerate(group)})
    return out


@numba.njit(cache=True, parallel=True)
def _mark(where, origin, spacing, V, F, sides, radius, n_pieces, count):
    """``near[c, n]``: node number ``n`` lies within ``radius`` of a triangle with piece ``c`` on a side
    (``sides``: the triangles' pieces numbered ``0..n_pieces-1``, -1 for one not asked). Threads write only
    True, so two triangles marking one node in two threads agree."""
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
                    if n < 0 or ((s0 < 0 or near[s0, n]) and (s1 < 0 or near[s1, n])):
                        continue
                    p = (origin[0] + i * spacing[0], origin[1] + j * spacing[1], origin[2] + k * spacing[2])
                    if point_triangle_distance2(p, a, b, c) <= r2:
                        if s0 >= 0:
                            near[s0, n] = True
                        if s1 >= 0:
                            near[s1, n] = True
    return near


def near_label(labels: np.ndarray, nodes: np.ndarray, label: int, cells: int) -> np.ndarray:
    """Which of ``nodes`` (flat indices of the grid ``labels``, which holds a piece per node or -1) have a
    node of ``label`` within ``cells`` nodes in every axis (a cube around them): where a piece's region,
    dilated by ``cells``, reaches. Each node's cube is read on its own, on every core: a dilation of the
    piece's whole region (a maximum filter over its box) per piece took the collapsing wall's twelve pieces
    0.16 s, most of it over nodes no move asks about."""
    nodes = np.ascontiguousarray(nodes, np.int64)
    return _near_label(np.ascontiguousarray(labels, np.int64), nodes, int(label), int(cells))


@numba.njit(cache=True, parallel=True)
def _near_label(labels, nodes, label, cells):
    nx, ny, nz = labels.shape
    out = np.zeros(nodes.shape[0], np.bool_)
    for t in numba.prange(nodes.shape[0]):
        c = nodes[t]
        i, j, k = c // (ny * nz), (c // nz) % ny, c % nz
        found = False
        for a in range(max(i - cells, 0), min(i + cells + 1, nx)):
            for b in range(max(j - cells, 0), min(j + cells + 1, ny)):
                for d in range(max(k - cells, 0), min(k + cells + 1, nz)):
                    if labels[a, b, d] == label:
                        found = True
                        break
                if found:
                    break
            if found:
                break
        out[t] = found
    return out
