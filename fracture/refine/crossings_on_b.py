"""Boundary curves that cross on B.

The boundary vertices of the fracture surface slide on B. Two boundary
curves (of two sheets, or two parts of one) can cross there without their
chords meeting in space: a chord sags below a curved B, and two chords that
cross on B's surface pass each other at different depths, which continuous
collision detection cannot see. Crossing curves make the pieces of Sec. 5
ill-defined (B cannot be cut along both), so a step that would make two
curves cross is not taken for the vertices involved, as a collision stops a
vertex (Sec. 4.4).

Two boundary edges cross on B when they are near each other in space and,
seen along B's normal there, their segments cross. Written here because no
library tests segments for crossing on a surface.
"""

from __future__ import annotations

import numba
import numpy as np
from scipy.spatial import cKDTree

from fracture.mesh import vec
from fracture.tolerances import tol

_TINY = tol.tiny  # a module constant: compiled code reads globals as constants


def crossing_pairs(X: np.ndarray, E: np.ndarray, normal_at, gap: float = 0.0) -> np.ndarray:
    """Pairs ``(k, 2)`` of boundary edges ``E`` (rows of vertex ids into ``X``) that cross on B, or come
    closer than ``gap`` there.

    ``normal_at(P)`` gives B's unit normal near points ``P (k, 3)``. Edges that
    share a vertex never count (they meet at it).
    """
    pairs, _ = close_pairs(X, E, normal_at, gap)
    return pairs


def close_pairs(X: np.ndarray, E: np.ndarray, normal_at, gap: float = 0.0,
                candidates: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`crossing_pairs` and, for each pair, whether it crosses (rather than only comes close).

    ``candidates``: pairs ``i < j`` of edges, sorted and unique, among which the close ones are
    (:func:`candidate_pairs`); by default they are searched for at ``X``."""
    none = np.zeros((0, 2), np.int64), np.zeros(0, bool)
    if len(E) < 2:
        return none
    A, B = X[E[:, 0]], X[E[:, 1]]
    M, L = 0.5 * (A + B), np.linalg.norm(B - A, axis=1)
    pairs = _candidates(M, L, gap) if candidates is None else candidates
    if not len(pairs):
        return none
    keep = _near_apart(E, M, L, pairs, gap)
    i, j = pairs[keep, 0], pairs[keep, 1]
    if not len(i):
        return none
    n = np.ascontiguousarray(normal_at(0.5 * (M[i] + M[j])), np.float64)
    close, cross = _on_b(X, E, i, j, n, gap)
    return np.stack([i[close], j[close]], 1), cross[close]


@numba.njit(cache=True)
def _near_apart(E, M, L, pairs, gap):
    """Which candidate pairs of edges (midpoints ``M``, lengths ``L``) are near (midpoints within half
    their lengths' sum and ``gap``) and share no vertex."""
    keep = np.zeros(pairs.shape[0], np.bool_)
    for k in range(pairs.shape[0]):
        a, b = pairs[k, 0], pairs[k, 1]
        p, q, r, s = E[a, 0], E[a, 1], E[b, 0], E[b, 1]
        if p == r or p == s or q == r or q == s:
            continue
        keep[k] = vec.norm(vec.sub(vec.point(M, a), vec.point(M, b))) <= 0.5 * (L[a] + L[b]) + gap
    return keep


@numba.njit(cache=True)
def _on_b(X, E, i, j, n, gap):
    """For edge pairs ``(i, j)`` and B's normal ``n`` near them: whether, seen along ``n``, the edges
    cross or come within ``gap`` of each other, and whether they cross."""
    close = np.zeros(i.shape[0], np.bool_)
    cross = np.zeros(i.shape[0], np.bool_)
    for k in range(i.shape[0]):
        nk = vec.point(n, k)
        helper = (1.0, 0.0, 0.0) if abs(nk[0]) < 0.9 else (0.0, 1.0, 0.0)  # a frame of B's tangent plane
        u = vec.cross(nk, helper)
        nu = vec.norm(u)
        u = (u[0] / nu, u[1] / nu, u[2] / nu)
        v = vec.cross(nk, u)
        a = _flat(vec.point(X, E[i[k], 0]), u, v)
        b = _flat(vec.point(X, E[i[k], 1]), u, v)
        c = _flat(vec.point(X, E[j[k], 0]), u, v)
        d = _flat(vec.point(X, E[j[k], 1]), u, v)
        cross[k] = (_side(a, b, c) * _side(a, b, d) < 0) and (_side(c, d, a) * _side(c, d, b) < 0)
        close[k] = cross[k] or (gap > 0.0 and min(_point_segment(a, c, d), _point_segment(b, c, d),
                                                   _point_segment(c, a, b), _point_segment(d, a, b)) < gap)
    return close, cross


@numba.njit(cache=True, inline="always")
def _flat(P, u, v):
    return (vec.dot(P, u), vec.dot(P, v))


@numba.njit(cache=True, inline="always")
def _side(p, q, r):
    """Sign of the turn p -> q -> r."""
    return np.sign((q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]))


@numba.njit(cache=True, inline="always")
def _point_segment(p, a, b):
    """Distance of 2D point ``p`` from segment ``a b``."""
    ab0, ab1 = b[0] - a[0], b[1] - a[1]
    t = min(max(((p[0] - a[0]) * ab0 + (p[1] - a[1]) * ab1) / max(ab0 * ab0 + ab1 * ab1, _TINY), 0.0), 1.0)
    return np.sqrt((a[0] + t * ab0 - p[0]) ** 2 + (a[1] + t * ab1 - p[1]) ** 2)


def candidate_pairs(X: np.ndarray, E: np.ndarray, gap: float, move=0.0) -> np.ndarray:
    """Pairs of edges ``E`` (sorted, unique) among which are all those that come within ``gap`` of each
    other at ``X``, or at any positions of their vertices within ``move`` of ``X`` (one distance, or per
    edge its ends' largest): an edge's midpoint moves by at most its ends' largest move ``m`` and its length
    changes by at most ``2 m``, so each edge is searched for as if ``4 m`` longer. One search then serves
    the checks of a step's trial positions (:func:`close_pairs`). Per edge, one boundary vertex that
    moves far widens its own edges' search only: with one distance for all, a step that put one vertex
    five cells away on B paired every boundary edge of the collapsing wall's searched surface with a
    fifth of the others (1.1 million pairs, 0.7 s per step)."""
    if len(E) < 2:
        return np.zeros((0, 2), np.int64)
    A, B = X[E[:, 0]], X[E[:, 1]]
    return _candidates(0.5 * (A + B), np.linalg.norm(B - A, axis=1) + 4.0 * np.asarray(move, np.float64), gap)


def _candidates(M: np.ndarray, L: np.ndarray, gap: float) -> np.ndarray:
    """Pairs ``i < j`` (sorted, unique) of edges with midpoints ``M`` and lengths ``L`` whose midpoints are
    within ``(L_i + L_j) / 2 + gap`` of each other, and possibly a few more.

    One search radius for all (the longest edge's) would pair every short
    edge with hundreds of others once a few long edges remain on a refined
    boundary (a chord along a flat face of B). So the edges up to the 90th
    percentile ``r0`` of the lengths are paired within ``r0``, each longer
    edge with the shorter ones within its reach of them, and the longer
    edges among themselves within the longest one's.
    """
    tree = cKDTree(M)
    r0 = float(np.percentile(L, 90))
    found = [tree.query_pairs(r0 + gap, output_type="ndarray")]
    long_ = np.flatnonzero(L > r0)
    if len(long_):
        reach = tree.query_ball_point(M[long_], 0.5 * (L[long_] + r0) + gap, return_sorted=False)
        counts = np.fromiter((len(r) for r in reach), np.int64, len(reach))
        if counts.sum():
            others = np.concatenate([np.asarray(r, np.int64) for r in reach if len(r)])
            mine = np.repeat(long_, counts)
            found.append(np.stack([np.minimum(mine, others), np.maximum(mine, others)], 1)[mine != others])
        among = cKDTree(M[long_]).query_pairs(float(L.max()) + gap, output_type="ndarray")
        found.append(np.sort(long_[among], axis=1))
    pairs = np.concatenate(found).astype(np.int64).reshape(-1, 2)
    # unique rows through one integer key each, in the same (lexicographic) order:
    # np.unique(axis=0) sorts a structured view, five times slower
    key = np.unique(pairs[:, 0] * len(M) + pairs[:, 1])
    return np.stack([key // len(M), key % len(M)], 1)


def splits_would_cross(V: np.ndarray, E: np.ndarray, which: np.ndarray, M: np.ndarray, normal_at) -> np.ndarray:
    """Which of the splits of boundary edges ``E[which]`` at points ``M`` (on B) would make their halves
    cross another boundary edge on B (a midpoint projected across a nearby curve), ``(len(which),)``."""
    k = len(which)
    if not k:
        return np.zeros(0, bool)
    X = np.concatenate([V, M])
    m = len(V) + np.arange(k)
    halves = np.concatenate([np.stack([E[which, 0], m], 1), np.stack([m, E[which, 1]], 1)])
    gone = np.zeros(len(E), bool)
    gone[which] = True
    bad = edges_would_cross(X, E, gone, halves, normal_at)
    return bad[:k] | bad[k:]


def edges_would_cross(X: np.ndarray, E: np.ndarray, gone: np.ndarray, new: np.ndarray, normal_at) -> np.ndarray:
    """Which of the boundary edges ``new`` would cross on B another boundary edge (or one another) if they
    replaced the edges ``E[gone]`` (a mask), ``(len(new),)``."""
    if not len(new):
        return np.zeros(0, bool)
    first_new = int((~gone).sum())
    pairs = crossing_pairs(X, np.concatenate([E[~gone], new]), normal_at)
    bad = np.zeros(len(new), bool)
    for side in pairs.T:
        bad[side[side >= first_new] - first_new] = True
    return bad
