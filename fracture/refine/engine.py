"""The refinement: a coarse-to-fine gradient flow with adaptive splits and constraints (Sections 4.3, 4.4).

The refiner composes the parts, each in its own module:

* the global search before the flow (:mod:`fracture.refine.search`, the
  ``search`` seam): a minimum cut of the functional over a band around the
  coarse surface, which makes the large moves and the turns the flow cannot
  walk; the flow then polishes its surface on the finest level alone (or first on
  ``polish_stages`` coarser stages of the schedule);
* the flow of Eq. 3 (:mod:`fracture.refine.flow`);
* the split plan of Sec. 4.4 (:mod:`fracture.refine.remesh`);
* the step control: implicit area term, move limits, step size
  (:mod:`fracture.refine.step`);
* the collision constraints (:mod:`fracture.refine.collide`) and safe edge
  flips (:mod:`fracture.refine.flips`);
* the pieces' volumes (:mod:`fracture.refine.volumes`): no step moves a
  piece's sheets further into it below ``keep_volume`` of its coarse volume;
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
1 % (full-size iterations are the dearest and gain the least), the last
stage of a flow from the coarse surface after coarser stages (which made the
large moves: a lone stage, the paper's field, travels in it) when its
functional on dense samples (which the splits do not move, as they move the
corners' quadrature) fell by less than half a percent over its last three
iterations (on the marble bunny the weakest fifth of zeta stops growing
halfway through that stage, while the triangles still grow by a quarter),
when no
step lowers the functional even at the least ``tau`` (the surface is at a
minimum of what the step reaches, and the next iterations would only split
triangles that do not move; the branch's polish spent its last three
iterations, 60 % of its time, so), or after ``stage_iterations``. The
polish of a searched surface has settled as soon as an iteration's step
lowers the functional at none of its attempts (each with half the ``tau``
of the last): the search puts the sheets on the floors of psi's valleys,
where psi has a kink and any move raises it at first order (the collapsing
wall's polish spent 2 s splitting 56,000 triangles to 204,000 for 0.3 % of
functional). A flow from the coarse surface goes on at a smaller ``tau``:
there a rejected iteration is most often passing, and stopping at it left
a turned weak sheet 0.8 point less of its area within a voxel. A polish
that ends above the search's surface on dense samples (on which that
surface was chosen) gives it back, as the log's last entry: its edge flips
cut the creases along which the searched sheets follow psi's valley floors
(on the example wall and the tilted and curved weak sheets the search's
surface is 0.5-7 % lower; on a sheet turned 20 degrees from the cut 4.5 %,
and below the flow alone's). A flow from the coarse surface whose last stage
ends above the coarse surface (as put on B) on dense samples, the measure the
search's surface is judged by, runs that stage again from the coarse
surface, with iterations of its own, and ends on the lower of the two: the
coarser stages' blurred fields can carry the surface off a valley that level
0 has and the last stage does not climb back into. A high stress weight
makes such a valley of the cone of xi around the coarse surface, a fraction
of a cell wide at level 0 and flattened in the blurred fields (the marble
bunny at a stress weight of 4: the last stage ended at 0.3992, 10 % above
the coarse surface's 0.3625, 0.30 cells from it; run again, at 0.3649, 0.12
cells from it; the default scenes never run it again). Each return to a
surface is an entry of the log, and the stop says what was kept.

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
   collision holds, the move limits, the pieces' volumes held at their share,
   projection of the boundary onto B,
   inner vertices that would leave B stopped (:meth:`~fracture.refine.boundary.BoundaryOnB.leaving`),
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

import copy
import time
from dataclasses import dataclass, field

import numpy as np

from fracture.mesh.exterior import Exterior
from fracture.refine.boundary import BoundaryOnB
from fracture.refine.collide import stop_collisions
from fracture.refine.fans import closed_vertices
from fracture.refine.flips import flip_edges
from fracture.refine.flow import PsiFlow, energy, energy_gradient, sampled_energy
from fracture.mesh.edges import edge_table, EdgeTable, row_edges
from fracture.refine.order import spatial_order
from fracture.mesh.fracture_surface import FractureSurface
from fracture.refine.params import RefineParams
from fracture.refine.remesh import PsiSplits
from fracture.refine.search import SearchResult, search_band, search_in_rounds
from fracture.refine.volumes import PieceVolumes, measure_volumes
from fracture.refine.state import VertexState
from fracture.refine.step import (BOUNDARY_MOVE, ImplicitStep, StepSize, cotangent_weights, limit_by_shortest_edge,
                                  limit_moves)
from fracture.threads import kernel_threads
from fracture.tolerances import tol
from fracture.mesh.topology import boundary_conormals

# Attempts of a step that would raise the functional, each with half the tau of the last.
_ATTEMPTS = 4
# The field's splits leave the last 1/this of the triangle budget to chord splits (the boundary following B).
_CHORD_RESERVE = 50
# The stage of the search's entry in the log.
SEARCH_STAGE = -1
# A stage has settled when its moves are small and an iteration splits at most this share of the triangles.
_FEW_SPLITS = 0.005
# ... and its moves are small, or its step lowered the functional by less than this fraction.
_LITTLE_GAIN = 1e-4
# The last stage of a flow from the coarse surface has settled when its functional on dense samples fell by less
# than this fraction over its last _SETTLE_SPAN iterations (module notes). On the marble bunny its weakest fifth
# grows from 31.0 to 32.6 % in its first 7 of 15 iterations and stays within 0.3 points of that after, while the
# triangles go from 80,000 to 103,000: it now ends after 9, in 2.8 s instead of 5.1 s, its functional 0.7 %
# higher; the Jell-O at its default budget after 6 of 15 (25.7 -> 26.8 %, 7.2 s -> 2.6 s), the example wall
# after 11 (51.2 -> 51.8 %). Spans of 2 to 4 and gains of a quarter to one percent: within 0.5 points of these.
_SETTLE_SPAN = 3
_SETTLE_GAIN = 5e-3
# Once the triangle budget is full, a stage has settled when an iteration lowers its functional by less than
# this fraction: at full size an iteration costs the most and gains the least (docs/design-measurements.md).
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
    # the functional of level 0 (shifted as the last stage's) over the coarse and the final surface, on dense
    # samples (flow.sampled_energy): comparable between surfaces meshed differently
    sampled: tuple[float, float] = (0.0, 0.0)
    # the same of the coarse surface fitted onto B, where the flow from it starts (0: not measured): its rims
    # follow B's curves, which can add area (the wall with the branch's material 0.7206 -> 0.7540)
    sampled_on_b: float = 0.0

    def tick(self, phase: str, since: float) -> float:
        now = time.perf_counter()
        self.seconds[phase] = self.seconds.get(phase, 0.0) + now - since
        return now

    @property
    def iterations(self) -> int:
        return max(len(self.functional) - 1, 0)


@dataclass
class Velocity:
    """The flow's velocity of an iteration and what the step needs with it.

    Attributes
    ----------
    v : (n, 3) float
        The velocity per vertex, with the boundary constraint applied.
    w : (n,) float
        The flow's integrand per vertex (Eq. 3: the shifted psibar).
    area : (n,) float
        Barycentric vertex areas.
    boundary : (k,) int
        The boundary vertices, and per boundary vertex the two directions its moves lose:
    conormal : (k, 3) float
        the sheet's outward conormal (its area term pulls the boundary inward), and
    normal : (k, 3) float
        B's normal (the projection onto B undoes it).
    """

    v: np.ndarray
    w: np.ndarray
    area: np.ndarray
    boundary: np.ndarray
    conormal: np.ndarray
    normal: np.ndarray


class Refiner:
    """Evolves and refines a fracture surface toward low psi (module notes).

    ``collisions`` is the collision step (default
    :func:`~fracture.refine.collide.stop_collisions`, same signature): a seam for
    another collision response, or for a test that blocks a vertex.
    ``search(mesh, pyramid, B, volumes) -> SearchResult`` is the global search before the
    flow (default: :func:`default_search` of the parameters; None: none); ``volumes`` are the pieces'
    volumes and shares to keep (:class:`~fracture.refine.volumes.PieceVolumes`, or None: no limit).
    ``grain`` (a :class:`fields.grain.Grain`) makes the functional the integral
    of psi g(n): the flow, the splits and the step's acceptance use it (the
    implicit area term takes each triangle's g(n) as a factor of its weight).
    ``flow`` is the flow (default :class:`~fracture.refine.flow.PsiFlow`, Eq. 3; its integrand and
    field term), ``splits`` the split rule (default :class:`~fracture.refine.remesh.PsiSplits`, the
    paper's): seams for another flow (``AreaFlow``: mean curvature flow) or split rule
    (``LongEdgeSplits``). ``coarse_volumes`` (optional) are the pieces' volumes at ``mesh``
    (:func:`~fracture.refine.volumes.measure_volumes` of it, B and the grid), measured when not given: they do not
    read psi, so a re-run with another material or stress may bring them.
    """

    def __init__(self, mesh: FractureSurface, pyramid, BV: np.ndarray, BF: np.ndarray, params: RefineParams,
                 rng: np.random.Generator, *, collisions=stop_collisions, search="default", grain=None, flow=None,
                 splits=None, coarse_volumes: np.ndarray | None = None):
        self.mesh, self.pyramid, self.params, self.rng = mesh, pyramid, params, rng
        self.grain = grain
        self.flow = PsiFlow() if flow is None else flow
        self.splits = PsiSplits() if splits is None else splits
        self.stop_collisions = collisions
        self.search = default_search(params, grain=grain) if search == "default" else search
        self.searched = False  # the search's surface replaced the coarse one
        self.searched_volume = None  # the pieces' volumes when it did (PieceVolumes)
        # the last stage's end, the coarse surface's and the end of the stage run again from it, on dense samples
        self.again: tuple[float, float, float] | None = None
        self.h = float(np.min(pyramid.grid.spacing))
        self.log = IterationLog()
        self.B = Exterior(BV, BF)  # its AABB tree, built on the first query, serves every iteration
        self.step = StepSize(params.step, self.h)
        self.solve = ImplicitStep()  # keeps its factorisation for a retried step
        self.state = VertexState.empty(len(mesh.V))
        # each piece's volume, kept above its share of the coarse one (None: no limit)
        self.volumes = None
        if params.keep_volume > 0.0 and len(mesh.F):
            self.volumes = (PieceVolumes.measure(mesh.V, mesh.F, mesh.sides, self.B, pyramid.grid, params.keep_volume)
                            if coarse_volumes is None else PieceVolumes.of(coarse_volumes, params.keep_volume))
        self.begin_stage(*self.stages()[0])  # sets first, count, near, offset and the step size
        # the boundary constraint on B: owns B's answers about the vertices, the boundary and what is off B
        self.onb = BoundaryOnB(mesh, self.state, self.B, self.h, params, collisions)
        self.full = False  # the triangle budget has stopped a wanted split
        self.at_minimum = False  # the last iteration's step lowered the functional at none of its taus: settled
        self._ordered = 0  # vertex count when the mesh was last put in spatial order

    # -- schedule -------------------------------------------------------------------------
    def stages(self) -> list[tuple[int, int]]:
        """``(first, count)`` of each stage's field, coarse to fine: the mean of pyramid levels
        ``first .. first+count-1`` (module notes)."""
        n = self.pyramid.n_levels
        c = min(max(self.params.coarse_levels, 1), n)
        if self.searched:  # the search made the large moves: the flow polishes, on psi itself at the end
            return [(first, c) for first in range(min(self.params.polish_stages, n - c), 0, -1)] + [(0, 1)]
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
        self.offset = self.shift(first, count)
        self.state.forget_field()
        self.step.begin(self.pyramid.gradient_scale(first, self.count))

    def shift(self, first: int, count: int) -> float:
        """What the stage of levels ``first .. first+count-1`` adds to psibar.

        A negative integrand would reward area: the flow would wrinkle without
        bound and the implicit matrix would lose its definiteness. Shifting
        psibar adds a constant surface tension and leaves its gradient
        unchanged; its minimum over the grid becomes ``tension`` of its range."""
        lowest, span = self.pyramid.window_range(first, count)
        return self.params.tension * span - lowest

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
        self.onb.renumber(new)

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

    def _velocity(self, table: EdgeTable) -> "Velocity":
        """The flow's velocity at every vertex with the boundary constraint (:class:`Velocity`); records
        the boundary vertices off B in ``onb.off_b``."""
        m = self.mesh
        _, psibar, grad = self.vertex_field()
        w = self.flow.integrand(psibar, self.offset)
        dE, area = energy_gradient(m.V, m.F, w, self.flow.gradient(grad), self.grain)
        v = -dE / np.maximum(area, tol.tiny)[:, None]
        rows = table.boundary_rows
        if not len(rows):
            self.onb.off_b = np.zeros(0, np.int64)
            return Velocity(v, w, area, np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))
        # boundary vertices slide on B: drop the part of their velocity that
        # points out of the sheet across its boundary (the area term of an
        # open sheet pulls its boundary inward; at a crease of B this pull is
        # not normal to B) and the part normal to B (projection undoes it)
        verts, c = boundary_conormals(m.V, m.F, row_edges(m.F, rows), strict=False, face=rows // 3, by_length=True)
        d2, tri, _ = self.onb.closest(verts)
        self.onb.off_b = verts[d2 > self.onb.on_b ** 2]
        nb = self.B.normals[tri]
        _drop(v, verts, c, nb)
        return Velocity(v, w, area, verts, c, nb)

    # -- one iteration --------------------------------------------------------------------
    def iterate(self) -> tuple[float, int]:
        """One iteration (module notes); returns the mean move in grid cells and the number of splits. Its
        kernels run on one thread on a surface of fewer triangles than the threads pay for
        (:func:`~fracture.threads.kernel_threads`)."""
        with kernel_threads(len(self.mesh.F)):
            return self._iterate()

    def _iterate(self) -> tuple[float, int]:
        m, p, log, s = self.mesh, self.params, self.log, self.state
        clock = time.perf_counter()
        self.put_in_spatial_order()
        clock = log.tick("order", clock)
        table = self.edges()
        vel = self._velocity(table)
        clock = log.tick("flow", clock)
        plan = self.splits.plan(self, table, vel.v, vel.w, budget=p.max_triangles - p.max_triangles // _CHORD_RESERVE - len(m.F))
        self.full |= plan.full
        made = plan.apply(m)
        if made:
            s.grow(len(m.V))
            table = self.edges()
            clock = log.tick("remesh", clock)
        fitted, table = self.onb.fit_chords(table)
        made += fitted
        clock = log.tick("boundary", clock)
        # the boundary constraint first: new vertices on boundary edges start on
        # the chord, off B; the step is measured from the surface on B
        self.onb.boundary = np.unique(row_edges(m.F, table.boundary_rows))
        settle = self.onb.error(self.onb.boundary) > self.onb.on_b
        if settle:
            self.onb.settle(table)
            clock = log.tick("boundary", clock)
        if made or settle:
            vel = self._velocity(table)
            clock = log.tick("flow", clock)
        v, w, area, boundary = vel.v, vel.w, vel.area, vel.boundary
        s.velocity = v
        before = energy(m.V, m.F, w, self.grain)
        wf = self.flow.triangle_weights(m.V, m.F, w, self.grain)  # the implicit area term's weights
        held = s.hold > 0
        s.hold = np.maximum(s.hold - 1, 0)
        closed = closed_vertices(m.F, len(m.V), table)  # for the collision step and the flips
        X1, grid, after, retries, stopped = m.V, None, before, 0, np.zeros(len(m.V), bool)
        descended = tried_least = False
        L = cotangent_weights(m.V, m.F, wf, table)
        for attempt in range(_ATTEMPTS):
            tau = self.step.tau
            d = self.solve(L, area, v, tau)
            _drop(d, boundary, vel.conormal, vel.normal)
            d[held] = 0.0
            limit_moves(m.V, m.F, d, p.fold, p.max_move * self.h)
            limit_by_shortest_edge(m.V, m.F, d, boundary, BOUNDARY_MOVE)
            if self.volumes is not None:
                self.volumes.hold(m.V, m.F, m.sides, d)
            trial = m.V + d
            self.onb.project(boundary, trial)
            inner = np.flatnonzero((d != 0.0).any(axis=1))
            inner = inner[~np.isin(inner, boundary)]
            out = self.onb.leaving(trial, inner)
            trial[out] = m.V[out]  # stopped, as a collision stops a vertex
            self.onb.stop_crossings(trial, table)
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
                descended = True
                break
            retries += 1
            grid = None  # the collision grid of a rejected trial does not fit the surface
            if self.step.at_least:
                tried_least = True
                break  # tau is halved no further
            self.step.rejected()
        # no attempt descended: the surface is at a minimum of what the step reaches when the last was at the
        # least tau, and on a searched surface at once (module notes)
        self.at_minimum = not descended and (tried_least or self.searched)
        s.hold[stopped] = p.hold
        moved = np.linalg.norm(X1 - m.V, axis=1)
        if self.volumes is not None:
            self.volumes.moved(m.V, X1, m.F, m.sides)
        m.V = X1
        self.onb.boundary = boundary  # flips keep the boundary: valid until the next splits
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
        result = self.search(self.mesh, self.pyramid, self.B, self.volumes)
        log.search = result
        if result.surface is None:
            log.tick("search", clock)
            return result
        self.searched = True
        self._take(result.surface, self._volumes_of(result))
        self.searched_volume = self._volume()
        self.begin_stage(*self.stages()[0])
        # both on the polish's field (level 0): the coarse surface's functional there, and the new one's;
        # how far the surface went: the new vertices' distances to the coarse surface
        travel = result.travel
        self._record_step(result.functional[0], self.functional(), float(travel.max()) if len(travel) else 0.0)
        self._record(float(travel.mean()) if len(travel) else 0.0, self.onb.error(self.onb.boundary),
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
        (:meth:`~fracture.refine.boundary.BoundaryOnB.settle`). The mesh ends numbered in creation order.
        """
        p, log = self.params, self.log
        coarse = self.mesh.V.copy(), self.mesh.F.copy()
        # iteration 0: the coarse surface
        E = self.functional()
        self._record_step(E, E, 0.0)
        self.onb.boundary = self.onb.vertices()
        self._record(0.0, self.onb.error(self.onb.boundary))
        if self.search is not None:
            self.run_search(callback)
        if log.boundary_error[-1] > self.onb.on_b:  # the surface onto B before the flow starts
            self.onb.settle()
        self.onb.fit_chords(self.edges())
        # the last stage may run again from it
        start = None if self.searched else (copy.deepcopy(self.mesh), self._volume())
        done, unsettled = 0, []
        stages = self.stages()
        for first, count in stages:
            if (first, count) != (self.first, self.count):
                self.begin_stage(first, count)
            # the last stage after coarser ones of a flow from the coarse surface: those made the large moves
            sampled = not self.searched and len(stages) > 1 and (first, count) == stages[-1]
            done, settled = self._stage(min(p.stage_iterations, p.iterations - done), done, callback, sampled)
            if not settled:
                unsettled.append(first)
            if done >= p.iterations:
                break
        if start is not None and len(self.stages()) > 1 and (self.first, self.count) == self.stages()[-1]:
            self._last_stage_again(*start, done, callback)
        off_b = self.onb.settle() if self.onb.error(self.onb.boundary) > self.onb.on_b else 0.0
        if off_b > self.onb.on_b:
            log.boundary_error[-1] = off_b
        if done >= p.iterations and (self.first, self.count) != self.stages()[-1]:
            log.stop = f"iterations: {done} done before the last stage"
        elif unsettled:
            log.stop = f"stage iterations spent on the stages of levels {unsettled}"
        else:
            log.stop = "settled"
        if self.again is not None:
            ended, start_value, again = self.again
            log.stop += (f"; the last stage ended at {ended:.6g} on dense samples, above the coarse surface put on "
                         f"B ({start_value:.6g}), and ran again from it: "
                         + (f"{again:.6g}, kept" if again < ended else f"{again:.6g}, not lower; the first kept"))
        if off_b > self.onb.on_b:
            off = int((self.onb.closest(self.onb.boundary)[0] > self.onb.on_b ** 2).sum())
            which = "1 boundary vertex stays" if off == 1 else f"{off} boundary vertices stay"
            log.stop += f"; {which} off B (up to {off_b / self.h:.3g} grid cells): collisions block the way"
        self._renumber(self.mesh.creation_order())  # the tree's order, coarse vertices first
        offset = self.shift(0, 1)  # the last stage's
        log.sampled = tuple(sampled_energy(V, F, self.pyramid.value, self.h, offset, self.grain)
                            for V, F in (coarse, (self.mesh.V, self.mesh.F)))
        if self.searched and 0.0 < log.search.sampled[1] < log.sampled[1]:  # 0: not measured
            self._keep_searched(callback)
        return self.log

    def _stage(self, iterations: int, done: int, callback=None, sampled: bool = False) -> tuple[int, bool]:
        """Up to ``iterations`` iterations of the current stage, until it settles (module notes); ``done``
        iterations were run before (``callback(it, refiner)`` is numbered from there); ``sampled``: the stage
        also settles when its functional on dense samples stops falling (the last stage after coarser ones).
        Returns the iterations done in all and whether the stage settled."""
        p, log = self.params, self.log
        settled = False
        trail = [] if sampled else None  # the stage's functional on dense samples after each iteration
        for _ in range(iterations):
            move, made = self.iterate()
            done += 1
            clock = time.perf_counter()
            gain = log.functional_before[-1] - log.functional[-1]
            little = (_FULL_GAIN if self.full else _LITTLE_GAIN) * abs(log.functional[-1])
            # a polish of the search's surface settles on its gain alone: it starts close to a valley
            # floor, where the moves are small from the first iteration (a flat weak sheet on a node
            # plane: the cut's surface a seventh of a cell off it ended after 4 iterations, its
            # functional 6 % above the flow's alone)
            small = gain < little or (move < p.tolerance and not self.searched)
            settled = (small and (made <= _FEW_SPLITS * len(self.mesh.F) or self.full)) or self.at_minimum
            if trail is not None and not settled:  # (a stage that settled otherwise needs no measure)
                trail.append(self.sampled_functional())
                settled |= len(trail) > _SETTLE_SPAN and trail[-1 - _SETTLE_SPAN] - trail[-1] < _SETTLE_GAIN * abs(
                    trail[-1])
            off_b = self.onb.error(self.onb.boundary)
            if settled and off_b > self.onb.on_b:
                off_b = self.onb.settle()
                log.functional[-1] = self.functional()
            self._record(move, off_b)
            log.tick("bookkeeping", clock)
            if callback is not None:
                callback(done - 1, self)
            if settled:
                break
        return done, settled

    def sampled_functional(self) -> float:
        """The stage's functional ``E_s`` over the surface on dense samples
        (:func:`~fracture.refine.flow.sampled_energy`): unlike the corners' quadrature of the flow, not moved by
        the splits of an iteration."""
        def integrand(P):
            return self.flow.integrand(self.pyramid.coarse_field(self.first, P, self.count)[1], self.offset)

        return sampled_energy(self.mesh.V, self.mesh.F, integrand, self.h, 0.0, self.grain)

    def _last_stage_again(self, start: FractureSurface, start_volume, done: int, callback=None) -> None:
        """After the last stage of a flow from the coarse surface ``start`` (on B; its pieces' volumes
        ``start_volume``): if it ended above ``start`` on level 0, on dense samples, the stage again from
        ``start``, with iterations of its own, and whichever of the two ends lower (module notes); each return
        to a surface is the log's next entry, with ``callback`` called (``done``: the iterations run before,
        which it numbers from)."""
        offset = self.shift(0, 1)

        def value(m):
            return sampled_energy(m.V, m.F, self.pyramid.value, self.h, offset, self.grain)

        ended, coarse = value(self.mesh), value(start)
        self.log.sampled_on_b = coarse
        if ended <= coarse:
            return
        first = copy.deepcopy(self.mesh), self._volume()
        self._return_to(start, callback, volume=start_volume)
        self._stage(self.params.stage_iterations, done, callback)
        again = value(self.mesh)
        if again >= ended:
            self._return_to(first[0], callback, volume=first[1])
        self.again = (ended, coarse, again)

    def _return_to(self, surface: FractureSurface, callback=None, stage: int | None = None, volume=None) -> None:
        """``surface`` (a copy; its pieces' volumes ``volume``) as the mesh, as the log's next entry (of the
        current stage, or ``stage``), ``callback`` called."""
        before = self.functional()
        self._take(surface, volume)
        self.full = False
        self._record_step(before, self.functional(), 0.0)
        self._record(0.0, self.onb.error(self.onb.boundary), stage=stage)
        if callback is not None:
            callback(len(self.log.functional) - 1, self)

    def _volumes_of(self, result: SearchResult) -> PieceVolumes | None:
        """The pieces' volumes after the search: as its labels changed them, or measured (a search that does
        not say)."""
        if self.volumes is None:
            return None
        if len(result.volume_change) == len(self.volumes.volume):
            return self.volumes.copy(self.volumes.volume + result.volume_change)
        s = result.surface
        return self.volumes.copy(measure_volumes(s.V, s.F, s.sides, self.B, self.pyramid.grid))

    def _volume(self) -> PieceVolumes | None:
        """The pieces' volumes now and the pieces the flow held on its way here (a copy): what a return to
        this surface takes back, so that the notes name the holds of the surface kept."""
        return None if self.volumes is None else self.volumes.copy()

    def _take(self, surface: FractureSurface, volume: PieceVolumes | None = None) -> None:
        """Replace the mesh by a copy of ``surface`` (in place; the iterations edit the mesh's arrays in place,
        and the log keeps the search's surface as it was), its pieces' volumes and holds those of ``volume``
        (:meth:`_volume`), and start its per-vertex state and boundary afresh."""
        self.mesh.replace(copy.deepcopy(surface))
        if self.volumes is not None:
            self.volumes = volume.copy()
        self.state = self.onb.state = VertexState.empty(len(self.mesh.V))
        self._ordered = 0
        self.onb.off_b = np.zeros(0, np.int64)
        self.onb.boundary = self.onb.vertices()

    def _keep_searched(self, callback=None) -> None:
        """The search's surface again, as the log's last entry (its stage the search's, ``callback`` called):
        the polish raised the functional on dense samples, on which the search's surface was chosen (module
        notes: a flip across a crease of a valley floor)."""
        log, polished = self.log, self.log.sampled[1]
        log.sampled = (log.sampled[0], log.search.sampled[1])
        log.stop += (f"; the polish raised the functional on dense samples ({polished:.6g} against the search's "
                     f"{log.search.sampled[1]:.6g}): the search's surface is kept")
        self._return_to(log.search.surface, callback, stage=SEARCH_STAGE, volume=self.searched_volume)


def default_search(params: RefineParams, distance: np.ndarray | None = None, names: list[str] | None = None,
                   grain=None, bands=None):
    """The search the parameters ask for, as the refiner's ``search`` seam (None for ``search: none``);
    ``distance`` (optional) are the grid nodes' distances to the coarse surface, known to the fields,
    ``names`` the pieces' names for its notes, ``grain`` the fibres of an anisotropic strength.
    ``bands`` (optional) keeps the search's band (:func:`~fracture.refine.search.search_band`, which does
    not read psi) for a later run on the same coarse surface and grid: ``bands.get()`` gives it or None,
    ``bands.put(band)`` keeps it."""
    if params.search == "none":
        return None

    def search(mesh, pyramid, B, volumes=None):
        prepared = None if bands is None else bands.get()
        if prepared is None:
            prepared = search_band(mesh, pyramid.grid, B, params.band, params.core, distance, names)
            if bands is not None:
                bands.put(prepared)
        return search_in_rounds(mesh, pyramid, B, params.band, params.tension, rounds=params.search_rounds,
                                distance=distance, prepared=prepared, core=params.core, names=names, grain=grain,
                                volumes=volumes)

    return search


def _drop(d: np.ndarray, ids: np.ndarray, c: np.ndarray, nb: np.ndarray) -> None:
    """Remove from the moves ``d[ids]`` their parts along ``c`` and then along ``nb`` (in place)."""
    if len(ids):
        d[ids] -= np.einsum("ij,ij->i", d[ids], c)[:, None] * c
        d[ids] -= np.einsum("ij,ij->i", d[ids], nb)[:, None] * nb
