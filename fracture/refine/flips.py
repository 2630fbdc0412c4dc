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

from fracture.refine import hashgrid
from fracture.refine.collide import _EPS, _cross, _dot, _pt, _sub, _triangles_intersect, triangle_grid
from fracture.refine.kernels import EdgeTable, _edge_table, _find_edge


@numba.njit(cache=True, inline="always")
def _cot(V, a, b, c):
    """Cotangent of the angle at vertex ``a`` of triangle (a, b, c), +inf for a degenerate triangle."""
    ux, uy, uz = V[b, 0] - V[a, 0], V[b, 1] - V[a, 1], V[b, 2] - V[a, 2]
    vx, vy, vz = V[c, 0] - V[a, 0], V[c, 1] - V[a, 1], V[c, 2] - V[a, 2]
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    sine = np.sqrt(nx * nx + ny * ny + nz * nz)
    return (ux * vx + uy * vy + uz * vz) / sine if sine > 0.0 else np.inf


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
        # the angles opposite the edge add up to more than pi: cot a + cot b < 0
        # (sin(a + b) = sin a sin b (cot a + cot b), with both angles in (0, pi))
        if _cot(V, w, u, v) + _cot(V, x, v, u) >= -1e-12:
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


@numba.njit(cache=True, inline="always")
def _boxes_apart(V, F, f, c):
    """The bounding boxes of triangles f and c do not overlap."""
    for k in range(3):
        if (max(V[F[f, 0], k], V[F[f, 1], k], V[F[f, 2], k]) < min(V[F[c, 0], k], V[F[c, 1], k], V[F[c, 2], k])
                or max(V[F[c, 0], k], V[F[c, 1], k], V[F[c, 2], k]) < min(V[F[f, 0], k], V[F[f, 1], k], V[F[f, 2], k])):
            return True
    return False


@numba.njit(cache=True, inline="always")
def _meet(V, F, f, c, eps):
    return not _boxes_apart(V, F, f, c) and _triangles_intersect(V, F, f, c, eps)


@numba.njit(cache=True)
def _meet_found(V, F, pairs, grid, first, ids, skip, eps, out):
    """Mark in ``out`` the triangle ``pairs`` that meet a triangle found in ``grid``: element
    ``first + i`` is triangle ``ids[i]`` (elements below ``first`` are not triangles), and triangles
    with ``skip`` are left out. Pairs already marked are not looked at again."""
    buf = np.empty(256, np.int64)
    lo = np.empty(3)
    hi = np.empty(3)
    for i in range(pairs.shape[0]):
        if out[i]:
            continue
        f, g = pairs[i, 0], pairs[i, 1]
        for c in range(3):
            lo[c] = min(V[F[f, 0], c], V[F[f, 1], c], V[F[f, 2], c], V[F[g, 0], c], V[F[g, 1], c], V[F[g, 2], c])
            hi[c] = max(V[F[f, 0], c], V[F[f, 1], c], V[F[f, 2], c], V[F[g, 0], c], V[F[g, 1], c], V[F[g, 2], c])
        buf, k = hashgrid.gather(grid, lo, hi, buf)
        for j in range(k):
            if buf[j] < first:
                continue
            c = ids[buf[j] - first]
            if not skip[c] and c != f and c != g and (_meet(V, F, f, c, eps) or _meet(V, F, g, c, eps)):
                out[i] = True
                break


def _meet_any(V: np.ndarray, F: np.ndarray, pairs: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Which triangle ``pairs`` meet one of the triangles ``ids``."""
    out = np.zeros(len(pairs), bool)
    _meet_found(V, F, pairs, _grid_of(V, F, ids), 0, ids, np.zeros(len(F), bool), _EPS, out)
    return out


def _unsafe(V: np.ndarray, F: np.ndarray, grid: tuple, first: int, cgrid: tuple, changed: np.ndarray,
            pairs: np.ndarray) -> np.ndarray:
    """Which flipped ``pairs`` meet another triangle of the surface.

    ``grid`` holds boxes that contain the triangles as they were before the
    flips (triangle ``f`` as element ``first + f``; elements below ``first``
    are not triangles): it finds the triangles that are still so. ``cgrid``
    holds the boxes of the triangles ``changed`` by the flips, as they are
    now (element ``i`` is triangle ``changed[i]``): it finds those.
    """
    is_changed = np.zeros(len(F), bool)
    is_changed[changed] = True
    out = np.zeros(len(pairs), bool)
    _meet_found(V, F, pairs, grid, first, np.arange(len(F)), is_changed, _EPS, out)
    _meet_found(V, F, pairs, cgrid, 0, changed, np.zeros(len(F), bool), _EPS, out)
    return out


def _grid_of(V: np.ndarray, F: np.ndarray, ids: np.ndarray) -> tuple:
    """A hash grid of the triangles ``ids`` (element ``i`` is triangle ``ids[i]``)."""
    return triangle_grid(V, np.ascontiguousarray(F[ids]))


def _changed_grid(V: np.ndarray, F: np.ndarray, start: np.ndarray) -> tuple[tuple, np.ndarray]:
    """A hash grid of the triangles of ``F`` that differ from ``start``, and their ids."""
    changed = np.flatnonzero((F != start).any(axis=1))
    return _grid_of(V, F, changed), changed


@numba.njit(cache=True)
def _meeting_flips(V, F, pairs, flip_of, eps, bad):
    """Mark in ``bad`` the flips (``flip_of`` each triangle, -1 for none) with a triangle in one of the
    overlapping triangle ``pairs`` that meet."""
    for i in range(pairs.shape[0]):
        a, b = pairs[i, 0], pairs[i, 1]
        fa, fb = flip_of[a], flip_of[b]
        if fa == fb:
            continue  # neither flipped, or the two triangles of one flip (they share their edge)
        if (fa < 0 or bad[fa]) and (fb < 0 or bad[fb]):
            continue  # decides nothing new
        if _triangles_intersect(V, F, a, b, eps):
            if fa >= 0:
                bad[fa] = True
            if fb >= 0:
                bad[fb] = True


def _unsafe_all(V: np.ndarray, F: np.ndarray, done: np.ndarray) -> np.ndarray:
    """:func:`_unsafe` for many flipped pairs ``done`` at once: one hash of all the triangles as they
    are now lists the overlapping pairs, and those with a triangle of ``done`` are tested. When a
    pass flips many edges this costs less than a look-up in the grid per flip."""
    flip_of = np.full(len(F), -1, np.int64)
    flip_of[done[:, 0]] = flip_of[done[:, 1]] = np.arange(len(done))
    bad = np.zeros(len(done), bool)
    _meeting_flips(V, F, hashgrid.pairs(triangle_grid(V, F), -1, False), flip_of, _EPS, bad)
    return bad


def flip_edges(V: np.ndarray, F: np.ndarray, sides: np.ndarray, max_passes: int = 8,
               safe: bool = False, grid: tuple | None = None, table: EdgeTable | None = None) -> int:
    """Flip non-Delaunay edges of ``F`` in place (see the module notes); returns the number of flips.

    ``F`` must be a C-contiguous int64 array (it is edited in place). A flip
    replaces the two triangles of a non-planar quad by the other two: with
    ``safe``, flips whose new triangles meet the rest of the surface are
    undone, and the flips kept are tested again until none meets anything
    (a static test of the flipped triangles against their surroundings).
    ``grid`` may give a :mod:`~fracture.refine.hashgrid` of boxes that
    contain the triangles, as ``(grid, first)`` with triangle ``f`` its
    element ``first + f`` (the collision step's); else one is built.
    ``table``, the :class:`~fracture.refine.kernels.EdgeTable` of ``F`` as
    passed, saves building it for the first pass (with ``safe``).
    """
    if F.dtype != np.int64 or not F.flags.c_contiguous:
        raise TypeError("F must be a C-contiguous int64 array")
    V = np.ascontiguousarray(V, np.float64)
    sides = np.ascontiguousarray(sides, np.int64)
    if not safe:
        return int(_flip(V, F, sides, int(max_passes), _pair_buffer(len(F), max_passes)))
    total = 0
    pairs = _pair_buffer(len(F), 1)
    start = F.copy()  # the triangles whose boxes the grid holds
    for i in range(max_passes):  # one pass at a time: a triangle takes part in one flip per pass
        before = F.copy()
        if i == 0 and table is not None:
            flipped = int(_flip_pass(V, F, sides, table.eid, table.count, table.first, table.second, table._start,
                                     table._hi, table._row, pairs, 0))
        else:
            flipped = int(_flip(V, F, sides, 1, pairs))
        if not flipped:
            break
        if grid is None:  # the boxes from before the first flip
            grid = triangle_grid(V, before), 0
        done = pairs[:flipped].copy()
        if flipped > len(F) // 5:  # many: all at once (about 1.5 us per triangle, not 7 per flip)
            bad = _unsafe_all(V, F, done)
        else:
            bad = _unsafe(V, F, grid[0], grid[1], *_changed_grid(V, F, start), done)
        kept = ~bad
        while bad.any():
            back = done[bad].ravel()
            F[back] = before[back]
            # undoing flips changes only the undone triangles: the kept flips are
            # tested again against these alone (their other tests stand)
            test = np.flatnonzero(kept)
            bad = np.zeros(flipped, bool)
            bad[test] = _meet_any(V, F, done[test], back)
            kept &= ~bad
        total += int(kept.sum())
    return total
