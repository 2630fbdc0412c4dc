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

from fracture.topology import directed_edges, edge_keys


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
    ux, uy, uz = V[b, 0] - V[a, 0], V[b, 1] - V[a, 1], V[b, 2] - V[a, 2]
    vx, vy, vz = V[c, 0] - V[a, 0], V[c, 1] - V[a, 1], V[c, 2] - V[a, 2]
    return uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx


@numba.njit(cache=True)
def _dot(p, q):
    return p[0] * q[0] + p[1] * q[1] + p[2] * q[2]


@numba.njit(cache=True)
def _flip_pass(V, F, fa, fb, ka, kb, edge_set_keys, n):
    """One pass over candidate edges (triangles fa, fb; the edge is fa's edge ka, fb's edge kb)."""
    busy = np.zeros(F.shape[0], np.bool_)
    flipped = 0
    new_keys = {np.int64(0)}
    new_keys.clear()
    for i in range(fa.shape[0]):
        f, g = fa[i], fb[i]
        if busy[f] or busy[g]:
            continue
        # f = (u, v, w) with edge u->v; g = (v, u, x) with edge v->u
        u = F[f, ka[i]]
        v = F[f, (ka[i] + 1) % 3]
        w = F[f, (ka[i] + 2) % 3]
        if F[g, kb[i]] != v or F[g, (kb[i] + 1) % 3] != u:
            continue  # not consistently oriented
        x = F[g, (kb[i] + 2) % 3]
        if w == x:
            continue
        if _angle(V, w, u, v) + _angle(V, x, v, u) <= np.pi + 1e-12:
            continue
        lo = min(w, x)
        hi = max(w, x)
        key = lo * n + hi
        idx = np.searchsorted(edge_set_keys, key)
        if idx < edge_set_keys.shape[0] and edge_set_keys[idx] == key:
            continue
        if key in new_keys:
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
        new_keys.add(key)
        flipped += 1
    return flipped


def flip_edges(V: np.ndarray, F: np.ndarray, sides: np.ndarray, max_passes: int = 8) -> int:
    """Flip non-Delaunay edges in place (see the module notes); returns the number of flips."""
    total = 0
    n = len(V)
    for _ in range(max_passes):
        key = edge_keys(directed_edges(F), n)
        order = np.argsort(key, kind="stable")
        k = key[order]
        start = np.r_[True, k[1:] != k[:-1]]
        group = np.cumsum(start) - 1
        size = np.bincount(group)
        first = np.flatnonzero(start & (size[group] == 2))
        ea, eb = order[first], order[first + 1]
        fa, fb = ea // 3, eb // 3
        same = (np.sort(sides[fa], axis=1) == np.sort(sides[fb], axis=1)).all(axis=1) & (
            sides[fa, 0] == sides[fb, 0])
        fa, fb, ka, kb = fa[same], fb[same], ea[same] % 3, eb[same] % 3
        flipped = _flip_pass(V, F, fa, fb, ka, kb, k[start], n)  # k[start]: the sorted unique keys
        total += flipped
        if flipped == 0:
            break
    return total
