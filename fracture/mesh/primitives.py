"""Simple meshes for examples and tests: boxes and parametric sheets."""

from __future__ import annotations

import numpy as np


def grid_faces(nu: int, nv: int) -> np.ndarray:
    """Triangles of an ``nu x nv`` node grid (row-major nodes), two per cell."""
    i, j = np.meshgrid(np.arange(nu - 1), np.arange(nv - 1), indexing="ij")
    a = (i * nv + j).ravel()
    b, c, d = a + nv, a + nv + 1, a + 1
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)


def box(lo, hi, divisions=(1, 1, 1)) -> tuple[np.ndarray, np.ndarray]:
    """A closed, outward-oriented triangulated box.

    Parameters
    ----------
    lo, hi : (3,) float
    divisions : (3,) int
        Cells along x, y and z on each face.

    Returns
    -------
    V : (n, 3) float
    F : (m, 3) int
    """
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    n = np.asarray(divisions, np.int64)
    Vs, Fs, offset = [], [], 0
    for axis in range(3):
        u, v = [a for a in range(3) if a != axis]
        for side, value in ((0, lo[axis]), (1, hi[axis])):
            su = np.linspace(lo[u], hi[u], n[u] + 1)
            sv = np.linspace(lo[v], hi[v], n[v] + 1)
            U, W = np.meshgrid(su, sv, indexing="ij")
            P = np.empty((U.size, 3))
            P[:, axis], P[:, u], P[:, v] = value, U.ravel(), W.ravel()
            F = grid_faces(n[u] + 1, n[v] + 1)
            # grid_faces winds counter-clockwise in (u, v): its normal is
            # e_u x e_v, which is -e_y for axis 1 and +e_axis otherwise.
            positive = axis != 1
            if positive != (side == 1):
                F = F[:, ::-1]
            Vs.append(P)
            Fs.append(F + offset)
            offset += len(P)
    V = np.concatenate(Vs)
    F = np.concatenate(Fs)
    # Weld the nodes shared by neighbouring faces: every node lies on the
    # lattice lo + k * (hi - lo) / n, so its integer lattice index is its key.
    key = np.round((V - lo) / (hi - lo) * n).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return V[first], inverse.reshape(-1)[F]


def cylinder(radius: float = 0.5, height: float = 3.0, segments: int = 64, rings: int = 12,
             axis: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """A closed, outward-oriented cylinder from 0 to ``height`` along ``axis``.

    The side is ``segments`` x ``rings`` quads (two triangles each); the caps
    are fans around their centres.
    """
    th = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    ring = np.stack([radius * np.cos(th), radius * np.sin(th)], 1)
    P = np.concatenate([np.column_stack([ring, np.full(segments, z)]) for z in np.linspace(0.0, height, rings)])
    i = np.arange(segments)
    j = np.arange(rings - 1)[:, None]
    a = (j * segments + i).ravel()
    b = (j * segments + (i + 1) % segments).ravel()
    side = np.concatenate([np.stack([a, b, b + segments], 1), np.stack([a, b + segments, a + segments], 1)])
    c0, c1 = len(P), len(P) + 1
    top = (rings - 1) * segments
    caps = np.concatenate([np.stack([np.full(segments, c0), (i + 1) % segments, i], 1),
                           np.stack([np.full(segments, c1), top + i, top + (i + 1) % segments], 1)])
    P = np.vstack([P, [0.0, 0.0, 0.0], [0.0, 0.0, height]])
    order = [(axis + 1) % 3, (axis + 2) % 3, axis]  # the cylinder's (x, y, z) go to these axes
    V = np.empty_like(P)
    V[:, order] = P
    return V, np.concatenate([side, caps]).astype(np.int64)


def sheet(fn, u_range, v_range, nu: int, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """A parametric sheet ``fn(u, v) -> (..., 3)`` on an ``nu x nv`` node grid."""
    U, W = np.meshgrid(np.linspace(*u_range, nu), np.linspace(*v_range, nv), indexing="ij")
    P = np.asarray(fn(U.ravel(), W.ravel()), np.float64)
    return P, grid_faces(nu, nv)
