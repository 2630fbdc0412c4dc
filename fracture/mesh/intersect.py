"""Which triangles of a surface cross each other: the static self-intersection count, and the boxes
and hash grid of triangles it shares with the continuous collision step (numba).

libigl and pymeshlab answer static questions one mesh at a time; the refinement asks after every
step, so the count uses the same hierarchical hash (:mod:`fracture.mesh.hashgrid`) as the
collision step, and its segment-triangle test skips the square roots of pairs clearly on one side.
"""

from __future__ import annotations

import numba
import numpy as np

from fracture.mesh import hashgrid, vec
from fracture.tolerances import tol

# compiled code reads tolerances as module constants (fracture/tolerances.py says why each)
_SIDE_TEST_FLOOR = tol.side_test_floor

_EPS = tol.static_test


def typical_cell(X, E):
    """Four times the median length of edges ``E`` (of at most 4096 of them, evenly spread). Any size
    gives the same pairs: smaller cells hold fewer elements but put each in more of them. With the
    buckets sorted by x (:mod:`~fracture.mesh.hashgrid`) the size matters little
    (``docs/design-measurements.md``)."""
    if not len(E):
        return 1.0
    E = E[:: -(-len(E) // 4096)]
    e = X[E[:, 1]] - X[E[:, 0]]
    return 4.0 * float(np.sqrt(np.median(np.einsum("ij,ij->i", e, e))))


@numba.njit(cache=True)
def swept_boxes(X0, X1, elems, pad):
    """The boxes ``lo, hi (k, 3)`` of elements ``elems (k, w)`` (vertex ids) swept from ``X0`` to ``X1``,
    grown by ``pad``."""
    k, w = elems.shape
    lo = np.empty((k, 3))
    hi = np.empty((k, 3))
    for e in range(k):
        for c in range(3):
            a = np.inf
            b = -np.inf
            for j in range(w):
                v = elems[e, j]
                a = min(a, X0[v, c], X1[v, c])
                b = max(b, X0[v, c], X1[v, c])
            lo[e, c] = a - pad
            hi[e, c] = b + pad
    return lo, hi


@numba.njit(cache=True, inline="always")
def segment_hits_triangle(p, q, a, e1, e2, n, nn, eps):
    """Segment pq meets the triangle at ``a`` with edges ``e1, e2`` from it (normal ``n = e1 x e2`` of
    length ``nn``), edges included, crossing its plane.

    Signed volumes decide the side of p and q (a segment within ``eps``
    relative of the plane at both ends lies in it: coplanar overlaps are not
    crossings of a surface); the crossing point is then tested against the
    triangle with barycentric tolerance ``eps``. Touching counts: that is the
    conservative side for a check that must be 0.
    """
    d = vec.sub(q, p)
    tol = eps * nn * np.sqrt(vec.dot(d, d))
    op, oq = vec.dot(n, vec.sub(p, a)), vec.dot(n, vec.sub(q, a))
    if (op > tol and oq > tol) or (op < -tol and oq < -tol) or (abs(op) <= tol and abs(oq) <= tol):
        return False
    # one end within the tolerance of the plane and the other off it: the segment touches the plane at
    # that end, not beyond it (t outside [0, 1] put the point on the segment's extension, so two nearly
    # coplanar triangles side by side counted as crossing)
    t = min(max(op / (op - oq), 0.0), 1.0)
    x = vec.sub(vec.lerp(p, q, t), a)
    # barycentric coordinates of x in the triangle's plane
    d00, d01, d11 = vec.dot(e1, e1), vec.dot(e1, e2), vec.dot(e2, e2)
    d20, d21 = vec.dot(x, e1), vec.dot(x, e2)
    den = d00 * d11 - d01 * d01
    if den <= 0.0:
        return False
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return v >= -eps and w >= -eps and v + w <= 1.0 + eps


@numba.njit(cache=True, inline="always")
def clearly_one_side(p, q, a, n, nn2, eps):
    """Both ends of segment pq lie on one side of the plane through ``a`` with normal ``n``
    (``n . n = nn2``), each further from it than :func:`segment_hits_triangle`'s tolerance by a
    factor of sqrt 2, far beyond rounding: that test would reject the segment too. Squares, so no
    square roots (most pairs the static tests see are neighbours whose far edges lie off the
    other's plane)."""
    d = vec.sub(q, p)
    tol2 = eps * eps * nn2 * vec.dot(d, d)
    op, oq = vec.dot(n, vec.sub(p, a)), vec.dot(n, vec.sub(q, a))
    return (tol2 > _SIDE_TEST_FLOOR) & (op * oq > 0.0) & (op * op > 2.0 * tol2) & (oq * oq > 2.0 * tol2)


@numba.njit(cache=True)
def triangles_intersect(X, F, f, g, eps):
    """Triangles f and g meet anywhere but at the vertex or the edge they share.

    Two triangles with one shared vertex s meet beyond it only along a
    segment from s whose far end lies on an edge opposite s (otherwise the
    segment runs along an edge at s, inside the other triangle's plane): so
    only the two opposite edges are tested.
    """
    shared = -1
    count = 0
    for i in range(3):
        for j in range(3):
            if F[f, i] == F[g, j]:
                shared = F[f, i]
                count += 1
    if count >= 2:
        return False  # triangles on one edge meet only along it (coplanar folds aside)
    for (s, t) in ((f, g), (g, f)):
        a = vec.point(X, F[t, 0])
        e1, e2 = vec.sub(vec.point(X, F[t, 1]), a), vec.sub(vec.point(X, F[t, 2]), a)
        n = vec.cross(e1, e2)  # once per triangle, not per edge tested against it
        nn2 = vec.dot(n, n)
        nn = -1.0  # its length, once a segment needs the full test
        for k in range(3):
            u, v = F[s, k], F[s, (k + 1) % 3]
            if u == shared or v == shared:
                continue
            p, q = vec.point(X, u), vec.point(X, v)
            if clearly_one_side(p, q, a, n, nn2, eps):
                continue
            if nn < 0.0:
                nn = np.sqrt(nn2)
            if segment_hits_triangle(p, q, a, e1, e2, n, nn, eps):
                return True
    return False


@numba.njit(cache=True, parallel=True)
def _pair_tests(X, F, pairs, eps, first):
    """How many of the triangle ``pairs`` intersect; the first ``len(first)`` of them (in the pairs'
    order) are written to ``first``. Tested on every thread, each pair's answer in its own place: the
    same on any number of threads."""
    hit = np.zeros(pairs.shape[0], np.bool_)
    for i in numba.prange(pairs.shape[0]):
        hit[i] = triangles_intersect(X, F, pairs[i, 0], pairs[i, 1], eps)
    rows = np.flatnonzero(hit)
    m = min(rows.shape[0], first.shape[0])
    first[:m] = pairs[rows[:m]]
    return rows.shape[0]


def box_grid(lo: np.ndarray, hi: np.ndarray, X: np.ndarray, F: np.ndarray) -> tuple:
    """A :mod:`~fracture.mesh.hashgrid` of boxes ``lo, hi`` of triangles ``F`` over ``X``, its cells
    sized by their edges (:func:`typical_cell`)."""
    return hashgrid.build(lo, hi, 1.0 / hashgrid.cell_size(lo, hi, typical_cell(X, F[:, :2])))


def triangle_grid(V: np.ndarray, F: np.ndarray) -> tuple:
    """A :mod:`~fracture.mesh.hashgrid` of the triangles' bounding boxes."""
    return box_grid(*swept_boxes(V, V, F, 0.0), V, F)


def self_intersections(V: np.ndarray, F: np.ndarray, report: int = 0) -> int | tuple[int, np.ndarray]:
    """Number of pairs of triangles that meet other than at a shared vertex or edge.

    With ``report > 0`` also returns up to that many of the pairs, ``(k, 2)``.
    """
    V = np.ascontiguousarray(V, np.float64)
    F = np.ascontiguousarray(F, np.int64)
    first = np.zeros((report, 2), np.int64)
    count = 0
    if len(F) >= 2:
        count = _pair_tests(V, F, hashgrid.pairs(triangle_grid(V, F)), _EPS, first)
    return (int(count), first[:min(count, report)]) if report else int(count)


# With fewer than 1/this of the triangles ``touching``, meeting_pairs looks up their pairs one triangle at a
# time (hashgrid.pairs_with) rather than listing every pair and keeping theirs.
_FEW_TOUCHING = 4


def meeting_pairs(V: np.ndarray, F: np.ndarray, touching: np.ndarray | None = None) -> np.ndarray:
    """Every pair ``(k, 2)`` of triangles that meet other than at a shared vertex or edge; with
    ``touching`` (a mask of triangles) only the pairs with one of those in them (after a change of a few
    triangles, the pairs of the others are what they were: the tests are a fraction of the full count's)."""
    V = np.ascontiguousarray(V, np.float64)
    F = np.ascontiguousarray(F, np.int64)
    if len(F) < 2:
        return np.zeros((0, 2), np.int64)
    lo, hi = swept_boxes(V, V, F, 0.0)
    grid = box_grid(lo, hi, V, F)
    if touching is None:
        pairs = hashgrid.pairs(grid)
    elif _FEW_TOUCHING * (few := np.flatnonzero(touching)).size < len(F):  # a look-up per triangle
        pairs = hashgrid.pairs_with(grid, lo, hi, few)
    else:
        pairs = hashgrid.pairs(grid)
        pairs = np.ascontiguousarray(pairs[touching[pairs[:, 0]] | touching[pairs[:, 1]]])
    found = np.zeros((len(pairs), 2), np.int64)
    return found[:_pair_tests(V, F, pairs, _EPS, found)]
