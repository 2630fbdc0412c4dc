"""Collision constraints and the self-intersection count (Section 4.4), compiled with numba.

Continuous collision detection in the style of Bridson et al. 2002: every
vertex moves on a straight line from ``X0`` to ``X1`` during a step. A vertex
and a triangle (or two edges) collide when the four points become coplanar at
some ``t`` in [0, 1] (a cubic in ``t``) and, at that moment, the vertex lies
in the triangle (the edges cross) within a thickness ``eta``, or when they end
the step closer than ``eta`` and closer than they started. The vertices of
every colliding pair are stopped (``X1 = X0``) and the test repeats until no
pair collides: a surface that does not intersect itself at ``X0`` does not
at ``X1``.

Broad phase: a hierarchical grid hashed into a table of buckets (a counting
sort, no Python loop). Every triangle and edge goes into the cells its swept
box covers, on the level where that is at most 2 x 2 x 2 cells; a pair is
tested once, in the cell holding the lower corner of the intersection of the
two boxes. Pairs further apart than their relative move are dropped before
the cubic. libigl and pymeshlab answer static questions
only (``pymeshlab`` selects self-intersecting faces of one mesh state), so
the moving test is written here, and the static count :func:`self_intersections`
shares its grid (the tests check it against an all-pairs search).
"""

from __future__ import annotations

import numba
import numpy as np

_P1, _P2, _P3, _P4 = 73856093, 19349663, 83492791, 2654435761
_EPS = 1e-10  # relative tolerance of the static tests


@numba.njit(cache=True, inline="always")
def _hash(ix, iy, iz, level, mask):
    return ((ix * _P1) ^ (iy * _P2) ^ (iz * _P3) ^ (level * _P4)) & mask


@numba.njit(cache=True, inline="always")
def _cell(x, inv):
    return np.int64(np.floor(x * inv))


@numba.njit(cache=True)
def _level(lo, hi, inv):
    """The level at which a box spans at most two cells per axis (cells double per level)."""
    extent = max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) * inv
    level = 0
    while extent > 1.0 and level < 40:
        extent *= 0.5
        level += 1
    return level


@numba.njit(cache=True)
def _build_grid(lo, hi, inv, mask):
    """Bucket boxes ``lo, hi (k, 3)`` into a hierarchical hashed grid.

    Every box goes to the level where it covers at most 2 x 2 x 2 cells (cell
    size ``2^level / inv``), so large and small elements cost the same.
    Returns ``(start, items, level, slot_box, slot_level)``: buckets as a CSR
    table of element ids, each element's level, and per slot a copy of its
    element's box (``(s, 6)``, lower then upper corner) and level, so a query
    scans its buckets' boxes in order instead of looking each element up.
    """
    k = lo.shape[0]
    level = np.empty(k, np.int64)
    start = np.zeros(mask + 2, np.int64)
    for e in range(k):
        level[e] = L = _level(lo[e], hi[e], inv)
        s = inv / 2.0 ** L
        for ix in range(_cell(lo[e, 0], s), _cell(hi[e, 0], s) + 1):
            for iy in range(_cell(lo[e, 1], s), _cell(hi[e, 1], s) + 1):
                for iz in range(_cell(lo[e, 2], s), _cell(hi[e, 2], s) + 1):
                    start[_hash(ix, iy, iz, L, mask) + 1] += 1
    for b in range(mask + 1):
        start[b + 1] += start[b]
    fill = start[:-1].copy()
    items = np.empty(start[-1], np.int64)
    slot_box = np.empty((start[-1], 6))
    slot_level = np.empty(start[-1], np.int64)
    for e in range(k):
        L = level[e]
        s = inv / 2.0 ** L
        for ix in range(_cell(lo[e, 0], s), _cell(hi[e, 0], s) + 1):
            for iy in range(_cell(lo[e, 1], s), _cell(hi[e, 1], s) + 1):
                for iz in range(_cell(lo[e, 2], s), _cell(hi[e, 2], s) + 1):
                    h = _hash(ix, iy, iz, L, mask)
                    p = fill[h]
                    items[p] = e
                    for c in range(3):
                        slot_box[p, c] = lo[e, c]
                        slot_box[p, 3 + c] = hi[e, c]
                    slot_level[p] = L
                    fill[h] += 1
    return start, items, level, slot_box, slot_level


@numba.njit(cache=True)
def _gather(qlo, qhi, min_level, grid, inv, mask, buf):
    """Elements of ``grid`` whose boxes overlap the box ``qlo, qhi``, each once, into ``buf``.

    Levels below ``min_level`` are skipped. An element is reported from the
    cell (at its own level) holding the lower corner of the two boxes'
    intersection. Returns (buf, count); ``buf`` grows when full.
    """
    start, items, level, max_level, box, slot_level = grid
    count = 0
    for L in range(min_level, max_level + 1):
        s = inv / 2.0 ** L
        for ix in range(_cell(qlo[0], s), _cell(qhi[0], s) + 1):
            for iy in range(_cell(qlo[1], s), _cell(qhi[1], s) + 1):
                for iz in range(_cell(qlo[2], s), _cell(qhi[2], s) + 1):
                    h = _hash(ix, iy, iz, L, mask)
                    for p in range(start[h], start[h + 1]):
                        if slot_level[p] != L:
                            continue
                        if not (qlo[0] <= box[p, 3] and box[p, 0] <= qhi[0] and qlo[1] <= box[p, 4]
                                and box[p, 1] <= qhi[1] and qlo[2] <= box[p, 5] and box[p, 2] <= qhi[2]):
                            continue
                        if (_cell(max(qlo[0], box[p, 0]), s) != ix or _cell(max(qlo[1], box[p, 1]), s) != iy
                                or _cell(max(qlo[2], box[p, 2]), s) != iz):
                            continue
                        if count == buf.shape[0]:
                            bigger = np.empty(2 * buf.shape[0], np.int64)
                            bigger[:count] = buf
                            buf = bigger
                        buf[count] = items[p]
                        count += 1
    return buf, count


@numba.njit(cache=True)
def _grid(lo, hi, inv, mask):
    start, items, level, slot_box, slot_level = _build_grid(lo, hi, inv, mask)
    return start, items, level, (level.max() if level.shape[0] else 0), slot_box, slot_level


# -- geometry ------------------------------------------------------------------------------


@numba.njit(cache=True, inline="always")
def _pt(X, i):
    return (X[i, 0], X[i, 1], X[i, 2])


@numba.njit(cache=True, inline="always")
def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@numba.njit(cache=True, inline="always")
def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@numba.njit(cache=True, inline="always")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@numba.njit(cache=True, inline="always")
def _lerp(a, b, t):
    return (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), a[2] + t * (b[2] - a[2]))


@numba.njit(cache=True)
def _point_triangle_distance2(p, a, b, c):
    """Squared distance from p to triangle abc (Ericson, Real-Time Collision Detection 5.1.5)."""
    ab, ac, ap = _sub(b, a), _sub(c, a), _sub(p, a)
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    if d1 <= 0.0 and d2 <= 0.0:
        q = a
    else:
        bp = _sub(p, b)
        d3, d4 = _dot(ab, bp), _dot(ac, bp)
        cp = _sub(p, c)
        d5, d6 = _dot(ab, cp), _dot(ac, cp)
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
    d = _sub(p, q)
    return _dot(d, d)


@numba.njit(cache=True)
def _segment_segment_distance2(p1, q1, p2, q2):
    """Squared distance between segments p1q1 and p2q2 (Ericson 5.1.9)."""
    d1, d2, r = _sub(q1, p1), _sub(q2, p2), _sub(p1, p2)
    a, e, f = _dot(d1, d1), _dot(d2, d2), _dot(d2, r)
    if a <= 1e-300 and e <= 1e-300:
        return _dot(r, r)
    if a <= 1e-300:
        s, t = 0.0, min(max(f / e, 0.0), 1.0)
    else:
        c = _dot(d1, r)
        if e <= 1e-300:
            t, s = 0.0, min(max(-c / a, 0.0), 1.0)
        else:
            b = _dot(d1, d2)
            den = a * e - b * b
            s = min(max((b * f - c * e) / den, 0.0), 1.0) if den > 0.0 else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                t, s = 0.0, min(max(-c / a, 0.0), 1.0)
            elif t > 1.0:
                t, s = 1.0, min(max((b - c) / a, 0.0), 1.0)
    x = (p1[0] + d1[0] * s - p2[0] - d2[0] * t, p1[1] + d1[1] * s - p2[1] - d2[1] * t,
         p1[2] + d1[2] * s - p2[2] - d2[2] * t)
    return _dot(x, x)


@numba.njit(cache=True)
def _coplanar_times(a0, a1, b0, b1, c0, c1, d0, d1, out):
    """Times in [0, 1] at which moving points a, b, c, d are (nearly) coplanar; returns their number.

    det[b - a, c - a, d - a](t) is a cubic. It is sampled at its end points and
    at the roots of its derivative (monotone pieces in between), each sign
    change is bisected, and every extremum where it nearly vanishes is kept
    too (touching without crossing, and sheets that move in their own plane).
    """
    def f(t):
        a = _lerp(a0, a1, t)
        return _dot(_cross(_sub(_lerp(b0, b1, t), a), _sub(_lerp(c0, c1, t), a)), _sub(_lerp(d0, d1, t), a))

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
    if abs(qa) > 1e-14 * (abs(qb) + abs(qc) + 1e-300):
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
    tiny = 1e-9 * scale + 1e-300
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
    return np.sqrt(_dot(x, x))


@numba.njit(cache=True)
def _inside_at(p, a, b, c, eps):
    """The projection of p onto the plane of abc lies in the triangle (barycentric tolerance eps)."""
    e1, e2, x = _sub(b, a), _sub(c, a), _sub(p, a)
    d00, d01, d11 = _dot(e1, e1), _dot(e1, e2), _dot(e2, e2)
    d20, d21 = _dot(x, e1), _dot(x, e2)
    den = d00 * d11 - d01 * d01
    if den <= 1e-30 * d00 * d11:
        return False  # degenerate triangle: the edge-edge tests see it
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return v >= -eps and w >= -eps and v + w <= 1.0 + eps


@numba.njit(cache=True)
def _segments_cross_at(p, q, r, s, eps):
    """Coplanar segments pq and rs cross (line parameters within [-eps, 1 + eps])."""
    d1, d2, w = _sub(q, p), _sub(s, r), _sub(p, r)
    a, b, c = _dot(d1, d1), _dot(d1, d2), _dot(d2, d2)
    d, e = _dot(d1, w), _dot(d2, w)
    den = a * c - b * b
    if den <= 1e-24 * a * c:
        return False  # parallel: the vertex-triangle tests see these
    u = (b * e - c * d) / den
    v = (a * e - b * d) / den
    return -eps <= u <= 1.0 + eps and -eps <= v <= 1.0 + eps


@numba.njit(cache=True)
def _vertex_triangle_hit(p0, p1, a0, a1, b0, b1, c0, c1, eta2, times):
    start = _point_triangle_distance2(p0, a0, b0, c0)
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
        if _inside_at(_lerp(p0, p1, t), _lerp(a0, a1, t), _lerp(b0, b1, t), _lerp(c0, c1, t), 1e-9):
            return True
    # contact at the end of the step that is closer than at its start (pairs
    # resting in contact, e.g. sheets meeting on B, may stay so)
    end = _point_triangle_distance2(p1, a1, b1, c1)
    return end <= eta2 and end < start


@numba.njit(cache=True)
def _edge_edge_hit(p0, p1, q0, q1, r0, r1, s0, s1, eta2, times):
    start = _segment_segment_distance2(p0, q0, r0, s0)
    reach = max(_relative_move(p0, p1, r0, r1), _relative_move(p0, p1, s0, s1),
                _relative_move(q0, q1, r0, r1), _relative_move(q0, q1, s0, s1))
    if start > (reach + np.sqrt(eta2)) ** 2:
        return False
    n = _coplanar_times(p0, p1, q0, q1, r0, r1, s0, s1, times)
    for i in range(n):
        t = times[i]
        if _segments_cross_at(_lerp(p0, p1, t), _lerp(q0, q1, t), _lerp(r0, r1, t), _lerp(s0, s1, t), 1e-9):
            return True
    end = _segment_segment_distance2(p1, q1, r1, s1)
    return end <= eta2 and end < start


@numba.njit(cache=True)
def _swept_boxes(X0, X1, elems, pad):
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


def _table_size(k):
    return max(1 << 10, 1 << int(np.ceil(np.log2(2 * k + 1))))


@numba.njit(cache=True)
def _vertex_triangle_pair(X0, X1, F, v, f, eta2, times, stop):
    """Test vertex v against triangle f (not one of its corners); marks a colliding pair in ``stop``."""
    a, b, c = F[f, 0], F[f, 1], F[f, 2]
    if v == a or v == b or v == c:
        return 0
    if not _vertex_triangle_hit(_pt(X0, v), _pt(X1, v), _pt(X0, a), _pt(X1, a),
                                _pt(X0, b), _pt(X1, b), _pt(X0, c), _pt(X1, c), eta2, times):
        return 0
    stop[v] = stop[a] = stop[b] = stop[c] = True
    return 1


@numba.njit(cache=True)
def _vertex_triangle_pairs(X0, X1, F, query, by_vertex, vlo, vhi, tlo, thi, grid, inv, mask, eta2, stop):
    """Vertex-triangle pairs of the elements ``query``: vertices against the triangle grid
    (``by_vertex``), or triangles against the vertex grid; marks colliding pairs in ``stop``."""
    times = np.empty(4)
    buf = np.empty(256, np.int64)
    hits = 0
    for q in query:
        if by_vertex:
            buf, k = _gather(vlo[q], vhi[q], 0, grid, inv, mask, buf)
            for i in range(k):
                hits += _vertex_triangle_pair(X0, X1, F, q, buf[i], eta2, times, stop)
        else:
            buf, k = _gather(tlo[q], thi[q], 0, grid, inv, mask, buf)
            for i in range(k):
                hits += _vertex_triangle_pair(X0, X1, F, buf[i], q, eta2, times, stop)
    return hits


@numba.njit(cache=True)
def _edge_edge_pairs(X0, X1, E, qe, elo, ehi, grid, inv, mask, eta2, all_pairs, stop):
    """Query edges ``qe`` against the edge grid.

    With ``all_pairs`` (``qe`` is every edge) each pair is tested once: an
    edge looks at its own level and the coarser ones only, and of two edges on
    one level the lower index asks.
    """
    times = np.empty(4)
    buf = np.empty(256, np.int64)
    level = grid[2]
    hits = 0
    for e in qe:
        p, q = E[e, 0], E[e, 1]
        buf, k = _gather(elo[e], ehi[e], level[e] if all_pairs else 0, grid, inv, mask, buf)
        for i in range(k):
            g = buf[i]
            if g == e or (all_pairs and level[g] == level[e] and g < e):
                continue
            r, s = E[g, 0], E[g, 1]
            if p == r or p == s or q == r or q == s:
                continue
            if _edge_edge_hit(_pt(X0, p), _pt(X1, p), _pt(X0, q), _pt(X1, q),
                              _pt(X0, r), _pt(X1, r), _pt(X0, s), _pt(X1, s), eta2, times):
                hits += 1
                stop[p] = stop[q] = stop[r] = stop[s] = True
    return hits


def _cell_size(X, E):
    """Twice the median length of edges ``E``: cells about the size of the elements' boxes."""
    if not len(E):
        return 1.0
    e = X[E[:, 1]] - X[E[:, 0]]
    return max(2.0 * float(np.sqrt(np.median(np.einsum("ij,ij->i", e, e)))), 1e-12)


def stop_collisions(X0: np.ndarray, X1: np.ndarray, F: np.ndarray, E: np.ndarray, eta: float,
                    max_rounds: int = 32) -> tuple[np.ndarray, int]:
    """Stop the vertices of colliding pairs, in place in ``X1``, until the step is collision-free.

    The first round tests every pair; stopping a vertex changes only the
    paths of the elements on it, so each later round tests just those
    elements (against everything), on the same grids (the boxes of the full
    step contain the shortened paths).

    Parameters
    ----------
    X0, X1 : (n, 3) float
        Positions before and after the step (``X1`` is edited).
    F : (m, 3) int
        Triangles; ``E (k, 2)`` their unique edges.
    eta : float
        Thickness: closer than this counts as contact.

    Returns
    -------
    stopped : (n,) bool
        Vertices held at ``X0``.
    pairs : int
        Colliding pairs found in the first round.
    """
    X0 = np.ascontiguousarray(X0, np.float64)
    F = np.ascontiguousarray(F, np.int64)
    E = np.ascontiguousarray(E, np.int64)
    n = len(X0)
    stopped = np.zeros(n, bool)
    if not len(E) and not len(F):
        return stopped, 0
    inv = 1.0 / _cell_size(X0, E if len(E) else F[:, :2])
    mask = _table_size(len(E) + len(F)) - 1
    eta2 = float(eta) ** 2
    vlo, vhi = _swept_boxes(X0, X1, np.arange(n).reshape(-1, 1), eta)
    tlo, thi = _swept_boxes(X0, X1, F, eta)
    elo, ehi = _swept_boxes(X0, X1, E, eta)
    tgrid = _grid(tlo, thi, inv, mask)
    egrid = _grid(elo, ehi, inv, mask)
    vgrid = None
    qv, qt, qe = np.arange(n), np.zeros(0, np.int64), np.arange(len(E))
    first = None
    for _ in range(max_rounds):
        stop = np.zeros(n, bool)
        pairs = _vertex_triangle_pairs(X0, X1, F, qv, True, vlo, vhi, tlo, thi, tgrid, inv, mask, eta2, stop)
        if len(qt):
            vgrid = _grid(vlo, vhi, inv, mask) if vgrid is None else vgrid
            pairs += _vertex_triangle_pairs(X0, X1, F, qt, False, vlo, vhi, tlo, thi, vgrid, inv, mask, eta2, stop)
        pairs += _edge_edge_pairs(X0, X1, E, qe, elo, ehi, egrid, inv, mask, eta2, first is None, stop)
        first = pairs if first is None else first
        stop &= ~stopped  # pairs of stopped vertices only are at rest: contact they had at X0
        if not stop.any():
            return stopped, first
        X1[stop] = X0[stop]
        stopped |= stop
        qv = np.flatnonzero(stop)
        qt = np.flatnonzero(stop[F].any(axis=1))
        qe = np.flatnonzero(stop[E].any(axis=1))
    # still colliding: nothing moves, and the state at X0 is intersection-free
    X1[:] = X0
    stopped[:] = True
    return stopped, first


# -- static self-intersections ---------------------------------------------------------------


@numba.njit(cache=True)
def _segment_hits_triangle(p, q, a, b, c, eps):
    """Segment pq meets triangle abc, edges included, crossing its plane.

    Signed volumes decide the side of p and q (a segment within ``eps``
    relative of the plane at both ends lies in it: coplanar overlaps are not
    crossings of a surface); the crossing point is then tested against the
    triangle with barycentric tolerance ``eps``. Touching counts: that is the
    conservative side for a check that must be 0.
    """
    e1, e2 = _sub(b, a), _sub(c, a)
    n = _cross(e1, e2)
    nn = np.sqrt(_dot(n, n))
    d = _sub(q, p)
    tol = eps * nn * np.sqrt(_dot(d, d))
    op, oq = _dot(n, _sub(p, a)), _dot(n, _sub(q, a))
    if (op > tol and oq > tol) or (op < -tol and oq < -tol) or (abs(op) <= tol and abs(oq) <= tol):
        return False
    t = op / (op - oq)
    x = _sub(_lerp(p, q, t), a)
    # barycentric coordinates of x in the triangle's plane
    d00, d01, d11 = _dot(e1, e1), _dot(e1, e2), _dot(e2, e2)
    d20, d21 = _dot(x, e1), _dot(x, e2)
    den = d00 * d11 - d01 * d01
    if den <= 0.0:
        return False
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return v >= -eps and w >= -eps and v + w <= 1.0 + eps


@numba.njit(cache=True)
def _triangles_intersect(X, F, f, g, eps):
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
        a, b, c = _pt(X, F[t, 0]), _pt(X, F[t, 1]), _pt(X, F[t, 2])
        for k in range(3):
            u, v = F[s, k], F[s, (k + 1) % 3]
            if u == shared or v == shared:
                continue
            if _segment_hits_triangle(_pt(X, u), _pt(X, v), a, b, c, eps):
                return True
    return False


@numba.njit(cache=True)
def _intersections(X, F, query, all_pairs, inv, mask, eps, first):
    """Static triangle-triangle intersections of the triangles ``query`` with all others.

    With ``all_pairs`` (``query`` is every triangle) each pair is counted once
    (a triangle looks at its own level and coarser ones; of two on one level
    the lower index asks). Returns the pair count and a mask over ``query`` of
    the triangles that meet another; the first ``len(first)`` pairs are written
    to ``first``.
    """
    lo, hi = _swept_boxes(X, X, F, 0.0)
    grid = _grid(lo, hi, inv, mask)
    level = grid[2]
    buf = np.empty(256, np.int64)
    count = 0
    hit = np.zeros(query.shape[0], np.bool_)
    for i in range(query.shape[0]):
        f = query[i]
        buf, k = _gather(lo[f], hi[f], level[f] if all_pairs else 0, grid, inv, mask, buf)
        for j in range(k):
            g = buf[j]
            if g == f or (all_pairs and level[g] == level[f] and g < f):
                continue
            if _triangles_intersect(X, F, f, g, eps):
                if count < first.shape[0]:
                    first[count, 0], first[count, 1] = f, g
                count += 1
                hit[i] = True
    return count, hit


@numba.njit(cache=True)
def _query_hits(X, F, query, inv, mask, eps):
    """Mask over ``query`` of the triangles that meet another triangle of ``F``.

    The grid holds only the query triangles and every triangle looks itself
    up in it: for a few queries (the flips of one pass) that is a scan of the
    triangles' boxes instead of a grid of all of them.
    """
    lo, hi = _swept_boxes(X, X, F, 0.0)
    grid = _grid(lo[query], hi[query], inv, mask)
    buf = np.empty(256, np.int64)
    hit = np.zeros(query.shape[0], np.bool_)
    for g in range(F.shape[0]):
        buf, k = _gather(lo[g], hi[g], 0, grid, inv, mask, buf)
        for j in range(k):
            i = buf[j]
            f = query[i]
            if f != g and not hit[i] and _triangles_intersect(X, F, f, g, eps):
                hit[i] = True
    return hit


def _static(V, F, query, all_pairs, report=0):
    V = np.ascontiguousarray(V, np.float64)
    F = np.ascontiguousarray(F, np.int64)
    first = np.zeros((report, 2), np.int64)
    if len(F) < 2 or not len(query):
        return 0, np.zeros(len(query), bool), first[:0]
    count, hit = _intersections(V, F, np.ascontiguousarray(query, np.int64), all_pairs,
                                1.0 / _cell_size(V, F[:, :2]), _table_size(len(F)) - 1, _EPS, first)
    return int(count), hit, first[:min(count, report)]


def self_intersections(V: np.ndarray, F: np.ndarray, report: int = 0) -> int | tuple[int, np.ndarray]:
    """Number of pairs of triangles that meet other than at a shared vertex or edge.

    With ``report > 0`` also returns up to that many of the pairs, ``(k, 2)``.
    """
    count, _, pairs = _static(V, F, np.arange(len(F)), True, report)
    return (count, pairs) if report else count


def faces_intersecting(V: np.ndarray, F: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Which of the triangles ``query`` meet another triangle of ``F`` (other than at shared vertices or edges)."""
    V = np.ascontiguousarray(V, np.float64)
    F = np.ascontiguousarray(F, np.int64)
    query = np.ascontiguousarray(query, np.int64)
    if len(F) < 2 or not len(query):
        return np.zeros(len(query), bool)
    if 8 * len(query) > len(F):
        return _static(V, F, query, False)[1]
    return _query_hits(V, F, query, 1.0 / _cell_size(V, F[:, :2]), _table_size(len(query)) - 1, _EPS)
