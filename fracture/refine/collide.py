"""Collision constraints (Section 4.4), compiled with numba.

Continuous collision detection in the style of Bridson et al. 2002: every
vertex moves on a straight line from ``X0`` to ``X1`` during a step. A vertex
and a triangle (or two edges) collide when the four points become coplanar at
some ``t`` in [0, 1] (a cubic in ``t``) and, at that moment, the vertex lies
in the triangle (the edges cross) within a thickness ``eta``, or when they end
the step closer than ``eta`` and closer than they started. The vertices of
every colliding pair are stopped (``X1 = X0``) and the test repeats until no
pair collides: a surface that does not intersect itself at ``X0`` does not
at ``X1``.

Broad phase: the swept boxes of the triangles go into a hierarchical
spatial hash (:mod:`fracture.mesh.hashgrid`), which lists every
overlapping pair once; each pair tests the vertices and edges its two
triangles represent (every feature has one representative triangle, Curtis
et al. 2008). Pairs of triangles around a vertex whose fan provably cannot
fold during the step (:mod:`fracture.refine.fans`) are skipped, and pairs
further apart than their relative move are dropped before the cubic.
libigl and pymeshlab answer static questions only (``pymeshlab`` selects
self-intersecting faces of one mesh state), so the moving test is written
here; the static count (:func:`fracture.mesh.intersect.self_intersections`)
uses the same hash.
"""

from __future__ import annotations

import numba
import numpy as np

from fracture.tolerances import tol

from fracture.mesh import hashgrid
from fracture.refine.fans import certified_fans, closed_vertices, share_certified
from fracture.mesh.edges import edge_table, EdgeTable
from fracture.mesh import vec
from fracture.mesh.intersect import box_grid, swept_boxes

# compiled code reads tolerances as module constants (fracture/tolerances.py says why each)
_TINY = tol.tiny
_CUBIC_LEADING = tol.cubic_leading
_CUBIC_ROOT = tol.cubic_root
_DEGENERATE_GRAM = tol.degenerate_gram
_PARALLEL_EDGES = tol.parallel_edges
_CONTACT_SLACK = tol.contact_slack

_EPS = tol.static_test
# The features a triangle represents (represented_features), as bits of one integer: bit k its vertex k,
# bit _EDGE_SHIFT + k its edge k (F[f, k] -> F[f, k + 1]).
_VERTEX_0 = 1
_ALL_VERTICES = 0b000111
_EDGE_SHIFT = 3
_EDGE_0 = 1 << _EDGE_SHIFT
_ALL_EDGES = 0b111000


# -- geometry ------------------------------------------------------------------------------


@numba.njit(cache=True)
def point_triangle_distance2(p, a, b, c):
    """Squared distance from p to triangle abc (Ericson, Real-Time Collision Detection 5.1.5); a triangle
    of no area (two corners in one place, or three on a line) is its three edges."""
    ab, ac, ap = vec.sub(b, a), vec.sub(c, a), vec.sub(p, a)
    n = vec.cross(ab, ac)
    if vec.dot(n, n) == 0.0:  # Ericson's regions divide by the area
        return min(_point_segment_distance2(p, a, b), _point_segment_distance2(p, b, c),
                   _point_segment_distance2(p, c, a))
    d1, d2 = vec.dot(ab, ap), vec.dot(ac, ap)
    if d1 <= 0.0 and d2 <= 0.0:
        q = a
    else:
        bp = vec.sub(p, b)
        d3, d4 = vec.dot(ab, bp), vec.dot(ac, bp)
        cp = vec.sub(p, c)
        d5, d6 = vec.dot(ab, cp), vec.dot(ac, cp)
        vc = d1 * d4 - d3 * d2
        vb = d5 * d2 - d1 * d6
        va = d3 * d6 - d5 * d4
        if d3 >= 0.0 and d4 <= d3:
            q = b
        elif d6 >= 0.0 and d5 <= d6:
            q = c
        elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
            v = d1 / (d1 - d3)
            q = (a[0] + v * ab[0], a[1] + v * ab[1], a[2] + v * ab[2])
        elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
            w = d2 / (d2 - d6)
            q = (a[0] + w * ac[0], a[1] + w * ac[1], a[2] + w * ac[2])
        elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
            w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
            q = (b[0] + w * (c[0] - b[0]), b[1] + w * (c[1] - b[1]), b[2] + w * (c[2] - b[2]))
        else:
            s = 1.0 / (va + vb + vc)
            v, w = vb * s, vc * s
            q = (a[0] + ab[0] * v + ac[0] * w, a[1] + ab[1] * v + ac[1] * w, a[2] + ab[2] * v + ac[2] * w)
    d = vec.sub(p, q)
    return vec.dot(d, d)


@numba.njit(cache=True)
def _point_segment_distance2(p, a, b):
    """Squared distance from p to segment ab (a point if a = b)."""
    ab, ap = vec.sub(b, a), vec.sub(p, a)
    length2 = vec.dot(ab, ab)
    t = min(max(vec.dot(ap, ab) / length2, 0.0), 1.0) if length2 > 0.0 else 0.0
    d = (ap[0] - t * ab[0], ap[1] - t * ab[1], ap[2] - t * ab[2])
    return vec.dot(d, d)


@numba.njit(cache=True)
def _segment_segment_distance2(p1, q1, p2, q2):
    """Squared distance between segments p1q1 and p2q2 (Ericson 5.1.9)."""
    d1, d2, r = vec.sub(q1, p1), vec.sub(q2, p2), vec.sub(p1, p2)
    a, e, f = vec.dot(d1, d1), vec.dot(d2, d2), vec.dot(d2, r)
    if a <= _TINY and e <= _TINY:
        return vec.dot(r, r)
    if a <= _TINY:
        s, t = 0.0, min(max(f / e, 0.0), 1.0)
    else:
        c = vec.dot(d1, r)
        if e <= _TINY:
            t, s = 0.0, min(max(-c / a, 0.0), 1.0)
        else:
            b = vec.dot(d1, d2)
            den = a * e - b * b
            s = min(max((b * f - c * e) / den, 0.0), 1.0) if den > 0.0 else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                t, s = 0.0, min(max(-c / a, 0.0), 1.0)
            elif t > 1.0:
                t, s = 1.0, min(max((b - c) / a, 0.0), 1.0)
    x = (p1[0] + d1[0] * s - p2[0] - d2[0] * t, p1[1] + d1[1] * s - p2[1] - d2[1] * t,
         p1[2] + d1[2] * s - p2[2] - d2[2] * t)
    return vec.dot(x, x)


@numba.njit(cache=True)
def _coplanar_times(a0, a1, b0, b1, c0, c1, d0, d1, out):
    """Times in [0, 1] at which moving points a, b, c, d are (nearly) coplanar; returns their number.

    det[b - a, c - a, d - a](t) is a cubic. It is sampled at its end points and
    at the roots of its derivative (monotone pieces in between), each sign
    change is bisected, and every extremum where it nearly vanishes is kept
    too (touching without crossing, and sheets that move in their own plane).
    """
    def f(t):
        a = vec.lerp(a0, a1, t)
        return vec.dot(vec.cross(vec.sub(vec.lerp(b0, b1, t), a), vec.sub(vec.lerp(c0, c1, t), a)), vec.sub(vec.lerp(d0, d1, t), a))

    # the cubic's coefficients from four samples (exact for a cubic)
    f0, f1, f2, f3 = f(0.0), f(1.0 / 3.0), f(2.0 / 3.0), f(1.0)
    k3 = 4.5 * (f3 - 3.0 * f2 + 3.0 * f1 - f0)
    k2 = 9.0 * (f0 - 2.5 * f1 + 2.0 * f2 - 0.5 * f3)
    k1 = -5.5 * f0 + 9.0 * f1 - 4.5 * f2 + f3
    scale = abs(f0) + abs(f1) + abs(f2) + abs(f3)
    knots = np.empty(4)
    knots[0] = 0.0
    nk = 1
    # roots of 3 c3 t^2 + 2 c2 t + c1
    qa, qb, qc = 3.0 * k3, 2.0 * k2, k1
    if abs(qa) > _CUBIC_LEADING * (abs(qb) + abs(qc) + _TINY):
        disc = qb * qb - 4.0 * qa * qc
        if disc >= 0.0:
            sq = np.sqrt(disc)
            r1, r2 = (-qb - sq) / (2.0 * qa), (-qb + sq) / (2.0 * qa)
            if r1 > r2:
                r1, r2 = r2, r1
            for r in (r1, r2):
                if 0.0 < r < 1.0:
                    knots[nk] = r
                    nk += 1
    elif abs(qb) > 0.0:
        r = -qc / qb
        if 0.0 < r < 1.0:
            knots[nk] = r
            nk += 1
    n = 0
    tiny = _CUBIC_ROOT * scale + _TINY
    prev_t, prev_f = 0.0, f0
    if abs(f0) <= tiny:
        out[n] = 0.0
        n += 1
    for i in range(1, nk + 1):
        t = knots[i] if i < nk else 1.0
        ft = f(t)
        if abs(ft) <= tiny:
            out[n] = t
            n += 1
        elif prev_f * ft < 0.0 and abs(prev_f) > tiny:
            lo, hi, flo = prev_t, t, prev_f
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                fm = f(mid)
                if (fm < 0.0) == (flo < 0.0):
                    lo, flo = mid, fm
                else:
                    hi = mid
            out[n] = 0.5 * (lo + hi)
            n += 1
        prev_t, prev_f = t, ft
    return n


@numba.njit(cache=True, inline="always")
def _relative_move(p0, p1, q0, q1):
    """|(p1 - p0) - (q1 - q0)|: how much closer two points can get during the step."""
    x = (p1[0] - p0[0] - q1[0] + q0[0], p1[1] - p0[1] - q1[1] + q0[1], p1[2] - p0[2] - q1[2] + q0[2])
    return np.sqrt(vec.dot(x, x))


@numba.njit(cache=True)
def _inside_at(p, a, b, c, eps):
    """The projection of p onto the plane of abc lies in the triangle (barycentric tolerance eps)."""
    e1, e2, x = vec.sub(b, a), vec.sub(c, a), vec.sub(p, a)
    d00, d01, d11 = vec.dot(e1, e1), vec.dot(e1, e2), vec.dot(e2, e2)
    d20, d21 = vec.dot(x, e1), vec.dot(x, e2)
    den = d00 * d11 - d01 * d01
    if den <= _DEGENERATE_GRAM * d00 * d11:
        return False  # degenerate triangle: the edge-edge tests see it
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return v >= -eps and w >= -eps and v + w <= 1.0 + eps


@numba.njit(cache=True)
def _segments_cross_at(p, q, r, s, eps):
    """Coplanar segments pq and rs cross (line parameters within [-eps, 1 + eps])."""
    d1, d2, w = vec.sub(q, p), vec.sub(s, r), vec.sub(p, r)
    a, b, c = vec.dot(d1, d1), vec.dot(d1, d2), vec.dot(d2, d2)
    d, e = vec.dot(d1, w), vec.dot(d2, w)
    den = a * c - b * b
    if den <= _PARALLEL_EDGES * a * c:
        return False  # parallel: the vertex-triangle tests see these
    u = (b * e - c * d) / den
    v = (a * e - b * d) / den
    return -eps <= u <= 1.0 + eps and -eps <= v <= 1.0 + eps


@numba.njit(cache=True)
def vertex_triangle_hit(p0, p1, a0, a1, b0, b1, c0, c1, eta2, times):
    start = point_triangle_distance2(p0, a0, b0, c0)
    # the distance shrinks by at most the largest move of p relative to a corner
    # (the triangle's points are convex combinations of its corners): a pair
    # further apart than that cannot meet, whatever the path (most pairs)
    reach = max(_relative_move(p0, p1, a0, a1), _relative_move(p0, p1, b0, b1), _relative_move(p0, p1, c0, c1))
    if start > (reach + np.sqrt(eta2)) ** 2:
        return False
    n = _coplanar_times(p0, p1, a0, a1, b0, b1, c0, c1, times)
    for i in range(n):
        t = times[i]
        # coplanar at t: a hit if p is in the triangle then (a test of
        # position in the plane, well conditioned however the root is)
        if _inside_at(vec.lerp(p0, p1, t), vec.lerp(a0, a1, t), vec.lerp(b0, b1, t), vec.lerp(c0, c1, t), _CONTACT_SLACK):
            return True
    # contact at the end of the step that is closer than at its start (pairs
    # resting in contact, e.g. sheets meeting on B, may stay so)
    end = point_triangle_distance2(p1, a1, b1, c1)
    return end <= eta2 and end < start


@numba.njit(cache=True)
def edge_edge_hit(p0, p1, q0, q1, r0, r1, s0, s1, eta2, times):
    start = _segment_segment_distance2(p0, q0, r0, s0)
    reach = max(_relative_move(p0, p1, r0, r1), _relative_move(p0, p1, s0, s1),
                _relative_move(q0, q1, r0, r1), _relative_move(q0, q1, s0, s1))
    if start > (reach + np.sqrt(eta2)) ** 2:
        return False
    n = _coplanar_times(p0, p1, q0, q1, r0, r1, s0, s1, times)
    for i in range(n):
        t = times[i]
        if _segments_cross_at(vec.lerp(p0, p1, t), vec.lerp(q0, q1, t), vec.lerp(r0, r1, t), vec.lerp(s0, s1, t), _CONTACT_SLACK):
            return True
    end = _segment_segment_distance2(p1, q1, r1, s1)
    return end <= eta2 and end < start


@numba.njit(cache=True)
def represented_features(F, n, eid):
    """Which features every triangle represents (Curtis et al. 2008): bit ``k`` its vertex ``k``,
    bit ``3 + k`` its edge ``k`` (``F[f, k] -> F[f, k + 1]``, edge id ``eid[3 f + k]``); each
    vertex and each edge has one representative.

    A pair of triangles tests the edges only if both represent one, and the
    vertices only if one of them represents one: the fewer triangles
    represent anything, the fewer pairs cost more than a look. So the
    features are packed into few triangles, greedily: first every triangle
    none of whose edges is taken takes all three; of the edges left, a
    triangle with two of them takes both, then a triangle that represents
    an edge already takes its others, and the rest go to their first
    triangle. The vertices then go to triangles that represent an edge,
    first to those that can take all three of theirs, then two, then one
    (fewer representing triangles than first-come, first-served: see
    ``docs/design-measurements.md``).
    """
    m = F.shape[0]
    rep = np.zeros(m, np.int64)
    taken = np.zeros(eid.max() + 1 if eid.shape[0] else 0, np.bool_)
    for f in range(m):
        if not taken[eid[3 * f]] and not taken[eid[3 * f + 1]] and not taken[eid[3 * f + 2]]:
            taken[eid[3 * f]] = taken[eid[3 * f + 1]] = taken[eid[3 * f + 2]] = True
            rep[f] = _ALL_EDGES
    for rule in range(3):  # two edges left; represents an edge already; any
        for f in range(m):
            left = 0
            for k in range(3):
                left += not taken[eid[3 * f + k]]
            if left == 0 or (rule == 0 and left < 2) or (rule == 1 and rep[f] == 0):
                continue
            for k in range(3):
                if not taken[eid[3 * f + k]]:
                    taken[eid[3 * f + k]] = True
                    rep[f] |= _EDGE_0 << k
    # every vertex of a triangle is on one of its edges, whose representative holds it too
    held = np.zeros(n, np.bool_)
    for least in (3, 2, 1):
        for f in range(m):
            if rep[f] == 0:
                continue
            free = 0
            for k in range(3):
                free += not held[F[f, k]]
            if free < least:
                continue
            for k in range(3):
                if not held[F[f, k]]:
                    held[F[f, k]] = True
                    rep[f] |= _VERTEX_0 << k
    return rep


def path_boxes(X0: np.ndarray, X1: np.ndarray) -> np.ndarray:
    """Per vertex the box of its path, ``(n, 6)``: lower corner, then upper corner."""
    return np.hstack([np.minimum(X0, X1), np.maximum(X0, X1)])


@numba.njit(cache=True, inline="always")
def _near(B, v, lo, hi, t, F):
    """Vertex v, not a corner of triangle t, has its path box overlap t's box ``lo[t], hi[t]``
    (``&`` rather than ``and``: no branches, most pairs are rejected)."""
    return ((v != F[t, 0]) & (v != F[t, 1]) & (v != F[t, 2])
            & (B[v, 3] >= lo[t, 0]) & (B[v, 0] <= hi[t, 0]) & (B[v, 4] >= lo[t, 1]) & (B[v, 1] <= hi[t, 1])
            & (B[v, 5] >= lo[t, 2]) & (B[v, 2] <= hi[t, 2]))


@numba.njit(cache=True, inline="always")
def _any_on(on, F, f):
    return on[F[f, 0]] or on[F[f, 1]] or on[F[f, 2]]


# With fewer than 1/this of the triangles on moving vertices, their pairs are looked up one triangle at a
# time rather than listed with every other pair (hashgrid.pairs_with).
_FEW_ACTIVE = 8
# The pairs are tested in this many chunks per thread (pairs near a fold cost more than the rest).
_CHUNKS_PER_THREAD = 4


def feature_tests(X0, X1, F, B, lo, hi, rep, pairs, eta, every, on, sure, stop) -> int:
    """Test the features that the triangles of each overlapping pair represent against each other:
    the vertices of each against the other triangle, and the edges of one against the edges of the
    other. ``B`` holds the vertices' path boxes (:func:`path_boxes`), ``lo, hi`` the triangles'
    swept boxes grown by ``eta``. Unless ``every``, only the features with a vertex in ``on`` are
    tested (the pairs are those with such a vertex). Pairs of triangles that share a vertex in
    ``sure`` (:func:`~fracture.refine.fans.certified_fans`) are skipped. Marks the vertices of
    colliding features in ``stop``; returns their number.

    Every vertex-triangle pair whose swept boxes overlap is tested once, from
    the pair of the vertex's representative and the triangle (their boxes
    overlap too); every edge pair once, from its representatives' pair. The
    pairs are tested on every thread in contiguous chunks; threads only ever
    set entries of ``stop``, so its result does not depend on their number.
    """
    return _feature_tests(X0, X1, F, B, lo, hi, rep, pairs, eta, every, on, sure, stop, numba.get_num_threads())


@numba.njit(cache=True, parallel=True)
def _feature_tests(X0, X1, F, B, lo, hi, rep, pairs, eta, every, on, sure, stop, threads):
    n = pairs.shape[0]
    k = max(1, min(n, _CHUNKS_PER_THREAD * threads))
    hits = np.zeros(k, np.int64)
    for c in numba.prange(k):
        hits[c] = _feature_tests_of(X0, X1, F, B, lo, hi, rep, pairs, c * n // k, (c + 1) * n // k, eta, every, on,
                                    sure, stop)
    return hits.sum()


@numba.njit(cache=True)
def _feature_tests_of(X0, X1, F, B, lo, hi, rep, pairs, begin, end, eta, every, on, sure, stop):
    """:func:`feature_tests` of the pairs ``begin:end``."""
    times = np.empty(4)
    eta2 = eta * eta
    box = np.empty((6, 6))  # the edges' path boxes of both triangles, the first three grown by eta
    hits = 0
    for i in range(begin, end):
        a, b = pairs[i, 0], pairs[i, 1]
        if share_certified(F, a, b, sure):
            continue  # every feature of one fan: they cannot meet
        for (s, t) in ((a, b), (b, a)):  # the vertices s represents against triangle t
            r = rep[s]
            if not r & _ALL_VERTICES:
                continue
            near = ((((r & _VERTEX_0) != 0) & _near(B, F[s, 0], lo, hi, t, F))
                    | ((((r & (_VERTEX_0 << 1)) != 0) & _near(B, F[s, 1], lo, hi, t, F)) << 1)
                    | ((((r & (_VERTEX_0 << 2)) != 0) & _near(B, F[s, 2], lo, hi, t, F)) << 2))
            for k in range(3):
                if near & (1 << k) and (every or on[F[s, k]] or _any_on(on, F, t)):
                    hits += _vertex_triangle_pair(X0, X1, F, F[s, k], t, eta2, times, stop)
        if not rep[a] & _ALL_EDGES or not rep[b] & _ALL_EDGES:
            continue
        for k in range(3):  # the edges a represents against those b does
            for (f, row, pad) in ((a, k, eta), (b, 3 + k, 0.0)):
                p, q = F[f, k], F[f, (k + 1) % 3]
                for c in range(3):
                    box[row, c] = min(B[p, c], B[q, c]) - pad
                    box[row, 3 + c] = max(B[p, 3 + c], B[q, 3 + c]) + pad
        near = 0  # bit 3 k + j: edge k of a and edge j of b share no vertex and their boxes overlap
        for k in range(3):
            p, q = F[a, k], F[a, (k + 1) % 3]
            for j in range(3):
                r, s = F[b, j], F[b, (j + 1) % 3]
                near |= ((((rep[a] >> (_EDGE_SHIFT + k)) & (rep[b] >> (_EDGE_SHIFT + j)) & 1) != 0)
                         & (p != r) & (p != s) & (q != r) & (q != s)
                         & (box[k, 3] >= box[3 + j, 0]) & (box[3 + j, 3] >= box[k, 0]) & (box[k, 4] >= box[3 + j, 1])
                         & (box[3 + j, 4] >= box[k, 1]) & (box[k, 5] >= box[3 + j, 2])
                         & (box[3 + j, 5] >= box[k, 2])) << (3 * k + j)
        if not near:
            continue
        for k in range(3):
            p, q = F[a, k], F[a, (k + 1) % 3]
            for j in range(3):
                r, s = F[b, j], F[b, (j + 1) % 3]
                if not near & (1 << (3 * k + j)) or not (every or on[p] or on[q] or on[r] or on[s]):
                    continue
                if edge_edge_hit(vec.point(X0, p), vec.point(X1, p), vec.point(X0, q), vec.point(X1, q),
                                  vec.point(X0, r), vec.point(X1, r), vec.point(X0, s), vec.point(X1, s), eta2, times):
                    hits += 1
                    stop[p] = stop[q] = stop[r] = stop[s] = True
    return hits


@numba.njit(cache=True)
def _vertex_triangle_pair(X0, X1, F, v, f, eta2, times, stop):
    """Test vertex v against triangle f (not one of its corners); marks a colliding pair in ``stop``."""
    a, b, c = F[f, 0], F[f, 1], F[f, 2]
    if not vertex_triangle_hit(vec.point(X0, v), vec.point(X1, v), vec.point(X0, a), vec.point(X1, a),
                                vec.point(X0, b), vec.point(X1, b), vec.point(X0, c), vec.point(X1, c), eta2, times):
        return 0
    stop[v] = stop[a] = stop[b] = stop[c] = True
    return 1


@numba.njit(cache=True, parallel=True)
def _touching(F, on):
    """Per triangle: it has a vertex in ``on``."""
    touched = np.zeros(F.shape[0], np.bool_)
    for f in numba.prange(F.shape[0]):
        touched[f] = _any_on(on, F, f)
    return touched


@numba.njit(cache=True, parallel=True)
def _pairs_touching(F, pairs, on):
    """The rows of triangle ``pairs`` with a vertex in ``on`` (in their order)."""
    touched = _touching(F, on)
    keep = np.empty(pairs.shape[0], np.bool_)
    for i in numba.prange(pairs.shape[0]):
        keep[i] = touched[pairs[i, 0]] | touched[pairs[i, 1]]
    return pairs[np.flatnonzero(keep)]


def _marked(n: int, ids: np.ndarray) -> np.ndarray:
    out = np.zeros(n, bool)
    out[ids] = True
    return out


def stop_collisions(X0: np.ndarray, X1: np.ndarray, F: np.ndarray, eta: float, table: EdgeTable | None = None,
                    max_rounds: int = 32, return_grid: bool = False, moving: np.ndarray | None = None,
                    closed: np.ndarray | None = None):
    """Stop the vertices of colliding pairs, in place in ``X1``, until the step is collision-free.

    Broad phase: the pairs of triangles whose swept boxes overlap, from one
    :mod:`~fracture.mesh.hashgrid`. Each vertex and each edge is represented
    by one of its triangles, and a pair of triangles tests the features they
    represent (Curtis, Tamstorf and Manocha 2008): every vertex-triangle and
    edge-edge pair that can meet is tested once, and the grid holds a third of
    the elements that grids of the vertices, edges and triangles would. Pairs
    of triangles around a vertex whose fan cannot fold during the step
    (:mod:`~fracture.refine.fans`) are not tested: they are nine in ten.

    The first round tests every pair; stopping a vertex changes only the
    paths of the features on it, so each later round tests just those (from
    the same triangle pairs: the boxes of the full step contain the shortened
    paths; and all of them, as the fans were certified for the full step).
    With ``moving`` (vertex ids; every other vertex has ``X1 == X0``) the
    first round too tests only the features on them: two features at rest
    cannot collide.

    Parameters
    ----------
    X0, X1 : (n, 3) float
        Positions before and after the step (``X1`` is edited).
    F : (m, 3) int
        Triangles.
    eta : float
        Thickness: closer than this counts as contact.
    table : EdgeTable, optional
        The edges of ``F`` (:func:`~fracture.mesh.edges.edge_table`);
        built if not given.
    closed : (n,) bool, optional
        :func:`~fracture.refine.fans.closed_vertices` of ``F``, if known.

    Returns
    -------
    stopped : (n,) bool
        Vertices held at ``X0``.
    pairs : int
        Colliding pairs found in the first round.
    grid : tuple
        With ``return_grid``: the :mod:`~fracture.mesh.hashgrid` of the
        triangles' swept boxes (grown by ``eta``), which contain the
        triangles at ``X1`` too.
    """
    X0 = np.ascontiguousarray(X0, np.float64)
    F = np.ascontiguousarray(F, np.int64)
    n = len(X0)
    stopped = np.zeros(n, bool)
    if not len(F):
        return (stopped, 0, None) if return_grid else (stopped, 0)
    table = table if table is not None else edge_table(F, n)
    eta = float(eta)
    lo, hi = swept_boxes(X0, X1, F, eta)
    grid = box_grid(lo, hi, X0, F)
    # a later round (or, with ``moving``, the first) tests only the triangle pairs with a vertex in ``on``
    every = moving is None
    on = np.zeros(n, bool) if every else _marked(n, moving)
    # with ``moving``, no round tests a pair without a moving vertex: two triangles at rest cannot collide
    if every:
        overlapping = hashgrid.pairs(grid)
    elif _FEW_ACTIVE * (active := np.flatnonzero(_touching(F, on))).size < len(F):
        # a few vertices move (the boundary settling onto B): the pairs of the triangles on them alone,
        # a look-up each
        overlapping = hashgrid.pairs_with(grid, lo, hi, active)
    else:
        overlapping = _pairs_touching(F, hashgrid.pairs(grid), on)
    rep = represented_features(F, n, np.ascontiguousarray(table.eid, np.int64))
    B = path_boxes(X0, X1)
    todo = overlapping
    unsure = np.zeros(n, bool)
    sure = unsure
    if every or 4 * len(moving) > n:  # the first round tests the full step of many vertices: certify the fans
        sure = certified_fans(X0, X1, F, closed if closed is not None else closed_vertices(F, n, table))
    first = None
    for _ in range(max_rounds):
        stop = np.zeros(n, bool)
        pairs = feature_tests(X0, X1, F, B, lo, hi, rep, todo, eta, every, on, sure, stop)
        first = pairs if first is None else first
        stop &= ~stopped  # pairs of stopped vertices only are at rest: contact they had at X0
        if not stop.any():
            return (stopped, first, grid) if return_grid else (stopped, first)
        X1[stop] = X0[stop]
        B[stop, 3:] = B[stop, :3] = X0[stop]
        stopped |= stop
        every, on, sure = False, stop, unsure
        todo = _pairs_touching(F, overlapping, on)
    # still colliding: nothing moves, and the state at X0 is intersection-free
    X1[:] = X0
    stopped[:] = True
    return (stopped, first, grid) if return_grid else (stopped, first)


# -- static self-intersections ---------------------------------------------------------------


