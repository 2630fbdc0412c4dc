"""Edge flips that remove slim triangles (Section 4.4), compiled with numba.

An edge is flipped when its two triangles are not locally Delaunay (the
angles opposite it add up to more than pi), only if it has exactly two
triangles, both separate the same pair of components with the same
orientation, the flipped pair does not fold over (both new normals agree with
the old ones), and the new edge does not exist yet. One pass flips a set of
edges that share no triangle; passes repeat until nothing flips.
"""

from __future__ import annotations

import numba
import numpy as np

from fracture.refine.collide import _cross, _dot, _pt, _sub, faces_intersecting
from fracture.refine.kernels import _edge_table, _find_edge


@numba.njit(cache=True)
def _angle(V, a, b, c):
    """Angle at vertex ``a`` of triangle (a, b, c) (scalar code: no temporary arrays)."""
    ux, uy, uz = V[b, 0] - V[a, 0], V[b, 1] - V[a, 1], V[b, 2] - V[a, 2]
    vx, vy, vz = V[c, 0] - V[a, 0], V[c, 1] - V[a, 1], V[c, 2] - V[a, 2]
    nu = np.sqrt(ux * ux + uy * uy + uz * uz)
    nv = np.sqrt(vx * vx + vy * vy + vz * vz)
    if nu == 0.0 or nv == 0.0:
        return 0.0
    x = (ux * vx + uy * vy + uz * vz) / (nu * nv)
    return np.arccos(min(1.0, max(-1.0, x)))


@numba.njit(cache=True)
def _normal(V, a, b, c):
    A = _pt(V, a)
    return _cross(_sub(_pt(V, b), A), _sub(_pt(V, c), A))


@numba.njit(cache=True)
def _flip_pass(V, F, sides, eid, count, first, second, start, hi, row, pairs, done):
    """One pass: flip a set of edges that share no triangle (the table is the one before the pass)."""
    busy = np.zeros(F.shape[0], np.bool_)
    flipped = 0
    new_edges = {(np.int64(0), np.int64(0))}
    new_edges.clear()
    for e in range(count.shape[0]):
        if count[e] != 2:
            continue
        f, g = first[e] // 3, second[e] // 3
        ka, kb = first[e] % 3, second[e] % 3
        if busy[f] or busy[g] or sides[f, 0] != sides[g, 0] or sides[f, 1] != sides[g, 1]:
            continue
        # f = (u, v, w) with edge u->v; g = (v, u, x) with edge v->u
        u = F[f, ka]
        v = F[f, (ka + 1) % 3]
        w = F[f, (ka + 2) % 3]
        if F[g, kb] != v or F[g, (kb + 1) % 3] != u:
            continue  # not consistently oriented
        x = F[g, (kb + 2) % 3]
        if w == x:
            continue
        if _angle(V, w, u, v) + _angle(V, x, v, u) <= np.pi + 1e-12:
            continue
        pair = (min(w, x), max(w, x))
        if _find_edge(start, hi, row, eid, w, x) >= 0 or pair in new_edges:
            continue
        a = _normal(V, u, v, w)
        b = _normal(V, v, u, x)
        n_old = (a[0] + b[0], a[1] + b[1], a[2] + b[2])
        if _dot(_normal(V, w, x, v), n_old) <= 0.0 or _dot(_normal(V, x, w, u), n_old) <= 0.0:
            continue
        F[f, 0], F[f, 1], F[f, 2] = w, x, v
        F[g, 0], F[g, 1], F[g, 2] = x, w, u
        busy[f] = True
        busy[g] = True
        new_edges.add(pair)
        pairs[done + flipped, 0], pairs[done + flipped, 1] = f, g
        flipped += 1
    return flipped


@numba.njit(cache=True)
def _flip(V, F, sides, max_passes, pairs):
    """Up to ``max_passes`` passes; the flipped triangle pairs go to ``pairs`` (room for m // 2 + 1 per pass)."""
    total = 0
    for _ in range(max_passes):
        eid, count, first, second, start, hi, row = _edge_table(F, V.shape[0])
        flipped = _flip_pass(V, F, sides, eid, count, first, second, start, hi, row, pairs, total)
        total += flipped
        if flipped == 0:
            break
    return total


def _pair_buffer(m: int, passes: int) -> np.ndarray:
    # a pass flips triangles that share none: at most m // 2 pairs
    return np.empty((passes * (m // 2 + 1), 2), np.int64)


def flip_edges(V: np.ndarray, F: np.ndarray, sides: np.ndarray, max_passes: int = 8,
               safe: bool = False) -> int:
    """Flip non-Delaunay edges of ``F`` in place (see the module notes); returns the number of flips.

    ``F`` must be a C-contiguous int64 array (it is edited in place). A flip
    replaces the two triangles of a non-planar quad by the other two: with
    ``safe``, flips whose new triangles meet the rest of the surface are
    undone (a static test of the flipped triangles only).
    """
    if F.dtype != np.int64 or not F.flags.c_contiguous:
        raise TypeError("F must be a C-contiguous int64 array")
    V = np.ascontiguousarray(V, np.float64)
    sides = np.ascontiguousarray(sides, np.int64)
    if not safe:
        return int(_flip(V, F, sides, int(max_passes), _pair_buffer(len(F), max_passes)))
    total = 0
    pairs = _pair_buffer(len(F), 1)
    for _ in range(max_passes):  # one pass at a time: a triangle takes part in one flip per pass
        before = F.copy()
        flipped = int(_flip(V, F, sides, 1, pairs))
        if not flipped:
            break
        done = pairs[:flipped]
        faces = np.unique(done)
        bad = faces[faces_intersecting(V, F, faces)]
        undo = np.isin(done, bad).any(axis=1)
        back = done[undo].ravel()
        F[back] = before[back]
        total += flipped - int(undo.sum())
    return total
