"""The refinement: a coarse-to-fine gradient flow with adaptive splits and constraints (Sections 4.3, 4.4).

The refiner composes the parts, each in its own module:

* the global search before the flow (:mod:`fracture.refine.search`, the
  ``search`` seam): a minimum cut of the functional over a band around the
  coarse surface, which makes the large moves and the turns the flow cannot
  walk; the flow then polishes its surface on the finest level alone;
* the flow of Eq. 3 (:mod:`fracture.refine.flow`);
* the split plan of Sec. 4.4 (:mod:`fracture.refine.remesh`);
* the step control: implicit area term, move limits, step size
  (:mod:`fracture.refine.step`);
* the collision constraints (:mod:`fracture.refine.collide`) and safe edge
  flips (:mod:`fracture.refine.flips`);
* the per-vertex state (:mod:`fracture.refine.state`), grown and renumbered as
  a whole.

Schedule. The paper's field averages the gradients of every pyramid level,
so that a vertex sees a valley of psi from further than the finest level
would show it (Sec. 4.3). A flow on that field from the start still refines
the surface to the grid's scale before it has travelled: the finest levels'
local minima hold it, and small triangles make it slow. So the refinement
runs through stages, coarse to fine in both the field and the mesh. Stage
``s`` follows ``psibar_s``, the mean of ``c = coarse_levels`` consecutive
pyramid levels ``s .. s+c-1``: the first the ``c`` smoothest, each next one a
level finer, down to levels ``1 .. c``; the last stage follows level 0, psi
itself. The coarse windows carry the valleys of psi far (the pyramid's
purpose, Sec. 4.3); the last one keeps the thin weak layers (a brick's
mortar boundary, a vein) at their full depth and their own place: the mean
over every level smears them to a fraction of their depth, and a mean with
the next level still pulls a surface between two layers a cell or two apart
toward the strong mortar between them (on the collapsing wall 44 % of the
network in the weakest 20 % of zeta with the levels 0 and 1 last, 51 % with
level 0 alone), so the surface ends in them rather than beside them.
``coarse_levels`` equal to the pyramid's levels is the paper's field alone
(one stage, the mean of every level). A stage's triangles
need not be finer than its field: samples closer than half the width of its
finest level to a corner (at least ``min_edge``) are not split. A stage ends
when it has settled: an iteration moved the surface by less than
``tolerance`` grid cells on average (or lowered the functional by less than
10^-4 of it) and split at most half a percent of the triangles (the paper's
test, "the surface change in one iteration is sufficiently small"), once the
triangle budget is full when an iteration lowers the functional by less than
1 % (full-size iterations are the dearest and gain the least), or after
``stage_iterations``.

One iteration:

1. psi, psibar_s and grad psibar_s at every vertex (one interpolation, only
   where a vertex moved or is new), Eq. 3's velocity with psibar_s shifted to
   be positive (``tension``: a small surface tension, so that the area term
   never rewards area; the shift is the stage's own, set from the range of
   its psibar: a blurred field's smaller contrast is not drowned by a shift
   that a finer field needed), and the boundary constraint: boundary vertices slide
   on B and do not pull the sheet's boundary inward;
2. the split plan of the samples, applied; boundary vertices off B (new
   ones on boundary edges start on the chord) are moved onto B, and the
   velocity is taken again where anything moved;
3. the step: backward Euler on the area term
   (:func:`~fracture.refine.step.implicit_step`), the boundary constraint again,
   collision holds, the move limits, projection of the boundary onto B,
   inner vertices that would leave B stopped (:meth:`Refiner.leaving_b`),
   continuous collision detection (stopped vertices stay where they were);
   the step is taken only if it does not raise the minimised functional
   ``E_s = integral of (psibar_s + offset)``, with the same quadrature as the
   flow; otherwise ``tau`` is halved and the step tried again (three times,
   then the surface stays where it is);
4. safe edge flips remove slim triangles.

The log holds, from iteration 0 (the coarse surface; with the search,
iteration 1 is its surface, stage -1), the stage, the
minimised functional before and after each step, the plain E(S) = integral
of psi, the area, triangles, mean and largest move, and ``tau``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numba
import numpy as np

from fracture.mesh import vec
from fracture.mesh.exterior import Exterior
from fracture.refine.collide import stop_collisions
from fracture.refine.crossings_on_b import candidate_pairs, close_pairs
from fracture.refine.fans import closed_vertices
from fracture.refine.flips import flip_edges
from fracture.refine.flow import PsiFlow, energy, energy_gradient, face_terms
from fracture.mesh.edges import edge_table, EdgeTable, row_edges
from fracture.refine.order import spatial_order
from fracture.mesh.fracture_surface import FractureSurface
from fracture.refine.params import RefineParams
from fracture.refine.remesh import PsiSplits, plan_chord_splits
from fracture.refine.search import SearchResult, graph_cut_search
from fracture.refine.state import VertexState
from fracture.refine.step import (BOUNDARY_MOVE, ImplicitStep, StepSize, cotangent_weights, limit_by_shortest_edge,
                                  limit_moves)
from fracture.tolerances import tol
from fracture.mesh.topology import boundary_conormals

# Boundary curves keep this far apart on B (grid cells): imprinting them moves their vertices a little.
_CURVE_GAP = 0.05
# Attempts of a step that would raise the functional, each with half the tau of the last.
_ATTEMPTS = 4
# The field's splits leave the last 1/this of the triangle budget to chord splits (the boundary following B).
_CHORD_RESERVE = 50
# Rounds of chord splits per iteration (fit_chords).
_CHORD_ROUNDS = 3
# The stage of the search's entry in the log.
SEARCH_STAGE = -1
# A stage has settled when its moves are small and an iteration splits at most this share of the triangles.
_FEW_SPLITS = 0.005
# ... and its moves are small, or its step lowered the functional by less than this fraction.
_LITTLE_GAIN = 1e-4
# Once the triangle budget is full, a stage has settled when an iteration lowers its functional by less than
# this fraction: at full size an iteration costs the most and gains the least (benchmarks/README.md).
_FULL_GAIN = 1e-2


@dataclass
class IterationLog:
    """Per iteration (entry 0: the coarse surface before any step)."""

    stage: list = field(default_factory=list)  # first pyramid level of the stage's field
    functional: list = field(default_factory=list)  # E_s after the step (what the flow minimises)
    functional_before: list = field(default_factory=list)  # E_s after the splits, before the step
    energy: list = field(default_factory=list)  # plain E(S) = integral of psi (level 0, unshifted)
    area: list = field(default_factory=list)
    triangles: list = field(default_factory=list)
    mean_move: list = field(default_factory=list)  # grid cells
    max_move: list = field(default_factory=list)  # grid cells
    tau: list = field(default_factory=list)
    retries: list = field(default_factory=list)  # halvings of tau before the step was taken
    splits: list = field(default_factory=list)
    boundary_error: list = field(default_factory=list)
    stopped: list = field(default_factory=list)  # vertices stopped by collisions
    seconds: dict = field(default_factory=dict)  # time per phase, summed over iterations
    stop: str = ""  # why the iterations ended
    search: SearchResult | None = None  # what the search found (None: no search)

    def tick(self, phase: str, since: float) -> float:
        now = time.perf_counter()
        self.seconds[phase] = self.seconds.get(phase, 0.0) + now - since
        return now

    @property
    def iterations(self) -> int:
        return max(len(self.functional) - 1, 0)


class Refiner:
    """Evolves and refines a fracture surface toward low psi (module notes).

    ``collisions`` is the collision step (default
    :func:`~fracture.refine.collide.stop_collisions`, same signature): a seam for
    another collision response, or for a test that blocks a vertex.
    ``search(mesh, pyramid, B) -> SearchResult`` is the global search before the
    flow (default: :func:`default_search` of the parameters; None: none).
    ``grain`` (a :class:`fields.grain.Grain`) makes the functional the integral
    of psi g(n): the flow, the splits and the step's acceptance use it (the
    implicit area term takes each triangle's g(n) as a factor of its weight).
    ``flow`` is the flow (default :class:`~fracture.refine.flow.PsiFlow`, Eq. 3; its integrand and
    field term), ``splits`` the split rule (default :class:`~fracture.refine.remesh.PsiSplits`, the
    paper's): seams for another flow (``AreaFlow``: mean curvature flow) or split rule
    (``LongEdgeSplits``).
    """

    def __init__(self, mesh: FractureSurface, pyramid, BV: np.ndarray, BF: np.ndarray, params: RefineParams,
                 rng: np.random.Generator, *, collisions=stop_collisions, search="default", grain=None, flow=None,
                 splits=None):
        self.mesh, self.pyramid, self.params, self.rng = mesh, pyramid, params, rng
        self.grain = grain
        self.flow = PsiFlow() if flow is None else flow
        self.splits = PsiSplits() if splits is None else splits
        self.stop_collisions = collisions
        self.search = default_search(params, grain=grain) if search == "default" else search
        self.searched = False  # the search's surface replaced the coarse one
        self.h = float(np.min(pyramid.grid.spacing))
        self.on_b = tol.on_b * self.h  # a boundary vertex this close to B is on it
        self.log = IterationLog()
        self.B = Exterior(BV, BF)  # its AABB tree, built on the first query, serves every iteration
        self.step = StepSize(params.step, self.h)
        self.solve = ImplicitStep()  # keeps its factorisation for a retried step
        self.state = VertexState.empty(len(mesh.V))
        self.begin_stage(*self.stages()[0])  # sets first, count, near, offset and the step size
        self.boundary = np.zeros(0, np.int64)  # boundary vertices of the last iteration
        self.off_b = np.zeros(0, np.int64)  # boundary vertices off B at the last velocity
        self.full = False  # the triangle budget has stopped a wanted split
        self._ordered = 0  # vertex count when the mesh was last put in spatial order

    # -- schedule -------------------------------------------------------------------------
    def stages(self) -> list[tuple[int, int]]:
        """``(first, count)`` of each stage's field, coarse to fine: the mean of pyramid levels
        ``first .. first+count-1`` (module notes)."""
        if self.searched:  # the search made the large moves: the flow polishes on psi itself
            return [(0, 1)]
        n = self.pyramid.n_levels
        c = min(max(self.params.coarse_levels, 1), n)
        if c == n:  # the paper's field: one stage on every level
            return [(0, n)]
        return [(first, c) for first in range(n - c, 0, -1)] + [(0, 1)]

    def _near_for(self, first: int) -> float:
        """Samples closer than this to a corner are not split in the stage that starts at level ``first``:
        half the width of its finest level, at least ``min_edge``."""
        width = float(self.pyramid.sigmas[first][0] * self.pyramid.grid.spacing[0])  # world units, any axis
        return max(self.params.min_edge * self.h, 0.5 * width)

    def begin_stage(self, first: int, count: int) -> None:
        """Follow the mean of levels ``first .. first+count-1`` from now on."""
        self.first, self.count = first, count
        self.near = self._near_for(first)
        # A negative integrand would reward area: the flow would wrinkle without
        # bound and the implicit matrix would lose its definiteness. Shifting
        # psibar adds a constant surface tension and leaves its gradient
        # unchanged; its minimum over the grid becomes ``tension`` of its range.
        lowest, span = self.pyramid.window_range(first, self.count)
        self.offset = self.params.tension * span - lowest
        self.state.forget_field()
        self.step.begin(self.pyramid.gradient_scale(first, self.count))

    # -- fields ---------------------------------------------------------------------------
    def field(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The stage's shifted psibar and its gradient at points (what the flow follows)."""
        _, psibar, grad = self.pyramid.coarse_field(self.first, P, self.count)
        return self.flow.integrand(psibar, self.offset), self.flow.gradient(grad)

    def vertex_field(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """psi, psibar (both unshifted) and grad psibar at the vertices, evaluated only where a vertex
        moved or is new."""
        V, s = self.mesh.V, self.state
        s.grow(len(V))
        todo = np.flatnonzero((V != s.field_at).any(axis=1))
        if len(todo):
            s.psi[todo], s.psibar[todo], s.grad[todo] = self.pyramid.coarse_field(self.first, V[todo], self.count)
            s.field_at[todo] = V[todo]
        return s.psi, s.psibar, s.grad

    @property
    def psi(self) -> np.ndarray:
        """psi (level 0, unshifted) at the current vertices."""
        return self.vertex_field()[0]

    @property
    def velocity(self) -> np.ndarray:
        """Eq. 3's velocity of the last step, per vertex."""
        self.state.grow(len(self.mesh.V))
        return self.state.velocity

    def functional(self) -> float:
        """E_s of the current surface: what the flow minimises (module notes)."""
        return energy(self.mesh.V, self.mesh.F, self.flow.integrand(self.vertex_field()[1], self.offset), self.grain)

    def plain_energy(self) -> float:
        """E(S) = integral of psi (level 0, unshifted; times g(n) with a grain) over the surface."""
        return energy(self.mesh.V, self.mesh.F, self.vertex_field()[0], self.grain)

    # -- memory order -----------------------------------------------------------------------
    def _renumber(self, vorder: np.ndarray, forder: np.ndarray | None = None) -> None:
        """Renumber the mesh (:meth:`FractureSurface.reorder`) and the per-vertex state with it."""
        new = self.mesh.reorder(vorder, forder)
        self.state.grow(len(vorder))
        self.state.permute(vorder)
        self.boundary, self.off_b = new[self.boundary], new[self.off_b]

    def put_in_spatial_order(self) -> None:
        """Number vertices along a Morton curve and triangles by their first vertex
        (:func:`~fracture.refine.order.spatial_order`): the iterations' loops then read
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
    def closest_on_b(self, ids: np.ndarray, V: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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

    def stop_crossings_on_b(self, X1: np.ndarray, table: EdgeTable, rounds: int = 4) -> int:
        """Keep in place (in ``X1``) the boundary vertices of edges that the step to ``X1`` would make cross
        (or come closer than ``_CURVE_GAP`` to) another boundary edge on B (:mod:`fracture.refine.crossings_on_b`); returns how many were kept.

        Pairs that cross already where the surface is stay as they are (they are not made worse by
        this step's own crossings only)."""
        E = row_edges(self.mesh.F, table.boundary_rows)
        if not len(E):
            return 0
        gap = _CURVE_GAP * self.h
        # every round's positions lie between the surface's and X1: one candidate search serves them all
        ends = E.ravel()  # a vertex on two edges counts twice: the same largest move
        move = float(np.sqrt(((X1[ends] - self.mesh.V[ends]) ** 2).sum(axis=1).max()))
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

    def leaving_b(self, X1: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """Of the inner vertices ``ids``, moved to ``X1``, those that would leave the object: outside B
        there, or closer to it than the collision thickness.

        The paper stops colliding vertices (Sec. 4.4); B is one more obstacle:
        a piece is the region of B on one side of the sheets, and an inner
        vertex outside B makes the piece cross itself. B is asked only about
        vertices that may be: a point closer to an inside point ``r`` than
        ``r``'s distance to B is inside, and farther from B than that distance
        less how far apart they are. So a vertex whose last known distance
        (at an inside position, kept by :meth:`closest_on_b`), less its move
        since, exceeds the thickness is inside and clear of B; only the rest
        are asked about. The same holds for a neighbour's last answer: a
        vertex made by a split (never asked) lies within its parents' clear
        balls, and inside the object they are mostly far wider than its
        edges (:func:`clearance`). An answer at a position outside B is
        forgotten: it bounds nothing.
        """
        s = self.state
        thin = self.params.thickness * self.h
        near = ids[~(clearance(self.mesh.F, X1, s.near_at, s.near_d2, ids) > thin)]
        if not len(near):
            return near
        d2 = self.closest_on_b(near, X1)[0]
        out = near[(d2 < thin * thin) | ~self.B.inside(X1[near])]
        s.near_at[out] = np.nan
        return out

    def project_to_exterior(self, ids: np.ndarray, V: np.ndarray) -> None:
        """Put vertices ``ids`` of positions ``V`` on B (in place)."""
        if len(ids):
            V[ids] = self.B.closest(V[ids])[2]

    def settle_boundary(self, table: EdgeTable | None = None) -> float:
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
        d2, _, P = self.closest_on_b(ids)
        off = d2 > self.on_b ** 2
        if not off.any():
            return float(np.sqrt(d2.max()))
        X1 = m.V.copy()
        X1[ids[off]] = P[off]
        self.stop_crossings_on_b(X1, table or self.edges())  # no two boundary curves made to cross on B
        stopped, _ = self.stop_collisions(m.V, X1, m.F, self.params.thickness * self.h, table or self.edges(),
                                     moving=ids[off])
        self.state.hold[stopped] = self.params.hold
        m.V = X1
        return self.boundary_error(ids)

    def fit_chords(self, table: EdgeTable, rounds: int = _CHORD_ROUNDS) -> tuple[int, EdgeTable]:
        """Split boundary edges whose chords pass farther than ``split_distance`` from B and put the new
        vertices on B (:func:`~fracture.refine.remesh.plan_chord_splits`), for a few rounds; returns the
        number of splits and the current edge table."""
        p, made = self.params, 0
        for _ in range(rounds):
            ids = np.unique(row_edges(self.mesh.F, table.boundary_rows))
            off_b = ids[self.closest_on_b(ids)[0] > self.on_b ** 2]
            plan = plan_chord_splits(self.mesh.V, self.mesh.F, table, far=p.split_distance * self.h,
                                     near_b=p.min_edge * self.h, budget=p.max_triangles - len(self.mesh.F),
                                     project=lambda P: self.B.closest(P)[2], off_b=off_b,
                                     normal_at=self.B.normal_at)
            if not plan.count:
                break
            made += plan.apply(self.mesh)
            self.state.grow(len(self.mesh.V))
            table = self.edges()
            self.boundary = np.unique(row_edges(self.mesh.F, table.boundary_rows))
            self.settle_boundary(table)
        return made, table

    def boundary_error(self, ids: np.ndarray | None = None) -> float:
        """Largest distance of the boundary vertices (or of ``ids``) from B."""
        ids = self.boundary_vertices() if ids is None else ids
        return float(np.sqrt(self.closest_on_b(ids)[0].max())) if len(ids) else 0.0

    def _velocity(self, table: EdgeTable):
        """Eq. 3 at every vertex with the boundary constraint.

        Returns the velocity, the shifted psibar at the vertices (the flow's
        integrand), the barycentric vertex areas, the boundary vertices and
        the two directions their moves lose (the sheet's outward conormal and
        B's normal); records the boundary vertices off B in ``off_b``.
        """
        m = self.mesh
        _, psibar, grad = self.vertex_field()
        w = self.flow.integrand(psibar, self.offset)
        dE, area = energy_gradient(m.V, m.F, w, self.flow.gradient(grad), self.grain)
        v = -dE / np.maximum(area, tol.tiny)[:, None]
        rows = table.boundary_rows
        if not len(rows):
            self.off_b = np.zeros(0, np.int64)
            return v, w, area, np.zeros(0, np.int64), (np.zeros((0, 3)), np.zeros((0, 3)))
        # boundary vertices slide on B: drop the part of their velocity that
        # points out of the sheet across its boundary (the area term of an
        # open sheet pulls its boundary inward; at a crease of B this pull is
        # not normal to B) and the part normal to B (projection undoes it)
        verts, c = boundary_conormals(m.V, m.F, row_edges(m.F, rows), strict=False, face=rows // 3, by_length=True)
        d2, tri, _ = self.closest_on_b(verts)
        self.off_b = verts[d2 > self.on_b ** 2]
        nb = self.B.normals[tri]
        _drop(v, verts, c, nb)
        return v, w, area, verts, (c, nb)

    # -- one iteration --------------------------------------------------------------------
    def iterate(self) -> tuple[float, int]:
        """One iteration (module notes); returns the mean move in grid cells and the number of splits."""
        m, p, log, s = self.mesh, self.params, self.log, self.state
        clock = time.perf_counter()
        self.put_in_spatial_order()
        clock = log.tick("order", clock)
        table = self.edges()
        v, w, area, boundary, frames = self._velocity(table)
        clock = log.tick("flow", clock)
        plan = self.splits.plan(self, table, v, w, budget=p.max_triangles - p.max_triangles // _CHORD_RESERVE - len(m.F))
        self.full |= plan.full
        made = plan.apply(m)
        if made:
            s.grow(len(m.V))
            table = self.edges()
            clock = log.tick("remesh", clock)
        fitted, table = self.fit_chords(table)
        made += fitted
        clock = log.tick("boundary", clock)
        # the boundary constraint first: new vertices on boundary edges start on
        # the chord, off B; the step is measured from the surface on B
        self.boundary = np.unique(row_edges(m.F, table.boundary_rows))
        settle = self.boundary_error(self.boundary) > self.on_b
        if settle:
            self.settle_boundary(table)
            clock = log.tick("boundary", clock)
        if made or settle:
            v, w, area, boundary, frames = self._velocity(table)
            clock = log.tick("flow", clock)
        s.velocity = v
        before = energy(m.V, m.F, w, self.grain)
        wf = w[m.F].mean(axis=1)
        if self.grain is not None:  # the implicit area term: each triangle's weight times its g(n)
            A, G, _ = face_terms(m.V, m.F, self.grain)
            wf = wf * G / np.maximum(A, tol.tiny)
        held = s.hold > 0
        s.hold = np.maximum(s.hold - 1, 0)
        closed = closed_vertices(m.F, len(m.V), table)  # for the collision step and the flips
        X1, grid, after, retries, stopped = m.V, None, before, 0, np.zeros(len(m.V), bool)
        L = cotangent_weights(m.V, m.F, wf, table)
        for attempt in range(_ATTEMPTS):
            tau = self.step.tau
            d = self.solve(L, area, v, tau)
            _drop(d, boundary, *frames)
            d[held] = 0.0
            limit_moves(m.V, m.F, d, p.fold, p.max_move * self.h)
            limit_by_shortest_edge(m.V, m.F, d, boundary, BOUNDARY_MOVE)
            trial = m.V + d
            self.project_to_exterior(boundary, trial)
            inner = np.flatnonzero((d != 0.0).any(axis=1))
            inner = inner[~np.isin(inner, boundary)]
            out = self.leaving_b(trial, inner)
            trial[out] = m.V[out]  # stopped, as a collision stops a vertex
            self.stop_crossings_on_b(trial, table)
            # the functional before the collisions are looked for: a step that raises it is
            # rejected without them (stopping colliding vertices where they are seldom lowers it)
            went = np.flatnonzero((trial != m.V).any(axis=1))  # the field is known where nothing moved
            fresh = self.pyramid.coarse_field(self.first, trial[went], self.count)
            psibar1 = s.psibar.copy()
            psibar1[went] = fresh[1]
            value = energy(trial, m.F, self.flow.integrand(psibar1, self.offset), self.grain)
            clock = log.tick("step", clock)
            if value <= before + tol.functional_rise * abs(before):
                hit, _, grid = self.stop_collisions(m.V, trial, m.F, p.thickness * self.h, table, return_grid=True,
                                               moving=went, closed=closed)
                clock = log.tick("collisions", clock)
                if hit.any():  # stopped vertices stay where they were, with their field
                    moved = (trial[went] != m.V[went]).any(axis=1)
                    went, fresh = went[moved], tuple(f[moved] for f in fresh)
                    psibar1[hit] = s.psibar[hit]
                    value = energy(trial, m.F, self.flow.integrand(psibar1, self.offset), self.grain)
                    clock = log.tick("step", clock)
            if value <= before + tol.functional_rise * abs(before):
                X1, after, stopped = trial, value, hit
                s.psi[went], s.psibar[went], s.grad[went] = fresh  # the next iteration's field
                s.field_at[went] = trial[went]
                self.step.accepted()
                break
            retries += 1
            grid = None  # the collision grid of a rejected trial does not fit the surface
            if self.step.at_least:
                break  # no descent at the smallest step: the surface is at a minimum
            self.step.rejected()
        s.hold[stopped] = p.hold
        moved = np.linalg.norm(X1 - m.V, axis=1)
        m.V = X1
        self.boundary = boundary  # flips keep the boundary: valid until the next splits
        flip_edges(m.V, m.F, m.sides, max_passes=3, safe=True, grid=grid, table=table, closed=closed)
        clock = log.tick("flips", clock)
        log.functional_before.append(before)
        log.functional.append(after)
        log.tau.append(tau)
        log.retries.append(retries)
        log.splits.append(made)
        log.stopped.append(int(stopped.sum()))
        log.max_move.append(float(moved.max() / self.h) if len(moved) else 0.0)
        return (float(moved.mean() / self.h) if len(moved) else 0.0), made

    def run_search(self, callback=None) -> SearchResult:
        """The global search (:mod:`fracture.refine.search`); its surface, if it lowers the functional,
        replaces the mesh (in place) and is the log's next entry, with ``callback(-1, self)``."""
        clock = time.perf_counter()
        log = self.log
        result = self.search(self.mesh, self.pyramid, self.B)
        log.search = result
        if result.surface is None:
            log.tick("search", clock)
            return result
        self.mesh.replace(result.surface)
        self.searched = True
        self.state = VertexState.empty(len(self.mesh.V))
        self._ordered = 0
        self.off_b = np.zeros(0, np.int64)
        self.begin_stage(*self.stages()[0])
        self.boundary = self.boundary_vertices()
        # both on the polish's field (level 0): the coarse surface's functional there, and the new one's;
        # how far the surface went: the new vertices' distances to the coarse surface
        travel = result.travel
        self._record_step(result.functional[0], self.functional(), float(travel.max()) if len(travel) else 0.0)
        self._record(float(travel.mean()) if len(travel) else 0.0, self.boundary_error(self.boundary),
                     stage=SEARCH_STAGE)
        log.tick("search", clock)
        if callback is not None:
            callback(-1, self)
        return result

    def _record_step(self, before: float, after: float, max_move: float) -> None:
        """The log's entry of a change that is not a flow step (the coarse surface, the search's): the
        functional before and after it and its largest move (cells), no tau, retries, splits or stops."""
        log = self.log
        log.functional_before.append(before)
        log.functional.append(after)
        log.max_move.append(max_move)
        log.tau.append(0.0)
        log.retries.append(0)
        log.splits.append(0)
        log.stopped.append(0)

    def _record(self, move: float, boundary_error: float, stage: int | None = None) -> None:
        log = self.log
        log.stage.append(self.first if stage is None else stage)
        log.energy.append(self.plain_energy())
        log.area.append(float(energy(self.mesh.V, self.mesh.F, np.ones(len(self.mesh.V)))))
        log.triangles.append(len(self.mesh.F))
        log.mean_move.append(move)
        log.boundary_error.append(boundary_error)

    def run(self, callback=None) -> IterationLog:
        """Run the stages (module notes) until each has settled or ``iterations`` are done.

        ``callback(it, refiner)`` is called after every iteration (the mesh
        may be numbered in spatial order then); the reason for stopping is
        ``log.stop``. Boundary vertices still off B at the end of a stage (a
        collision stopped their projection) are moved onto B alone
        (:meth:`settle_boundary`). The mesh ends numbered in creation order.
        """
        p, log = self.params, self.log
        # iteration 0: the coarse surface
        E = self.functional()
        self._record_step(E, E, 0.0)
        self.boundary = self.boundary_vertices()
        self._record(0.0, self.boundary_error(self.boundary))
        if self.search is not None:
            self.run_search(callback)
        if log.boundary_error[-1] > self.on_b:  # the surface onto B before the flow starts
            self.settle_boundary()
        self.fit_chords(self.edges())
        done, unsettled = 0, []
        for first, count in self.stages():
            if (first, count) != (self.first, self.count):
                self.begin_stage(first, count)
            settled = False
            for _ in range(p.stage_iterations):
                if done >= p.iterations:
                    break
                move, made = self.iterate()
                done += 1
                clock = time.perf_counter()
                gain = log.functional_before[-1] - log.functional[-1]
                little = (_FULL_GAIN if self.full else _LITTLE_GAIN) * abs(log.functional[-1])
                settled = (move < p.tolerance or gain < little) and (made <= _FEW_SPLITS * len(self.mesh.F)
                                                                      or self.full)
                off_b = self.boundary_error(self.boundary)
                if settled and off_b > self.on_b:
                    off_b = self.settle_boundary()
                    log.functional[-1] = self.functional()
                self._record(move, off_b)
                log.tick("bookkeeping", clock)
                if callback is not None:
                    callback(done - 1, self)
                if settled:
                    break
            if not settled:
                unsettled.append(first)
            if done >= p.iterations:
                break
        off_b = self.settle_boundary() if self.boundary_error(self.boundary) > self.on_b else 0.0
        if off_b > self.on_b:
            log.boundary_error[-1] = off_b
        if done >= p.iterations and (self.first, self.count) != self.stages()[-1]:
            log.stop = f"iterations: {done} done before the last stage"
        elif unsettled:
            log.stop = f"stage iterations spent on the stages of levels {unsettled}"
        else:
            log.stop = "settled"
        if off_b > self.on_b:
            off = int((self.closest_on_b(self.boundary)[0] > self.on_b ** 2).sum())
            which = "1 boundary vertex stays" if off == 1 else f"{off} boundary vertices stay"
            log.stop += f"; {which} off B (up to {off_b / self.h:.3g} grid cells): collisions block the way"
        self._renumber(self.mesh.creation_order())  # the tree's order, coarse vertices first
        return self.log


def default_search(params: RefineParams, distance: np.ndarray | None = None, names: list[str] | None = None,
                   grain=None):
    """The search the parameters ask for, as the refiner's ``search`` seam (None for ``search: none``);
    ``distance`` (optional) are the grid nodes' distances to the coarse surface, known to the fields,
    ``names`` the pieces' names for its notes, ``grain`` the fibres of an anisotropic strength."""
    if params.search == "none":
        return None

    def search(mesh, pyramid, B):
        return graph_cut_search(mesh, pyramid, B, params.band, params.tension, distance=distance, core=params.core,
                                names=names, grain=grain)

    return search


def clearance(F: np.ndarray, X: np.ndarray, at: np.ndarray, d2: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """For vertices ``ids`` at ``X[ids]``: the largest ``sqrt(d2[j]) - |X[i] - at[j]|`` over the vertex
    itself and its neighbours ``j`` in triangles ``F``, where ``d2[j]`` is the squared distance to B of
    the inside point ``at[j]`` (NaN: unknown). Positive, it is a lower bound of ``X[i]``'s distance to
    B, and ``X[i]`` lies inside (the distance is 1-Lipschitz); ``-inf`` where nothing is known."""
    mark = np.zeros(len(X), np.bool_)
    mark[ids] = True
    bound = np.full(len(X), -np.inf)
    _clearance(F, X, at, d2, mark, bound)
    return bound[ids]


@numba.njit(cache=True, inline="always")
def _ball(X, at, d2, i, j, bound):
    """Raise ``bound[i]`` to what ``j``'s answer (if any) proves of ``X[i]``."""
    if np.isfinite(d2[j]) and at[j, 0] == at[j, 0]:
        bound[i] = max(bound[i], np.sqrt(d2[j]) - vec.norm(vec.sub(vec.point(X, i), vec.point(at, j))))


@numba.njit(cache=True)
def _clearance(F, X, at, d2, mark, bound):
    # one pass over the vertices and one over the triangles (a running maximum, which NumPy's
    # maximum.at makes ten times slower on the wall's 200K triangles)
    for i in range(X.shape[0]):
        if mark[i]:
            _ball(X, at, d2, i, i, bound)
    for f in range(F.shape[0]):
        for k in range(3):
            i = F[f, k]
            if mark[i]:
                _ball(X, at, d2, i, F[f, (k + 1) % 3], bound)
                _ball(X, at, d2, i, F[f, (k + 2) % 3], bound)


def _drop(d: np.ndarray, ids: np.ndarray, c: np.ndarray, nb: np.ndarray) -> None:
    """Remove from the moves ``d[ids]`` their parts along ``c`` and then along ``nb`` (in place)."""
    if len(ids):
        d[ids] -= np.einsum("ij,ij->i", d[ids], c)[:, None] * c
        d[ids] -= np.einsum("ij,ij->i", d[ids], nb)[:, None] * nb
