"""Edge flips that remove slim triangles (Section 4.4), compiled with numba.

An edge is flipped when its two triangles are not locally Delaunay (the
angles opposite it add up to more than pi), only if it has exactly two
triangles, both separate the same pair of components with the same
orientation, the flipped pair does not fold over (both new normals agree with
the old ones), and the new edge neither existed before the first pass nor was
made by an earlier flip. One pass flips a set of edges that share no
triangle; the next tries the edges around its flips, until nothing flips.
"""

from __future__ import annotations

import numba
import numpy as np

from fracture.mesh import hashgrid
from fracture.mesh.intersect import triangle_grid, triangles_intersect
from fracture.tolerances import tol
from fracture.refine.fans import certified_fans, closed_vertices, share_certified
from fracture.mesh.edges import edge_table, EdgeTable, find_edge
from fracture.mesh import vec

# compiled code reads tolerances as module constants (fracture/tolerances.py says why each)
_DELAUNAY = tol.delaunay


@numba.njit(cache=True, inline="always")
def corner_cot(V, a, b, c):
    """Cotangent of the angle at vertex ``a`` of triangle (a, b, c), +inf for a degenerate triangle."""
    A = vec.point(V, a)
    u, v = vec.sub(vec.point(V, b), A), vec.sub(vec.point(V, c), A)
    sine = vec.norm(vec.cross(u, v))
    return vec.dot(u, v) / sine if sine > 0.0 else np.inf


@numba.njit(cache=True, inline="always")
def corner_obtuse(V, a, b, c):
    """The angle at vertex ``a`` of triangle (a, b, c) is over pi / 2 (its cotangent is negative)."""
    A = vec.point(V, a)
    return vec.dot(vec.sub(vec.point(V, b), A), vec.sub(vec.point(V, c), A)) < 0.0


@numba.njit(cache=True, inline="always")
def _normal(V, a, b, c):
    A = vec.point(V, a)
    return vec.cross(vec.sub(vec.point(V, b), A), vec.sub(vec.point(V, c), A))


@numba.njit(cache=True, inline="always")
def _link(twin, row, other):
    """Make directed triangle edges ``row`` and ``other`` (-1: none) each other's twin."""
    twin[row] = other
    if other >= 0:
        twin[other] = row


@numba.njit(cache=True, inline="always")
def _try_flip(V, F, sides, r, twin, busy, made, table):
    """Flip the edge of directed triangle edge ``r`` if it should be (module notes) and neither of its
    triangles is ``busy``; keeps ``twin`` (the other triangle's directed edge on each two-triangle
    edge) up to date. No flip makes an edge that ``table`` (the edge table before the first pass)
    has, or that an earlier flip made (``made``). Returns the other triangle if it flipped, else -1."""
    r2 = twin[r]
    if r2 < 0:
        return -1
    f, g = r // 3, r2 // 3
    ka, kb = r % 3, r2 % 3
    if busy[f] or busy[g] or sides[f, 0] != sides[g, 0] or sides[f, 1] != sides[g, 1]:
        return -1
    # f = (u, v, w) with edge u->v; g = (v, u, x) with edge v->u
    u = F[f, ka]
    v = F[f, (ka + 1) % 3]
    w = F[f, (ka + 2) % 3]
    if F[g, kb] != v or F[g, (kb + 1) % 3] != u:
        return -1  # not consistently oriented
    x = F[g, (kb + 2) % 3]
    if w == x:
        return -1
    # the angles opposite the edge add up to more than pi: cot a + cot b < 0
    # (sin(a + b) = sin a sin b (cot a + cot b), with both angles in (0, pi));
    # only if one of them is obtuse, which two dot products tell (most edges)
    if not (corner_obtuse(V, w, u, v) or corner_obtuse(V, x, v, u)) or corner_cot(V, w, u, v) + corner_cot(V, x, v, u) >= -_DELAUNAY:
        return -1
    # the tests that read only the quad's corners before those that look up
    # memory far away (the made set and the edge table)
    a = _normal(V, u, v, w)
    b = _normal(V, v, u, x)
    n_old = (a[0] + b[0], a[1] + b[1], a[2] + b[2])
    if vec.dot(_normal(V, w, x, v), n_old) <= 0.0 or vec.dot(_normal(V, x, w, u), n_old) <= 0.0:
        return -1
    pair = (min(w, x), max(w, x))
    if pair in made or find_edge(table.start, table.hi, table.row, table.eid, w, x) >= 0:
        return -1
    vw, wu = twin[3 * f + (ka + 1) % 3], twin[3 * f + (ka + 2) % 3]
    ux, xv = twin[3 * g + (kb + 1) % 3], twin[3 * g + (kb + 2) % 3]
    F[f, 0], F[f, 1], F[f, 2] = w, x, v
    F[g, 0], F[g, 1], F[g, 2] = x, w, u
    _link(twin, 3 * f, 3 * g)  # w->x and x->w
    _link(twin, 3 * f + 1, xv)
    _link(twin, 3 * f + 2, vw)
    _link(twin, 3 * g + 1, wu)
    _link(twin, 3 * g + 2, ux)
    busy[f] = True
    busy[g] = True
    made.add(pair)
    return g


@numba.njit(cache=True)
def flip_passes(V, F, sides, max_passes, pairs, table):
    """Up to ``max_passes`` passes, each flipping a set of edges that share no triangle; the flipped
    triangle pairs go to ``pairs`` (room for m // 2 + 1 per pass). ``table`` is the edge table of
    ``F`` as given (:meth:`~fracture.mesh.edges.EdgeTable.arrays`).

    The first pass tries every edge; a later one only the outer edges of the
    triangles the pass before flipped (the others' triangles are unchanged,
    and a flipped edge is locally Delaunay), found through each directed
    edge's twin, which the flips keep up to date: no edge table is rebuilt.
    No flip makes an edge that ``F`` had or an earlier flip made, so that
    restoring any flipped triangles to their first state
    (:func:`flip_edges`) cannot give an edge four triangles.
    """
    eid, count, first, second, start, hi, row = table
    m = F.shape[0]
    twin = np.full(3 * m, -1, np.int64)
    for e in range(count.shape[0]):
        if count[e] == 2:
            _link(twin, first[e], second[e])
    made = {(np.int64(0), np.int64(0))}
    made.clear()
    busy = np.zeros(m, np.bool_)
    work = first[_not_delaunay(V, F, first, second, count)]
    total = 0
    for _ in range(max_passes):
        busy[:] = False
        flipped = 0
        for r in work:
            g = _try_flip(V, F, sides, r, twin, busy, made, table)
            if g >= 0:
                pairs[total + flipped, 0], pairs[total + flipped, 1] = r // 3, g
                flipped += 1
        if flipped == 0:
            break
        work = np.empty(4 * flipped, np.int64)
        for j in range(flipped):
            f, g = pairs[total + j, 0], pairs[total + j, 1]
            work[4 * j], work[4 * j + 1], work[4 * j + 2], work[4 * j + 3] = 3 * f + 1, 3 * f + 2, 3 * g + 1, 3 * g + 2
        total += flipped
    return total


@numba.njit(cache=True, parallel=True)
def _not_delaunay(V, F, first, second, count):
    """Per edge: it has two triangles and the angles opposite it add up to more than pi (the Delaunay
    test of :func:`_try_flip`), for every edge at once on every thread. Most edges are Delaunay; the
    first pass tries only the others, in their order, with the outcome of trying all: an edge whose
    triangles no flip of the pass changed yet is tested on the same corners here, and one whose
    triangle a flip changed is skipped as busy anyway."""
    out = np.zeros(count.shape[0], np.bool_)
    for e in numba.prange(count.shape[0]):
        if count[e] != 2:
            continue
        r, r2 = first[e], second[e]
        f, g = r // 3, r2 // 3
        u, v, w = F[f, r % 3], F[f, (r + 1) % 3], F[f, (r + 2) % 3]
        x = F[g, (r2 + 2) % 3]
        out[e] = ((corner_obtuse(V, w, u, v) or corner_obtuse(V, x, v, u))
                  and corner_cot(V, w, u, v) + corner_cot(V, x, v, u) < -_DELAUNAY)
    return out


def pair_buffer(m: int, passes: int) -> np.ndarray:
    # a pass flips triangles that share none: at most m // 2 pairs
    return np.empty((passes * (m // 2 + 1), 2), np.int64)


@numba.njit(cache=True)
def flip_regions(m, done):
    """The triangles that flips ``done (k, 2)`` joined: per triangle the root of its group (a triangle
    of it), -1 for triangles no flip touched. The triangles of a group always cover the same
    polygon (a flip re-triangulates its two triangles' quad), so a group can go back to its first
    triangles without touching any other triangle."""
    parent = np.full(m, -1, np.int64)
    for i in range(done.shape[0]):
        for f in (done[i, 0], done[i, 1]):
            if parent[f] < 0:
                parent[f] = f
    for i in range(done.shape[0]):
        a, b = done[i, 0], done[i, 1]
        while parent[a] != a:
            a = parent[a]
        while parent[b] != b:
            b = parent[b]
        if a != b:
            parent[max(a, b)] = min(a, b)
    for f in range(m):
        if parent[f] >= 0:
            r = f
            while parent[r] != r:
                r = parent[r]
            parent[f] = r
    return parent


@numba.njit(cache=True, inline="always")
def _boxes_apart(V, F, f, c):
    """The bounding boxes of triangles f and c do not overlap."""
    for k in range(3):
        if (max(V[F[f, 0], k], V[F[f, 1], k], V[F[f, 2], k]) < min(V[F[c, 0], k], V[F[c, 1], k], V[F[c, 2], k])
                or max(V[F[c, 0], k], V[F[c, 1], k], V[F[c, 2], k]) < min(V[F[f, 0], k], V[F[f, 1], k], V[F[f, 2], k])):
            return True
    return False


# Groups of triangles are looked up in this many chunks per thread.
_CHUNKS_PER_THREAD = 4


def _meet_found(V, F, tris, starts, grid, ids, skip, sure, eps, out) -> None:
    """Mark in ``out`` the triangles ``tris`` that meet a triangle found in ``grid`` (element ``i`` is
    triangle ``ids[i]``); triangles with ``skip``, and those that share a vertex in ``sure``
    (:func:`~fracture.refine.fans.certified_fans`), are left out. Triangles already marked are not
    looked at again.

    ``tris`` come in groups ``starts[j]:starts[j + 1]`` of triangles near each
    other (those joined by flips): a group looks up the box around its
    triangles once (a look-up scans whole buckets, and a box twice as large
    finds little more), then each of its triangles tests what that found.
    The groups are looked up on every thread, in contiguous chunks (each
    writes only its own triangles' entries of ``out``).
    """
    _meet_found_parallel(V, F, tris, starts, grid, ids, skip, sure, eps, out, numba.get_num_threads())


@numba.njit(cache=True, parallel=True)
def _meet_found_parallel(V, F, tris, starts, grid, ids, skip, sure, eps, out, threads):
    n = starts.shape[0] - 1
    k = max(1, min(n, _CHUNKS_PER_THREAD * threads))
    for c in numba.prange(k):
        _meet_found_of(V, F, tris, starts, c * n // k, (c + 1) * n // k, grid, ids, skip, sure, eps, out)


@numba.njit(cache=True)
def _meet_found_of(V, F, tris, starts, begin, end, grid, ids, skip, sure, eps, out):
    """:func:`_meet_found` of the groups ``begin:end``."""
    buf = np.empty(256, np.int64)
    lo = np.empty(3)
    hi = np.empty(3)
    for j in range(begin, end):
        lo[:] = np.inf
        hi[:] = -np.inf
        for i in range(starts[j], starts[j + 1]):
            f = tris[i]
            for c in range(3):
                lo[c] = min(lo[c], V[F[f, 0], c], V[F[f, 1], c], V[F[f, 2], c])
                hi[c] = max(hi[c], V[F[f, 0], c], V[F[f, 1], c], V[F[f, 2], c])
        buf, k = hashgrid.gather(grid, lo, hi, buf)
        for i in range(starts[j], starts[j + 1]):
            if out[i]:
                continue
            f = tris[i]
            for n in range(k):
                c = ids[buf[n]]
                if (not skip[c] and c != f and not _boxes_apart(V, F, f, c) and not share_certified(F, f, c, sure)
                        and triangles_intersect(V, F, f, c, eps)):
                    out[i] = True
                    break


def _meet_any(V: np.ndarray, F: np.ndarray, tris: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Which triangles ``tris`` meet one of the triangles ``ids``."""
    out = np.zeros(len(tris), bool)
    _meet_found(V, F, tris, np.arange(len(tris) + 1), _grid_of(V, F, ids), ids, np.zeros(len(F), bool),
                np.zeros(len(V), bool), tol.static_test, out)
    return out


def _grid_of(V: np.ndarray, F: np.ndarray, ids: np.ndarray) -> tuple:
    """A hash grid of the triangles ``ids`` (element ``i`` is triangle ``ids[i]``)."""
    return triangle_grid(V, np.ascontiguousarray(F[ids]))


def unsafe_flips(V: np.ndarray, F: np.ndarray, grid: tuple, group: np.ndarray, sure: np.ndarray) -> np.ndarray:
    """Which of the triangles changed by flips (those in a ``group``, :func:`flip_regions`) meet another
    triangle of the surface, in the order of their ids. Pairs that share a vertex in ``sure`` (whose
    fan does not fold, :func:`~fracture.refine.fans.certified_fans`) are not tested.

    ``grid`` holds boxes that contain the triangles as they were before the
    flips (element ``f`` is triangle ``f``): it finds the triangles that are
    still so, one look-up per group of flips. The pairs of a hash of the
    changed triangles' boxes as they are now find those that meet each other.
    """
    is_changed = group >= 0
    changed = np.flatnonzero(is_changed)
    meets = np.zeros(len(F), bool)
    _meeting(V, F, changed[hashgrid.pairs(_grid_of(V, F, changed))], is_changed, sure, tol.static_test, meets)
    tris = changed[np.argsort(group[changed], kind="stable")]
    starts = np.r_[0, np.flatnonzero(np.diff(group[tris])) + 1, len(tris)]
    out = meets[tris]
    _meet_found(V, F, tris, starts, grid, np.arange(len(F)), is_changed, sure, tol.static_test, out)
    meets[tris] = out
    return meets[changed]


@numba.njit(cache=True)
def _meeting(V, F, pairs, changed, sure, eps, out):
    """Mark in ``out`` the ``changed`` triangles in one of the overlapping triangle ``pairs`` that meet
    (pairs that share a vertex in ``sure`` cannot)."""
    for i in range(pairs.shape[0]):
        a, b = pairs[i, 0], pairs[i, 1]
        if (not changed[a] or out[a]) and (not changed[b] or out[b]):
            continue  # decides nothing new
        if not share_certified(F, a, b, sure) and triangles_intersect(V, F, a, b, eps):
            out[a] |= changed[a]
            out[b] |= changed[b]


def unsafe_flips_all(V: np.ndarray, F: np.ndarray, is_changed: np.ndarray, sure: np.ndarray) -> np.ndarray:
    """:func:`unsafe_flips` at once: one hash of all the triangles as they are now lists the overlapping
    pairs, and those with a changed triangle are tested. When many triangles changed this costs
    less than a look-up in the grid per triangle."""
    out = np.zeros(len(F), bool)
    _meeting(V, F, hashgrid.pairs(triangle_grid(V, F)), is_changed, sure, tol.static_test, out)
    return out[is_changed]


def flip_edges(V: np.ndarray, F: np.ndarray, sides: np.ndarray, max_passes: int = 8,
               safe: bool = False, grid: tuple | None = None, table: EdgeTable | None = None,
               closed: np.ndarray | None = None) -> int:
    """Flip non-Delaunay edges of ``F`` in place (see the module notes); returns the number of flips.

    ``F`` must be a C-contiguous int64 array (it is edited in place). A flip
    replaces the two triangles of a non-planar quad by the other two. With
    ``safe`` no flipped triangle meets the rest of the surface: the passes
    run first (none makes an edge ``F`` had), then the triangles they changed
    are tested (a static test against their surroundings), every group of
    triangles joined by flips with one that meets something goes back to its
    first triangles, and the groups kept are tested again against those until
    none meets anything. ``grid`` may give a :mod:`~fracture.mesh.hashgrid`
    of boxes that contain the triangles as given (triangle ``f`` its element
    ``f``, e.g. the collision step's); else one is built if needed.
    ``table``, the :class:`~fracture.mesh.edges.EdgeTable` of ``F`` as
    given, saves building it, and ``closed``, its
    :func:`~fracture.refine.fans.closed_vertices`, finding those. The
    triangles around a vertex whose fan does not fold after the flips
    (:func:`~fracture.refine.fans.certified_fans`) are not tested against
    each other.
    """
    if F.dtype != np.int64 or not F.flags.c_contiguous:
        raise TypeError("F must be a C-contiguous int64 array")
    V = np.ascontiguousarray(V, np.float64)
    sides = np.ascontiguousarray(sides, np.int64)
    table = table if table is not None else edge_table(F, len(V))
    pairs = pair_buffer(len(F), max_passes)
    start = F.copy() if safe else None
    if safe and closed is None:
        closed = closed_vertices(F, len(V), table)
    total = int(flip_passes(V, F, sides, int(max_passes), pairs, table.arrays()))
    if not safe or not total:
        return total
    sure = certified_fans(V, V, F, closed)  # flips keep the closed vertices closed
    done = pairs[:total]
    group = flip_regions(len(F), done)
    is_changed = group >= 0
    changed = np.flatnonzero(is_changed)
    # many: all at once (about 0.5 us per triangle, against 1.6 to 1.8 per changed one)
    if len(changed) > 0.3 * len(F):
        meets = unsafe_flips_all(V, F, is_changed, sure)
    else:
        meets = unsafe_flips(V, F, grid if grid is not None else triangle_grid(V, start), group, sure)
    while meets.any():
        bad = np.zeros(len(F), bool)
        bad[group[changed[meets]]] = True
        back = changed[bad[group[changed]]]
        F[back] = start[back]
        group[back] = -1
        # going back changes only those triangles: the groups kept are tested
        # again against these alone (their other tests stand)
        changed = np.flatnonzero(group >= 0)
        meets = _meet_any(V, F, changed, back)
    return int((group[done[:, 0]] >= 0).sum())
