"""Virtual fracture (Section 4.1): extend incomplete cuts until they split the object.

An incomplete cut ends inside the object: some boundary edges of the fracture
surface (its *crack front*) do not lie on the exterior B. :func:`extend_cuts`
grows the surface from the front in the cut's own separation direction (in
the plane of the triangle behind each front edge, away from it), one strip of
triangles per step, until every front vertex has crossed B; the crossing is
located by bisection on the winding number of B and projected onto B. The
added triangles are virtual fracture: they separate the object into
components but never open in the animation.
"""

from __future__ import annotations

import numpy as np

from fracture.errors import InputError
from fracture.mesh.exterior import Exterior
from fracture.tolerances import tol
from fracture.mesh.topology import boundary_conormals, boundary_edges, directed_edge_face


def _crack_front(V, F, B: Exterior) -> tuple[np.ndarray, np.ndarray]:
    """Front edges (oriented as in their triangle) and, per front vertex, whether it is off B."""
    E = boundary_edges(F)
    if not len(E):
        return np.zeros((0, 2), np.int64), np.zeros((0, 2), bool)
    diag = float(np.linalg.norm(np.ptp(B.V, axis=0)))
    off = (B.distance(V[E.ravel()]) > tol.on_surface * diag).reshape(-1, 2)
    front = off.any(axis=1)
    return E[front].astype(np.int64), off[front]


def crack_front(V: np.ndarray, F: np.ndarray, BV: np.ndarray, BF: np.ndarray) -> np.ndarray:
    """Boundary edges of the surface ``(V, F)`` that end inside the object, ``(k, 2)``.

    A boundary edge is on B when both its vertices are (its midpoint may not
    be: on a curved B the coarse boundary edges are chords). Edges are
    returned in the orientation they have in their triangle.
    """
    return _crack_front(V, F, Exterior(BV, BF))[0]


def _crossing(B: Exterior, inside_pts: np.ndarray, outside_pts: np.ndarray, tolerance: float) -> np.ndarray:
    """Points where segments from inside to outside B cross B (bisection to ``tolerance``, then projection)."""
    a, b = inside_pts.copy(), outside_pts.copy()
    while np.linalg.norm(b - a, axis=1).max() > tolerance:
        m = 0.5 * (a + b)
        ins = B.inside(m)
        a[ins], b[~ins] = m[ins], m[~ins]
    return B.closest(0.5 * (a + b))[2]


def extend_cuts(V: np.ndarray, F: np.ndarray, BV: np.ndarray, BF: np.ndarray, step: float | None = None,
                max_steps: int = 500, virtual: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Extend every crack front of the fracture surface to the exterior B.

    Parameters
    ----------
    V, F : (n, 3) float, (m, 3) int
        Fracture surface; its boundary may partly lie inside the object.
    BV, BF : closed exterior surface B.
    step : float, optional
        Length of one strip (default: the mean length of the front edges).
    max_steps : int
    virtual : (m,) bool, optional
        Which of the given triangles are virtual already (default: none).

    Returns
    -------
    V2 : (n2, 3) float
        The old vertices followed by the new ones.
    F2 : (m2, 3) int
        The old triangles followed by the virtual ones.
    virtual : (m2,) bool
        True for the added triangles (and those given as virtual).

    Raises
    ------
    InputError
        When a front does not reach B within ``max_steps`` strips.
    """
    B = Exterior(BV, BF)  # many winding-number and distance queries: build the trees once
    reach = tol.on_surface * float(np.linalg.norm(np.ptp(B.V, axis=0)))
    given = np.zeros(len(F), bool) if virtual is None else np.asarray(virtual, bool)
    front, off = _crack_front(V, F, B)
    if len(front) == 0:
        return V, F, given.copy()
    Vall = np.asarray(V, np.float64)
    try:
        verts, direction = boundary_conormals(Vall, F, front)
    except ValueError:
        raise InputError("virtual fracture: a crack-front triangle is degenerate (zero area)") from None
    h = float(np.linalg.norm(Vall[front[:, 1]] - Vall[front[:, 0]], axis=1).mean()) if step is None else step

    tip = verts.copy()  # current vertex id at the end of each front vertex's track
    # front vertices already on B (the ends of a front) stay where they are
    active = np.zeros(len(verts), bool)
    active[np.searchsorted(verts, front[off])] = True
    edges = np.searchsorted(verts, front)  # front edges as indices into verts
    new_faces = []
    for _ in range(max_steps):
        if not active.any():
            break
        cur = Vall[tip[active]]
        nxt = cur + h * direction[active]
        ins = B.inside(nxt)
        if (~ins).any():
            nxt[~ins] = _crossing(B, cur[~ins], nxt[~ins], reach)
        new_ids = np.arange(len(Vall), len(Vall) + len(nxt))
        Vall = np.concatenate([Vall, nxt])
        new_tip = tip.copy()
        new_tip[active] = new_ids
        # strips: per front edge (a, b) the quad a0 b0 b1 a1 when both ends
        # moved, the triangle toward the end that moved otherwise
        a0, b0, a1, b1 = tip[edges[:, 0]], tip[edges[:, 1]], new_tip[edges[:, 0]], new_tip[edges[:, 1]]
        ma, mb = a1 != a0, b1 != b0
        new_faces += [np.stack([b0, a0, a1], 1)[ma],
                      np.stack([b0, a1, b1], 1)[ma & mb],
                      np.stack([b0, a0, b1], 1)[~ma & mb]]
        idx = np.flatnonzero(active)
        active[idx[~ins]] = False
        # the front edge now runs between the new tips, in the same orientation
        tip = new_tip
    else:
        raise InputError(f"virtual fracture: a crack front did not reach the exterior within {max_steps} steps "
                         f"of {h:.3g}; is the cut inside a closed exterior?")
    F2 = np.concatenate([F] + [f.astype(np.int64) for f in new_faces])
    flags = np.ones(len(F2), bool)
    flags[:len(F)] = given
    return follow_b(Vall, F2, flags, B)


# A boundary edge of the extended cut whose midpoint is farther than this
# (relative to B's diagonal) from B is split, the new vertex put on B.
CHORD = 2e-3


def follow_b(V: np.ndarray, F: np.ndarray, virtual: np.ndarray, B: Exterior, max_rounds: int = 10):
    """Split the cut's boundary edges until they follow B within :data:`CHORD` of its diagonal.

    The extended fronts end on B vertex by vertex, and the straight edge
    between two ends on different faces of B cuts a corner off B's convex
    edges (the edge runs inside) or leaves it (concave ones): the cut then
    leaves a channel round that corner that joins its two sides. Each split
    puts a new vertex where the sheet meets B in the triangle's plane: on the
    ray from the triangle's third corner (inside the object) through the edge's
    midpoint, where it first meets B (:meth:`Exterior.along`; an edge across a
    re-entrant part of B, such as a step of a staircase, has its midpoint deep
    inside, and B's closest point to it lies on another face, which splits the
    edge into two chords as deep). One edge per triangle a round; the triangle
    on it is halved and the halves keep its flag.
    """
    limit = CHORD * float(np.linalg.norm(np.ptp(B.V, axis=0)))
    for _ in range(max_rounds):
        E = boundary_edges(F)
        d2, _, _ = B.closest(0.5 * (V[E[:, 0]] + V[E[:, 1]]))
        far = np.flatnonzero(d2 > limit ** 2)
        if not len(far):
            break
        face = directed_edge_face(F, E[far])
        far, first = far[np.unique(face, return_index=True)[1]], np.unique(face)
        a, b = E[far, 0], E[far, 1]
        m = len(V) + np.arange(len(far))
        tri = F[first]
        c = tri.sum(axis=1) - a - b  # the corner off the edge
        V = np.concatenate([V, B.along(V[c], 0.5 * (V[a] + V[b]))])
        F = F.copy()
        F[first] = np.stack([a, m, c], 1)
        F = np.concatenate([F, np.stack([m, b, c], 1)])
        virtual = np.concatenate([virtual, virtual[first]])
    return V, F, virtual

