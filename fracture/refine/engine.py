"""The refinement loop: gradient flow, adaptive splits, boundary and collision constraints (Sections 4.3, 4.4).

One iteration:

1. psi and the level-averaged grad psi at every vertex (one interpolation),
   the velocity of Eq. 3 (:mod:`fracture.refine.flow`) and the step size:
   ``dt`` moves a vertex of median speed ``step`` grid cells (speeds below a
   floor count as rest); boundary vertices move tangentially to B and do not
   pull the sheet's boundary inward;
2. one random sample per triangle (on its boundary or junction edge when it
   has one) is moved by Eq. 3 with the triangle as its neighbourhood; where it
   leaves the triangle by more than ``split_distance`` of the step, it becomes
   a vertex (1-to-3 split, or an edge split through every triangle on the
   edge). Samples closer than ``min_edge`` grid cells to a corner are skipped,
   and so are boundary-edge samples whose projection onto B would turn one of
   the new triangles over (:func:`split_folds`);
3. the moves: no vertex moves more than ``max_move`` of its shortest edge nor
   more than a grid cell (no vertex can overtake its neighbours), and each
   vertex scales its move by its own gain: a vertex whose velocity turns back
   from the last iteration's (it stepped over the bottom of its valley of psi,
   or the area term of its small triangles overshot) halves its gain, the
   others regrow theirs by 20 % up to 1. On the finest triangles the area
   term is too stiff for any one step size (stable steps scale with the
   squared edge length); the gains damp the vertices that oscillate and leave
   the others at full speed;
4. boundary vertices are projected onto the exterior B (libigl's AABB tree);
5. continuous collision detection from the old to the new positions stops the
   vertices of every colliding pair (:mod:`fracture.refine.collide`), so the
   surface never passes through itself;
6. edge flips remove slim triangles (:mod:`fracture.refine.flips`).

The loop ends when the mean move falls below ``tolerance``, or once the
triangle budget is spent and an iteration raises the energy (see
:meth:`Refiner.run`), but not while a boundary vertex is off B, unless
collisions keep it off for ``hold`` iterations more.

The per-element work is compiled (:mod:`fracture.refine.kernels`); what is
left in NumPy is O(m) array arithmetic and small sorts of the split candidates.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from fracture.allocator import keep_freed_memory
from fracture.exterior import Exterior
from fracture.refine.collide import stop_collisions
from fracture.refine.fans import closed_vertices
from fracture.refine.flips import flip_edges
from fracture.refine.flow import energy, sample_displacement, velocity
from fracture.refine.kernels import (EdgeTable, edge_table, first_per_group, limit_moves, row_edges, spatial_order,
                                     split_wanted)
from fracture.refine.mesh import RefineMesh
from fracture.tolerances import tol
from fracture.topology import boundary_conormals


@dataclass
class RefineParams:
    """Thresholds of the loop; lengths are in grid cells of the finest pyramid level."""

    iterations: int = 40
    tolerance: float = 0.01  # stop when the mean vertex move is below this (see Refiner.run)
    step: float = 0.25  # a vertex of median speed moves this far per iteration (grid cells)
    max_move: float = 0.3  # ... and no vertex more than this fraction of its shortest edge
    split_distance: float = 0.02  # split when a sample leaves its triangle by this fraction of the step
    tension: float = 0.05  # psi is shifted so its minimum is this fraction of its range
    min_edge: float = 0.1  # samples closer than this to a corner are skipped
    max_triangles: int = 200_000
    thickness: float = 1e-6  # closer than this counts as a collision
    hold: int = 3  # iterations a vertex stopped by a collision stays stopped


@dataclass
class IterationLog:
    energy: list = field(default_factory=list)
    mean_move: list = field(default_factory=list)
    triangles: list = field(default_factory=list)
    boundary_error: list = field(default_factory=list)
    stopped: list = field(default_factory=list)  # vertices stopped by collisions
    seconds: dict = field(default_factory=dict)  # time per phase, summed over iterations
    stop: str = ""  # why the iterations ended

    def tick(self, phase: str, since: float) -> float:
        now = time.perf_counter()
        self.seconds[phase] = self.seconds.get(phase, 0.0) + now - since
        return now


def split_folds(T: np.ndarray, k: np.ndarray, Q: np.ndarray, N: np.ndarray) -> np.ndarray:
    """Whether splitting edge ``k`` of triangles ``T (s, 3, 3)`` (unit normals ``N``) at a vertex that
    then moves to ``Q`` turns one of the two new triangles over (its normal against its parent's)."""
    ar = np.arange(len(T))
    a, b, d = T[ar, k], T[ar, (k + 1) % 3], T[ar, (k + 2) % 3]
    n1, n2 = np.cross(Q - a, d - a), np.cross(b - Q, d - Q)
    return (np.einsum("ij,ij->i", n1, N) <= 0.0) | (np.einsum("ij,ij->i", n2, N) <= 0.0)


class Refiner:
    """Evolves and refines a fracture surface toward low psi."""

    def __init__(self, mesh: RefineMesh, pyramid, BV: np.ndarray, BF: np.ndarray, params: RefineParams,
                 rng: np.random.Generator):
        self.mesh, self.pyramid, self.params, self.rng = mesh, pyramid, params, rng
        keep_freed_memory()  # every iteration frees and allocates the same large arrays again
        self.h = float(np.min(pyramid.grid.spacing))
        self.on_b = tol.on_b * self.h  # a boundary vertex this close to B is on it
        self.log = IterationLog()
        # A negative psi would reward area: the flow would wrinkle without
        # bound and explicit steps would be anti-diffusive. Shifting psi adds
        # a constant surface tension and leaves grad psi unchanged.
        values = pyramid.levels[0]
        self.offset = params.tension * float(np.ptp(values)) - float(values.min())
        self.B = Exterior(BV, BF)  # its AABB tree, built on the first query, serves every iteration
        # speeds below this (psi changing by 1 % of its range per grid cell)
        # count as at rest: dt stops growing, the moves shrink, the loop ends
        self.slow = 0.01 * float(np.ptp(values)) / self.h
        self.dt = 0.0
        self.velocity = np.zeros_like(mesh.V)  # of the last step, per vertex (for snapshots)
        self.gain = np.ones(len(mesh.V))  # per-vertex step factor (halved when a vertex turns back)
        self.hold = np.zeros(len(mesh.V), np.int64)  # iterations a stopped vertex stays stopped
        # psi (unshifted) and grad psi at the vertices, for the positions in _field_V: a vertex is
        # evaluated again only when it moved or is new (see vertex_field)
        self._field_V = np.zeros((0, 3))
        self._psi, self._grad = np.zeros(0), np.zeros((0, 3))
        # the last answers of closest_on_b: vertex ids, their positions then, and B's answers
        self._near = (np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), np.zeros((0, 3)))
        self.boundary = np.zeros(0, np.int64)  # boundary vertices of the last iteration
        self.off_b = np.zeros(0, np.int64)  # boundary vertices off B at the last velocity
        self.full = False  # the triangle budget has stopped a wanted split
        self._ordered = 0  # vertex count when the mesh was last put in spatial order

    def field(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        psi, grad = self.pyramid.value_and_gradient(P)
        return psi + self.offset, grad

    def vertex_field(self) -> tuple[np.ndarray, np.ndarray]:
        """psi (unshifted) and grad psi at the mesh's vertices, evaluated only where a vertex moved or is new."""
        V, old = self.mesh.V, self._field_V
        k = min(len(old), len(V))
        todo = np.r_[np.flatnonzero((V[:k] != old[:k]).any(axis=1)), np.arange(k, len(V))]
        if len(V) != len(old):
            self._psi, self._grad = np.resize(self._psi, len(V)), np.resize(self._grad, (len(V), 3))
        if len(todo):
            self._psi[todo], self._grad[todo] = self.pyramid.value_and_gradient(V[todo])
        self._field_V = V.copy()
        return self._psi, self._grad

    @property
    def psi(self) -> np.ndarray:
        """Unshifted psi at the current vertices."""
        return self.vertex_field()[0]

    # -- memory order -----------------------------------------------------------------------
    def _renumber(self, vorder: np.ndarray, forder: np.ndarray | None = None) -> None:
        """Renumber the mesh (:meth:`RefineMesh.reorder`) and the per-vertex state with it."""
        new = self.mesh.reorder(vorder, forder)

        def follow(a, fresh):  # per-vertex state that does not cover every vertex starts afresh
            return a[vorder] if len(a) == len(vorder) else fresh

        empty = np.zeros((0, 3))  # psi cached for no vertex: vertex_field evaluates them all
        self._field_V, self._psi, self._grad = (follow(self._field_V, empty), follow(self._psi, np.zeros(0)),
                                                follow(self._grad, empty))
        self.hold = follow(self.hold, np.zeros(len(vorder), np.int64))
        self._near = (new[self._near[0]],) + self._near[1:]
        self.gain = follow(self.gain, np.ones(len(vorder)))
        self.velocity = follow(self.velocity, self.velocity)
        self.boundary, self.off_b = new[self.boundary], new[self.off_b]

    def put_in_spatial_order(self) -> None:
        """Number vertices along a Morton curve and triangles by their first vertex
        (:func:`~fracture.refine.kernels.spatial_order`): the iterations' loops then read
        neighbours from nearby memory. Done when the mesh grew by a fifth since the last time."""
        if len(self.mesh.V) > 1.2 * self._ordered:
            self._renumber(*spatial_order(self.mesh.V, self.mesh.F))
            self._ordered = len(self.mesh.V)

    # -- topology ---------------------------------------------------------------------------
    def edges(self) -> EdgeTable:
        """The edge table of the current triangles (O(m), compiled)."""
        return edge_table(self.mesh.F, len(self.mesh.V))

    def boundary_vertices(self) -> np.ndarray:
        return np.unique(row_edges(self.mesh.F, self.edges().boundary_rows))

    # -- constraints -----------------------------------------------------------------------
    def closest_on_b(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`Exterior.closest` of vertices ``ids`` (distinct) where they are: squared distances,
        triangles of B and closest points.

        B is asked only about the vertices that were not in the last call or
        have moved since: the boundary's distances measured at the end of an
        iteration serve the next one's velocity, and the velocity after the
        splits asks only about the new boundary vertices. The answers are
        kept for the next call: read them, do not edit them.
        """
        V = self.mesh.V
        last, X, d2, tri, P = self._near
        slot = np.full(len(V), -1)
        slot[last] = np.arange(len(last))
        slot = slot[ids]
        known = np.flatnonzero(slot >= 0)
        known = known[(V[ids[known]] == X[slot[known]]).all(axis=1)]
        answer = (np.empty(len(ids)), np.empty(len(ids), np.int64), np.empty((len(ids), 3)))
        for a, b in zip(answer, (d2, tri, P)):
            a[known] = b[slot[known]]
        ask = np.ones(len(ids), bool)
        ask[known] = False
        if ask.any():
            for a, b in zip(answer, self.B.closest(V[ids[ask]])):
                a[ask] = b
        self._near = (ids.copy(), V[ids]) + answer
        return answer

    def project_to_exterior(self, ids: np.ndarray, V: np.ndarray) -> None:
        """Put vertices ``ids`` of positions ``V`` on B (in place)."""
        if len(ids):
            V[ids] = self.B.closest(V[ids])[2]

    def settle_boundary(self) -> float:
        """Move the boundary vertices that are off B onto it, the rest of the surface at rest, unless a
        collision stops them; returns the largest distance of a boundary vertex from B after that.

        A new vertex on a boundary edge starts on the edge's chord, off B, and a
        collision may stop its first projection (and the hold keep it there).
        Once the flow has settled, this step, which tests only the elements on
        the few vertices it moves, replaces the whole iterations that would
        otherwise wait for them.
        """
        m, ids = self.mesh, self.boundary
        if not len(ids):
            return 0.0
        d2, _, P = self.closest_on_b(ids)
        off = d2 > self.on_b ** 2
        if not off.any():
            return float(np.sqrt(d2.max()))
        X1 = m.V.copy()
        X1[ids[off]] = P[off]
        stopped, _ = stop_collisions(m.V, X1, m.F, self.params.thickness * self.h, self.edges(),
                                     moving=ids[off])
        self.hold[stopped] = self.params.hold
        m.V = X1
        return self.boundary_error(ids)

    def boundary_error(self, ids: np.ndarray | None = None) -> float:
        """Largest distance of the boundary vertices (or of ``ids``) from B."""
        ids = self.boundary_vertices() if ids is None else ids
        return float(np.sqrt(self.closest_on_b(ids)[0].max())) if len(ids) else 0.0

    def _velocity(self, table: EdgeTable) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Eq. 3 at every vertex with the boundary constraint.

        Returns the velocity, the shifted psi at the vertices and the boundary vertices; records
        those off B in ``off_b`` (from the same closest-point query).
        """
        m = self.mesh
        psi, grad = self.vertex_field()
        psi = psi + self.offset
        v = velocity(m.V, m.F, psi, grad)
        # boundary vertices slide on B: drop the part of their velocity that
        # points out of the sheet across its boundary (the area term of an
        # open sheet pulls its boundary inward; at a crease of B this pull is
        # not normal to B) and the part normal to B (projection undoes it)
        rows = table.boundary_rows
        if not len(rows):
            self.off_b = np.zeros(0, np.int64)
            return v, psi, np.zeros(0, np.int64)
        verts, c = boundary_conormals(m.V, m.F, row_edges(m.F, rows), strict=False, face=rows // 3, by_length=True)
        v[verts] -= np.einsum("ij,ij->i", v[verts], c)[:, None] * c
        d2, tri, _ = self.closest_on_b(verts)
        self.off_b = verts[d2 > self.on_b ** 2]
        nb = self.B.normals[tri]
        v[verts] -= np.einsum("ij,ij->i", v[verts], nb)[:, None] * nb
        return v, psi, verts

    # -- one iteration --------------------------------------------------------------------
    def _step_size(self, v: np.ndarray, used: np.ndarray) -> float:
        speed = np.linalg.norm(v[used], axis=1)
        typical = max(float(np.median(speed)) if len(speed) else 0.0, self.slow)
        return self.params.step * self.h / typical

    def remesh(self, table: EdgeTable, v: np.ndarray, psi: np.ndarray, dt: float) -> int:
        """One round of sampled splits; returns the number of new vertices.

        ``v`` and ``psi`` (shifted) are the velocity and psi at the vertices.
        """
        m, p = self.mesh, self.params
        if len(m.F) >= p.max_triangles:
            self.full = True
            return 0
        row_count = table.row_count
        special = (row_count != 2).reshape(-1, 3)  # boundary or junction edges of every triangle
        has_edge = special.any(axis=1)
        k_edge = np.argmax(special, axis=1)
        T = m.V[m.F]
        # samples: random inside, away from the edges (every barycentric
        # coordinate at least 0.1: a sample near an edge would make a sliver),
        # or on the triangle's first special edge
        bary = 0.1 + 0.7 * self.rng.dirichlet([1.0, 1.0, 1.0], size=len(m.F))
        t = self.rng.uniform(0.2, 0.8, size=len(m.F))
        rows = np.flatnonzero(has_edge)
        bary[rows] = 0.0
        bary[rows, k_edge[rows]] = 1.0 - t[rows]
        bary[rows, (k_edge[rows] + 1) % 3] = t[rows]
        P = np.einsum("fk,fkc->fc", bary, T)
        psi_P, grad_P = self.field(P)
        # how far the sample leaves its triangle (its own move minus the move the
        # corners give it); samples too close to a corner are skipped, and needles
        # are not split inside (their children would be needles too): the flips
        # improve them first
        d = sample_displacement(P, T, psi_P, grad_P, psi[m.F], dt)
        want, N = split_wanted(T, P, bary, d, v, m.F, dt, k_edge, has_edge, (p.min_edge * self.h) ** 2,
                               p.split_distance * p.step * self.h, 0.2)
        self._keep_unfolded(want, table, P, T, N, k_edge)
        # no splits beside a boundary vertex still off B (a collision stopped its
        # projection): smaller triangles around it would make the move onto B
        # fold them over, and it would never get there
        beside = None
        if len(self.off_b):
            off = np.zeros(len(m.V), bool)
            off[self.off_b] = True
            beside = off[m.F].any(axis=1)
            want &= ~beside
        budget = max(0, (p.max_triangles - len(m.F)) // 2)
        # edge splits: one per edge (a random one of its triangles' samples) ...
        ef = np.flatnonzero(want & has_edge)
        eid = table.eid[3 * ef + k_edge[ef]]
        keep = first_per_group(eid, self.rng.random(len(ef)))
        ef, eid = ef[keep], eid[keep]
        # ... and a triangle takes part in one split at most: of two chosen
        # edges on a triangle, the later one is dropped everywhere
        good = table.independent(eid)
        self.full |= int(good.sum()) > budget
        good &= np.cumsum(good) <= budget
        ef, eid = ef[good], eid[good]
        on, which = table.rows_of(eid)
        if beside is not None and len(eid):  # ... nor a junction edge with a triangle beside an off-B vertex
            clear = np.bincount(which, weights=beside[on // 3], minlength=len(eid)) == 0
            rows = clear[which]
            ef, eid, on, which = ef[clear], eid[clear], on[rows], (np.cumsum(clear) - 1)[which[rows]]
        busy = np.zeros(len(m.F), bool)
        busy[on // 3] = True
        E = np.stack([m.F[ef, k_edge[ef]], m.F[ef, (k_edge[ef] + 1) % 3]], 1)
        new_edge = m.split_edges(E, t[ef], rows=on, which=which) if len(ef) else np.zeros(0, np.int64)
        # 1-to-3 splits of the others
        tf = np.flatnonzero(want & ~has_edge & ~busy)
        self.full |= len(tf) > budget - len(ef)
        tf = tf[: max(0, budget - len(ef))]
        if len(tf):
            m.split_triangles(tf, bary[tf])
        return len(new_edge) + len(tf)

    def _keep_unfolded(self, want, table, P, T, N, k_edge) -> None:
        """Drop (in ``want``) the boundary-edge splits whose new vertex, once projected onto B, would
        turn one of its two triangles over.

        A sample on a boundary edge lies on the edge's chord, off B where B is
        curved; the next projection moves it by the sagitta. On a thin triangle
        that move can fold the new triangle over its neighbour: the collision
        test then stops the vertex off B for good.
        """
        rows = np.flatnonzero(want & (table.row_count.reshape(-1, 3)[np.arange(len(want)), k_edge] == 1))
        if not len(rows):
            return
        want[rows[split_folds(T[rows], k_edge[rows], self.B.closest(P[rows])[2], N[rows])]] = False

    def iterate(self) -> float:
        """One iteration (module notes); returns the mean move in grid cells."""
        m, p, log = self.mesh, self.params, self.log
        clock = time.perf_counter()
        self.put_in_spatial_order()
        clock = log.tick("order", clock)
        table = self.edges()
        v, psi, boundary = self._velocity(table)
        used = np.bincount(m.F.ravel(), minlength=len(m.V)) > 0
        self.dt = dt = self._step_size(v, used)
        clock = log.tick("flow", clock)
        if self.remesh(table, v, psi, dt):
            clock = log.tick("remesh", clock)
            table = self.edges()
            v, psi, boundary = self._velocity(table)
            used = np.r_[used, np.ones(len(m.V) - len(used), bool)]  # new vertices are on triangles
            clock = log.tick("flow", clock)
        # per-vertex gains (module notes, 3): halved where the velocity turned back
        prev = self.velocity
        gain = np.r_[self.gain, np.ones(len(m.V) - len(self.gain))]
        back = np.einsum("ij,ij->i", prev, v[: len(prev)]) < 0.0
        gain[: len(prev)] = np.where(back, 0.5 * gain[: len(prev)], np.minimum(1.0, 1.2 * gain[: len(prev)]))
        self.gain = gain
        self.velocity = v
        d = dt * v
        # vertices stopped by a collision stay stopped for a few iterations:
        # the flow that pushed them into contact still pushes, and a pair at
        # rest costs the collision test nothing
        self.hold = np.concatenate([self.hold, np.zeros(len(m.V) - len(self.hold), np.int64)])
        d[self.hold > 0] = 0.0
        self.hold = np.maximum(self.hold - 1, 0)
        limit_moves(m.V, m.F, d, p.max_move, self.h)
        d *= gain[:, None]
        X1 = m.V + d
        self.boundary = boundary  # flips keep the boundary: valid until the next splits
        self.project_to_exterior(boundary, X1)
        clock = log.tick("boundary", clock)
        closed = closed_vertices(m.F, len(m.V), table)  # for the collision step and the flips
        stopped, _, grid = stop_collisions(m.V, X1, m.F, p.thickness * self.h, table, return_grid=True,
                                         closed=closed)
        self.hold[stopped] = p.hold
        clock = log.tick("collisions", clock)
        moved = np.linalg.norm(X1 - m.V, axis=1)
        m.V = X1
        flip_edges(m.V, m.F, m.sides, max_passes=3, safe=True, grid=grid, table=table, closed=closed)
        clock = log.tick("flips", clock)
        log.stopped.append(int(stopped.sum()))
        return float(moved[used].mean() / self.h) if used.any() else 0.0

    def run(self, callback=None) -> IterationLog:
        """Iterate until the surface settles or ``iterations`` are done.

        The surface has settled when the mean move is below ``tolerance``, or
        when the triangle budget is spent and an iteration raised the energy:
        the flow then oscillates about the minimum it can reach with these
        triangles (steps on the finest triangles overshoot), and further
        iterations with smaller steps only wander about it. Neither ends the
        loop while a boundary vertex is off B (a new vertex on a boundary edge
        whose first projection a collision stopped): such vertices are moved
        onto B alone first (:meth:`settle_boundary`). Should collisions still
        block them ``hold`` iterations later (a vertex stopped by a collision
        waits that long for the surface around it to move), the loop ends
        all the same and ``log.stop`` says how many stay off B: iterating on
        would only wait for them, at full cost per iteration.
        ``callback(it, refiner)`` is called after every iteration (the mesh
        may be numbered in spatial order then); the reason for stopping is
        ``log.stop``. The mesh ends numbered in creation order.
        """
        p, log = self.params, self.log
        log.stop = "iterations"
        waited = 0  # iterations that would have stopped but for boundary vertices off B
        for it in range(p.iterations):
            move = self.iterate()
            clock = time.perf_counter()
            E = energy(self.mesh.V, self.mesh.F, self.psi)
            rose = bool(log.energy) and E > log.energy[-1]
            stop = ("moves below tolerance" if move < p.tolerance else
                    "triangle budget spent and the energy rose" if self.full and rose else "")
            off_b = self.boundary_error(self.boundary)
            if stop and off_b > self.on_b:
                off_b = self.settle_boundary()
                E = energy(self.mesh.V, self.mesh.F, self.psi)
            log.energy.append(E)
            log.mean_move.append(move)
            log.triangles.append(len(self.mesh.F))
            log.boundary_error.append(off_b)
            log.tick("bookkeeping", clock)
            if callback is not None:
                callback(it, self)
            if stop and off_b <= self.on_b:  # else a boundary vertex is still off B: iterate on
                log.stop = stop
                break
            waited = waited + 1 if stop else 0
            if waited > p.hold:
                off = int((self.closest_on_b(self.boundary)[0] > self.on_b ** 2).sum())
                which = "1 boundary vertex stays" if off == 1 else f"{off} boundary vertices stay"
                log.stop = f"{stop}; {which} off B (up to {off_b / self.h:.3g} grid cells): collisions block the way"
                break
        self._renumber(self.mesh.creation_order())  # the tree's order, coarse vertices first
        return self.log
