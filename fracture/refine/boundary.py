"""The boundary constraint on B (Sec. 4.4): the fracture surface's boundary stays on the exterior B.

The refined surface meets B along its boundary curves, which must stay on B
for the pieces to be cut out of B along them (Section 5). This module owns B
(its trees, built once) and the answers B gave about the vertices (kept in the
refiner's per-vertex state, asked again only where a vertex moved), and does
what the refiner asks of the boundary:

- :meth:`BoundaryOnB.closest`: where B is, for the vertices that moved;
- :meth:`~BoundaryOnB.project`: the step's boundary vertices put back on B;
- :meth:`~BoundaryOnB.stop_crossings`: a step's boundary vertices that would
  make two boundary curves cross on B (or come closer than
  ``_CURVE_GAP`` cells) stay where they were;
- :meth:`~BoundaryOnB.leaving`: inner vertices that a step would take out of
  the object, or too close to B, which the refiner stops like a collision;
- :meth:`~BoundaryOnB.settle`: boundary vertices off B (new ones on boundary
  edges start on the chord) moved onto B, the rest at rest, unless a collision
  or another curve stops them;
- :meth:`~BoundaryOnB.fit_chords`: boundary edges whose chords pass far from B
  split, the new vertices put on B.

:attr:`BoundaryOnB.boundary` holds the boundary vertices of the last
iteration and :attr:`~BoundaryOnB.off_b` those off B at the last velocity.
"""

from __future__ import annotations

import numba
import numpy as np

from fracture.mesh import vec
from fracture.mesh.edges import EdgeTable, edge_table, row_edges
from fracture.mesh.exterior import Exterior
from fracture.refine.crossings_on_b import candidate_pairs, close_pairs
from fracture.refine.remesh import plan_chord_splits
from fracture.tolerances import tol

# Boundary curves keep this far apart on B (grid cells): imprinting them moves their vertices a little.
_CURVE_GAP = 0.05
# Rounds of chord splits per call of fit_chords.
_CHORD_ROUNDS = 3


class BoundaryOnB:
    """The boundary constraint on B of the refiner's surface (module notes).

    Parameters
    ----------
    mesh : FractureSurface
        The surface being refined (the refiner's; edited in place).
    state : VertexState
        The refiner's per-vertex state: the answers of B (``near_*``) and the collision holds.
    B : Exterior
    h : float
        The finest grid cell.
    params : RefineParams
    collisions : callable
        The collision step (:func:`~fracture.refine.collide.stop_collisions`).
    """

    def __init__(self, mesh, state, B: Exterior, h: float, params, collisions):
        self.mesh, self.state, self.B, self.h, self.params = mesh, state, B, h, params
        self.collisions = collisions
        self.on_b = tol.on_b * h  # a boundary vertex this close to B is on it
        self.boundary = np.zeros(0, np.int64)  # boundary vertices of the last iteration
        self.off_b = np.zeros(0, np.int64)  # boundary vertices off B at the last velocity

    def renumber(self, new: np.ndarray) -> None:
        """Follow a renumbering of the vertices (``new[old]``)."""
        self.boundary, self.off_b = new[self.boundary], new[self.off_b]

    def vertices(self) -> np.ndarray:
        return np.unique(row_edges(self.mesh.F, edge_table(self.mesh.F, len(self.mesh.V)).boundary_rows))

    def closest(self, ids: np.ndarray, V: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`Exterior.closest` of vertices ``ids`` where they are (or at positions ``V``): squared
        distances, triangles of B and closest points. B is asked only about vertices that are new or
        moved since they were last asked about (the answers are kept in the vertex state)."""
        V, s = (self.mesh.V if V is None else V), self.state
        s.grow(len(V))
        ask = ids[(V[ids] != s.near_at[ids]).any(axis=1)]
        if len(ask):
            s.near_d2[ask], s.near_tri[ask], s.near_point[ask] = self.B.closest(V[ask])
            s.near_at[ask] = V[ask]
        return s.near_d2[ids], s.near_tri[ids], s.near_point[ids]

    def stop_crossings(self, X1: np.ndarray, table: EdgeTable, rounds: int = 4) -> int:
        """Keep in place (in ``X1``) the boundary vertices of edges that the step to ``X1`` would make cross
        (or come closer than ``_CURVE_GAP`` to) another boundary edge on B (:mod:`fracture.refine.crossings_on_b`); returns how many were kept.

        Pairs that cross already where the surface is stay as they are (they are not made worse by
        this step's own crossings only)."""
        E = row_edges(self.mesh.F, table.boundary_rows)
        if not len(E):
            return 0
        gap = _CURVE_GAP * self.h
        # every round's positions lie between the surface's and X1: one candidate search serves them all
        move = np.linalg.norm(X1[E] - self.mesh.V[E], axis=2).max(axis=1)  # per edge, its ends' largest
        candidates = candidate_pairs(self.mesh.V, E, gap, move)
        pairs, crossing = close_pairs(self.mesh.V, E, self.B.normal_at, gap, candidates)
        close = {tuple(x) for x in pairs.tolist()}
        cross = {tuple(x) for x in pairs[crossing].tolist()}
        kept = 0
        for _ in range(rounds):
            # new pairs closer than the gap, and new crossings (of pairs already close, too)
            now, crossing = close_pairs(X1, E, self.B.normal_at, gap, candidates)
            pairs = [x for x, c in zip(now.tolist(), crossing.tolist())
                     if tuple(x) not in close or (c and tuple(x) not in cross)]
            if not pairs:
                break
            ids = np.unique(E[np.asarray(pairs).ravel()])
            ids = ids[(X1[ids] != self.mesh.V[ids]).any(axis=1)]
            if not len(ids):
                break
            X1[ids] = self.mesh.V[ids]
            kept += len(ids)
        return kept

    def leaving(self, X1: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """Of the inner vertices ``ids``, moved to ``X1``, those that would leave the object: outside B
        there, or closer to it than the collision thickness.

        The paper stops colliding vertices (Sec. 4.4); B is one more obstacle:
        a piece is the region of B on one side of the sheets, and an inner
        vertex outside B makes the piece cross itself. B is asked only about
        vertices that may be: a point closer to an inside point ``r`` than
        ``r``'s distance to B is inside, and farther from B than that distance
        less how far apart they are. So a vertex whose last known distance
        (at an inside position, kept by :meth:`closest`), less its move
        since, exceeds the thickness is inside and clear of B; only the rest
        are asked about. The same holds for a neighbour's last answer: a
        vertex made by a split (never asked) lies within its parents' clear
        balls, and inside the object they are mostly far wider than its
        edges (:func:`clearance`). An answer at a position outside B is
        forgotten: it bounds nothing.
        """
        s = self.state
        thin = self.params.thickness * self.h
        bound = clearance(self.mesh.F, X1, s.near_at, s.near_d2, ids, also=((s.clear_at, s.clear_d2),))
        clear = bound > thin
        # what the answers prove is kept as the vertex's own: a vertex made by a split, two rings from any
        # answer, is proved clear by its neighbours' proofs (on the marble bunny 12,500 points asked of B,
        # at 10 microseconds each, a median 3.4 cells inside)
        proved = ids[clear]
        s.clear_at[proved], s.clear_d2[proved] = X1[proved], bound[clear] ** 2
        near = ids[~clear]
        if not len(near):
            return near
        d2, tri, C = self.closest(near, X1)
        out = near[(d2 < thin * thin) | ~self.B.inside_near(X1[near], tri, C)]
        s.near_at[out] = np.nan
        return out

    def project(self, ids: np.ndarray, V: np.ndarray) -> None:
        """Put vertices ``ids`` of positions ``V`` on B (in place)."""
        if len(ids):
            V[ids] = self.B.closest(V[ids])[2]

    def settle(self, table: EdgeTable | None = None) -> float:
        """Move the boundary vertices that are off B onto it, the rest of the surface at rest, unless a
        collision stops them; returns the largest distance of a boundary vertex from B after that.

        A new vertex on a boundary edge starts on the edge's chord, off B, and a
        collision may stop its first projection, as may another boundary curve that the projection would
        cross on B (near B's creases B's closest point takes points on both sides to the edge); at the
        end of a stage this
        step, which tests only the elements on the few vertices it moves,
        replaces the iterations that would otherwise wait for them. ``table``
        is the current edge table, if the caller has it.
        """
        m, ids = self.mesh, self.boundary
        if not len(ids):
            return 0.0
        d2, _, P = self.closest(ids)
        off = d2 > self.on_b ** 2
        if not off.any():
            return float(np.sqrt(d2.max()))
        X1 = m.V.copy()
        X1[ids[off]] = P[off]
        table = table or edge_table(m.F, len(m.V))
        self.stop_crossings(X1, table)  # no two boundary curves made to cross on B
        stopped, _ = self.collisions(m.V, X1, m.F, self.params.thickness * self.h, table,
                                     moving=ids[off])
        self.state.hold[stopped] = self.params.hold
        m.V = X1
        return self.error(ids)

    def fit_chords(self, table: EdgeTable, rounds: int = _CHORD_ROUNDS) -> tuple[int, EdgeTable]:
        """Split boundary edges whose chords pass farther than ``split_distance`` from B and put the new
        vertices on B (:func:`~fracture.refine.remesh.plan_chord_splits`), for a few rounds; returns the
        number of splits and the current edge table."""
        p, made = self.params, 0
        for _ in range(rounds):
            ids = np.unique(row_edges(self.mesh.F, table.boundary_rows))
            off_b = ids[self.closest(ids)[0] > self.on_b ** 2]
            plan = plan_chord_splits(self.mesh.V, self.mesh.F, table, far=p.split_distance * self.h,
                                     near_b=p.min_edge * self.h, budget=p.max_triangles - len(self.mesh.F),
                                     project=lambda P: self.B.closest(P)[2], off_b=off_b,
                                     normal_at=self.B.normal_at)
            if not plan.count:
                break
            made += plan.apply(self.mesh)
            self.state.grow(len(self.mesh.V))
            table = edge_table(self.mesh.F, len(self.mesh.V))
            self.boundary = np.unique(row_edges(self.mesh.F, table.boundary_rows))
            self.settle(table)
        return made, table

    def error(self, ids: np.ndarray | None = None) -> float:
        """Largest distance of the boundary vertices (or of ``ids``) from B."""
        ids = self.vertices() if ids is None else ids
        return float(np.sqrt(self.closest(ids)[0].max())) if len(ids) else 0.0


def clearance(F: np.ndarray, X: np.ndarray, at: np.ndarray, d2: np.ndarray, ids: np.ndarray, also=()
              ) -> np.ndarray:
    """For vertices ``ids`` at ``X[ids]``: the largest ``sqrt(d2[j]) - |X[i] - at[j]|`` over the vertex
    itself and its neighbours ``j`` in triangles ``F``, where ``d2[j]`` is the squared distance to B of
    the inside point ``at[j]`` (NaN: unknown), or a lower bound of it. Positive, it is a lower bound of
    ``X[i]``'s distance to B, and ``X[i]`` lies inside (the distance is 1-Lipschitz); ``-inf`` where
    nothing is known. ``also``: more pairs ``(at, d2)`` of the same kind, the largest of all taken."""
    mark = np.zeros(len(X), np.bool_)
    mark[ids] = True
    bound = np.full(len(X), -np.inf)
    for at_k, d2_k in ((at, d2), *also):
        _clearance(F, X, at_k, d2_k, mark, bound, numba.get_num_threads())
    return bound[ids]


@numba.njit(cache=True, inline="always")
def _ball(X, at, d2, i, j, bound):
    """Raise ``bound[i]`` to what ``j``'s answer (if any) proves of ``X[i]``."""
    if np.isfinite(d2[j]) and at[j, 0] == at[j, 0]:
        bound[i] = max(bound[i], np.sqrt(d2[j]) - vec.norm(vec.sub(vec.point(X, i), vec.point(at, j))))


@numba.njit(cache=True, parallel=True)
def _clearance(F, X, at, d2, mark, bound, threads):
    # the triangles in a chunk per thread, each chunk's running maxima in a row of its own, then the
    # rows' maximum (a running maximum, which NumPy's maximum.at makes ten times slower on the wall's
    # 200K triangles)
    for i in numba.prange(X.shape[0]):
        if mark[i]:
            _ball(X, at, d2, i, i, bound)
    k = threads
    rows = np.full((k, X.shape[0]), -np.inf)
    m = F.shape[0]
    for c in numba.prange(k):
        row = rows[c]
        for f in range(c * m // k, (c + 1) * m // k):
            for j in range(3):
                i = F[f, j]
                if mark[i]:
                    _ball(X, at, d2, i, F[f, (j + 1) % 3], row)
                    _ball(X, at, d2, i, F[f, (j + 2) % 3], row)
    for i in numba.prange(X.shape[0]):
        if mark[i]:
            for c in range(k):
                bound[i] = max(bound[i], rows[c, i])
