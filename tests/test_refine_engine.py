"""The refinement loop on synthetic fields with known minimisers."""

from __future__ import annotations

import numpy as np

from fields.grid import Grid
from fields.pyramid import StrengthPyramid
from fracture.mesh.primitives import box, sheet
from fracture.refine.boundary import clearance
from fracture.refine.engine import SEARCH_STAGE, RefineParams, Refiner
from fracture.refine.remesh import plan_splits, split_folds
from fracture.mesh.fracture_surface import FractureSurface
from fracture.tolerances import tol


def two_weak_sheets(levels=4):
    """psi on the unit cube: strong material with weak sheets at x = 0.4 and x = 0.75."""
    grid = Grid.from_bounds([-0.05] * 3, [1.05] * 3, (56, 56, 56))
    X = grid.points().reshape(tuple(grid.shape) + (3,))[..., 0]
    psi = 1.0 - np.exp(-((X - 0.4) ** 2) / (2 * 0.04**2)) - 0.8 * np.exp(-((X - 0.75) ** 2) / (2 * 0.04**2))
    return StrengthPyramid(grid, psi, levels=levels, sigma=1.5)


def flat_cut(x=0.52, n=7):
    V, F = sheet(lambda u, v: np.stack([np.full_like(u, x), u, v], 1), (0, 1), (0, 1), n, n)
    return FractureSurface.from_coarse(V, F, np.tile([0, 1], (len(F), 1)))


def test_flat_cut_moves_onto_the_nearer_weak_sheet_and_the_functional_decreases():
    pyramid = two_weak_sheets()
    BV, BF = box([0, 0, 0], [1, 1, 1], (8, 8, 8))
    mesh = flat_cut()
    r = Refiner(mesh, pyramid, BV, BF, RefineParams(tolerance=1e-3), np.random.default_rng(0))
    log = r.run()
    assert log.stop == "settled"  # far below the triangle budget
    x = mesh.V[:, 0]
    assert abs(np.median(x) - 0.4) < 0.02
    assert np.abs(x - 0.4).max() < 0.05
    E, before = np.array(log.functional), np.array(log.functional_before)
    assert (E <= before + tol.functional_rise * np.abs(before)).all()  # no accepted step raises the functional
    assert log.energy[-1] < log.energy[0]
    assert log.stage == sorted(log.stage, reverse=True) and log.stage[-1] == 0  # coarse to fine, ends on every level
    # the boundary stays on the box
    on_b = r.onb.vertices()
    P = mesh.V[on_b]
    assert (np.abs(np.minimum(np.abs(P), np.abs(P - 1)).min(axis=1)) < 1e-9).all()


def test_a_boundary_split_that_its_projection_would_fold_is_recognised():
    """A boundary edge across a crease of B: its midpoint projects 0.05 onto a face of the box."""
    a, b = np.array([0.5, 0.0, 0.1]), np.array([0.5, 0.1, 0.0])
    mid, Q = 0.5 * (a + b), np.array([0.5, 0.0, 0.05])
    wide = np.array([0.5, 0.4, 0.4])  # apex far from the edge: its children tilt a little
    needle = mid - 0.01 * np.array([0.0, 1.0, 1.0])  # apex between the edge and the crease: one turns over
    T = np.array([[a, b, wide], [a, b, needle], [needle, a, b]])
    N = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    N /= np.linalg.norm(N, axis=1)[:, None]
    k = np.array([0, 0, 1])  # the edge a-b in each
    assert split_folds(T, k, np.tile(Q, (3, 1)), N).tolist() == [False, True, True]
    # staying on the chord tilts nothing
    assert not split_folds(T, k, np.tile(mid, (3, 1)), N).any()


def test_settle_boundary_moves_only_the_vertices_off_b_onto_it():
    pyramid = two_weak_sheets()
    BV, BF = box([0, 0, 0], [1, 1, 1], (8, 8, 8))
    mesh = flat_cut()
    r = Refiner(mesh, pyramid, BV, BF, RefineParams(), np.random.default_rng(0))
    r.onb.boundary = r.onb.vertices()
    before = mesh.V.copy()
    off = r.onb.boundary[np.argmin(mesh.V[r.onb.boundary, 1])]  # a vertex on the face y = 0
    mesh.V[off, 1] = -0.03
    assert r.onb.error() > 0.029
    assert r.onb.settle() < 1e-12
    assert np.allclose(mesh.V, before, atol=1e-15)  # back on y = 0; nothing else moved


def test_a_sample_asks_for_a_split_when_it_leaves_its_triangle():
    from fracture.refine.remesh import split_wanted
    T = np.array([[[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]] * 6)
    T[5, 2] = [0.5, 0.01, 0.0]  # a needle
    bary = np.tile([0.4, 0.3, 0.3], (6, 1))
    bary[3] = [0.999, 0.0005, 0.0005]  # by a corner
    bary[4] = [0.5, 0.5, 0.0]  # on the edge 0-1
    P = np.einsum("fk,fkc->fc", bary, T)
    d = np.array([[0, 0, 0.2], [0.2, 0.2, 0], [0, 0, 0.05], [0, 0, 0.2], [0.3, 0.2, 0], [0, 0, 0.2]])
    has_edge = np.array([False, False, False, False, True, False])
    F = np.arange(18).reshape(6, 3)
    v = np.zeros((18, 3))
    want, N = split_wanted(T, P, bary, d, v, F, 1.0, np.zeros(6, np.int64), has_edge, 0.01**2, 0.1, 0.2)
    # off the plane; in the plane (the triangle's own move); too little; at a corner; across its edge; a needle
    assert want.tolist() == [True, False, False, False, True, False]
    assert np.allclose(N, [0, 0, 1])
    # the corners' own move is subtracted: a sample moving with its triangle stays in it
    v[:, 2] = 0.2
    assert not split_wanted(T, P, bary, d, v, F, 1.0, np.zeros(6, np.int64), has_edge, 0.01**2, 0.1, 0.2)[0][0]


def test_settle_boundary_stops_a_vertex_whose_way_onto_b_is_blocked():
    """A boundary vertex pulled 0.03 inside the box; a small sheet lies across its way back to y = 0."""
    from fracture.mesh.intersect import self_intersections
    pyramid = two_weak_sheets()
    BV, BF = box([0, 0, 0], [1, 1, 1], (8, 8, 8))
    sheet_mesh = flat_cut()
    V, F, sides = sheet_mesh.V.copy(), sheet_mesh.F.copy(), sheet_mesh.sides.copy()
    on_y0 = np.flatnonzero(V[:, 1] == 0.0)
    v = on_y0[np.argmin(np.abs(V[on_y0, 2] - 0.5))]
    z0 = V[v, 2]
    V[v, 1] = 0.03
    obstacle = np.array([[0.45, 0.015, z0 - 0.01], [0.59, 0.015, z0 - 0.01], [0.52, 0.015, z0 + 0.03]])
    mesh = FractureSurface.from_coarse(np.vstack([V, obstacle]), np.vstack([F, len(V) + np.array([[0, 1, 2]])]),
                                  np.vstack([sides, [[1, 2]]]))
    assert self_intersections(mesh.V, mesh.F) == 0
    r = Refiner(mesh, pyramid, BV, BF, RefineParams(), np.random.default_rng(0))
    r.onb.boundary = np.array([v])
    before = mesh.V.copy()
    assert abs(r.onb.settle() - 0.03) < 1e-12  # still off B ...
    assert np.array_equal(mesh.V, before) and r.state.hold[v] == r.params.hold  # ... held where it was
    mesh.V[-3:, 0] += 2.0  # the obstacle elsewhere: it goes
    assert r.onb.settle() < 1e-12 and mesh.V[v, 1] == 0.0


def test_no_splits_beside_a_boundary_vertex_that_is_off_b():
    """Smaller triangles around a boundary vertex that a collision kept off B would fold when it moves
    onto B at last: its triangles wait, the others split."""
    pyramid = two_weak_sheets()
    BV, BF = box([0, 0, 0], [1, 1, 1], (8, 8, 8))
    mesh = flat_cut()
    r = Refiner(mesh, pyramid, BV, BF, RefineParams(), np.random.default_rng(0))
    r.begin_stage(*r.stages()[-1])  # the last stage: level 0
    on_y0 = np.flatnonzero(mesh.V[:, 1] == 0.0)
    v = on_y0[np.argmin(np.abs(mesh.V[on_y0, 2] - 0.5))]
    mesh.V[v, 1] = 0.03
    table = r.edges()
    flow = r._velocity(table)
    vel, w = flow.v, flow.w
    assert r.onb.off_b.tolist() == [v]
    fan = mesh.F[(mesh.F == v).any(axis=1)].copy()
    m = len(mesh.F)
    plan = plan_splits(mesh.V, mesh.F, table, vel, w, 10.0 * r.step.start, r.field, r.rng, near=0.0, far=0.0,
                       budget=10_000, off_b=r.onb.off_b)
    assert plan.apply(mesh) > 0
    assert len(mesh.F) > m + len(fan)  # the rest did split ...
    assert np.array_equal(mesh.F[(mesh.F == v).any(axis=1)], fan)  # ... around v nothing did


def test_a_plan_says_the_budget_is_full_when_it_leaves_out_a_wanted_triangle_split():
    """The edge splits fit the budget and a single 1-to-3 split more does: every other wanted split of a
    triangle is left out, and the plan says so (the stage's settle test reads it)."""
    pyramid = two_weak_sheets()
    BV, BF = box([0, 0, 0], [1, 1, 1], (8, 8, 8))
    mesh = flat_cut()
    r = Refiner(mesh, pyramid, BV, BF, RefineParams(), np.random.default_rng(0))
    r.begin_stage(*r.stages()[-1])
    table = r.edges()
    flow = r._velocity(table)

    def plan(budget):
        return plan_splits(mesh.V, mesh.F, table, flow.v, flow.w, 10.0 * r.step.start, r.field,
                           np.random.default_rng(1), near=0.0, far=0.0, budget=budget, off_b=r.onb.off_b)

    every = plan(10_000)
    assert not every.full and len(every.edges) > 0 and len(every.faces) > 1
    some = plan(2 * (len(every.edges) + 1))  # room for the edge splits and one triangle's
    assert len(some.edges) == len(every.edges) and len(some.faces) == 1 and some.full


def test_closest_points_on_b_are_asked_again_only_for_vertices_that_moved():
    pyramid = two_weak_sheets()
    BV, BF = box([0, 0, 0], [1, 1, 1], (8, 8, 8))
    mesh = flat_cut()
    r = Refiner(mesh, pyramid, BV, BF, RefineParams(), np.random.default_rng(0))
    asked = []
    closest = r.B.closest
    r.B.closest = lambda P: asked.append(len(P)) or closest(P)
    ids = r.onb.vertices()
    for moved in (0, 3):
        mesh.V[ids[:moved]] += 0.01
        got = r.onb.closest(ids)
        for a, b in zip(got, closest(mesh.V[ids])):
            assert np.array_equal(a, b)
    assert asked == [len(ids), 3]
    r._renumber(np.arange(len(mesh.V))[::-1])  # the answers follow a renumbering
    mesh.split_triangles(np.array([0]), np.array([[0.2, 0.3, 0.5]]))  # and grow with the mesh
    ids = r.onb.vertices()
    for a, b in zip(r.onb.closest(np.r_[ids, len(mesh.V) - 1]), closest(mesh.V[np.r_[ids, len(mesh.V) - 1]])):
        assert np.array_equal(a, b)
    assert asked == [len(ids), 3, 1]


def test_the_loop_ends_when_collisions_keep_a_boundary_vertex_off_b():
    """Collisions block one boundary vertex in every step (as if a sheet lay across its way back onto
    B): the stages still end, and the reason says that it stays off B and how far."""
    from fracture.refine.collide import stop_collisions
    pyramid = two_weak_sheets()
    BV, BF = box([0, 0, 0], [1, 1, 1], (8, 8, 8))
    mesh = flat_cut()
    on_y0 = np.flatnonzero(mesh.V[:, 1] == 0.0)
    v = on_y0[np.argmin(np.abs(mesh.V[on_y0, 2] - 0.5))]
    mesh.V[v, 1] = 0.03
    P = mesh.V[v].copy()  # blocked, v stays here (the loop renumbers the vertices)

    def blocked(X0, X1, *args, **kwargs):
        out = stop_collisions(X0, X1, *args, **kwargs)
        at = np.flatnonzero((X0 == P).all(axis=1))
        X1[at] = X0[at]
        out[0][at] = True
        return out

    params = RefineParams(iterations=40, max_triangles=400)
    log = Refiner(mesh, pyramid, BV, BF, params, np.random.default_rng(0), collisions=blocked).run()
    assert log.iterations <= params.iterations
    assert "1 boundary vertex stays off B" in log.stop
    assert abs(log.boundary_error[-1] - 0.03) < 1e-9
    # without the block the same run ends with the boundary on B
    log = Refiner(flat_cut(), pyramid, BV, BF, params, np.random.default_rng(0)).run()
    assert "off B" not in log.stop and log.boundary_error[-1] < 1e-12


def test_chord_splits_take_every_boundary_edge_far_from_b_and_only_those():
    """plan_chord_splits: a boundary edge whose middle is farther than ``far`` from B is split at its middle,
    long enough edges only, never one on a vertex off B, and no triangle carries two split edges."""
    from fracture.mesh.edges import edge_table, row_edges
    from fracture.refine.remesh import plan_chord_splits

    mesh = flat_cut()  # the plane x = 0.52 across the unit box; B stands in as a projection
    V, F = mesh.V, mesh.F
    table = edge_table(F, len(V))

    def project(P):  # "B" lies 0.2 off the sheet where y > 0.5
        return P + np.where(P[:, 1:2] > 0.5, [0.2, 0.0, 0.0], [0.0, 0.0, 0.0])

    E = row_edges(F, table.boundary_rows)
    far_edges = {tuple(sorted(e)) for e in E if 0.5 * (V[e[0], 1] + V[e[1], 1]) > 0.5}
    plan = plan_chord_splits(V, F, table, far=0.05, near_b=1e-3, budget=10_000, project=project,
                             off_b=np.zeros(0, np.int64))
    split = {tuple(sorted(e)) for e in plan.edges}
    assert split and split <= far_edges and np.allclose(plan.t, 0.5)
    assert len(np.unique(plan.rows // 3)) == len(plan.rows)  # a triangle carries one split edge at most
    # every far edge is split or shares a triangle with one that is
    faces_split = set((plan.rows // 3).tolist())
    for e in far_edges - split:
        faces = np.flatnonzero(np.isin(F, e).sum(axis=1) == 2)
        assert faces_split & set(faces.tolist())
    # not beside a vertex off B, nor shorter than 2 near_b
    off = np.array(sorted({v for e in split for v in e})[:1])
    plan = plan_chord_splits(V, F, table, far=0.05, near_b=1e-3, budget=10_000, project=project, off_b=off)
    assert not np.isin(plan.edges, off).any()
    assert plan_chord_splits(V, F, table, far=0.05, near_b=1.0, budget=10_000, project=project,
                             off_b=np.zeros(0, np.int64)).count == 0


def test_inner_vertices_that_would_leave_b_are_found_and_only_near_ones_are_asked_about():
    """BoundaryOnB.leaving: an inner vertex moved out of the box (or onto it) is reported, one moved inside is not,
    B is asked only about vertices that its last answers do not prove inside, and an answer outside B
    proves nothing."""
    pyramid = two_weak_sheets()
    BV, BF = box([0, 0, 0], [1, 1, 1], (8, 8, 8))
    mesh = flat_cut()  # the plane x = 0.52; inner vertices from 1/6 to 5/6 in y and z
    r = Refiner(mesh, pyramid, BV, BF, RefineParams(), np.random.default_rng(0))
    inner = np.flatnonzero((np.abs(mesh.V[:, 1:] - 0.5) < 0.4).all(axis=1))
    r.onb.closest(inner)  # their distances to B are known now
    X1 = mesh.V.copy()
    edge, middle = inner[np.argmin(mesh.V[inner, 1])], inner[np.argmin(np.abs(mesh.V[inner, 1:] - 0.5).sum(axis=1))]
    X1[edge, 1] = -0.01  # out through the face y = 0
    X1[middle, 0] += 0.05  # inside, far from B
    asked = []
    closest = r.B.closest
    r.B.closest = lambda P: (asked.append(len(P)), closest(P))[1]
    out = r.onb.leaving(X1, np.array([edge, middle]))
    assert out.tolist() == [edge] and asked == [1]  # the middle vertex is farther than its move from B
    X1[edge, 1] = -0.3  # far out: 0.3 from B
    assert r.onb.leaving(X1, np.array([edge])).tolist() == [edge]
    X1[edge, 1] = -0.25  # still out, though within 0.3 of where B was last asked about it
    assert r.onb.leaving(X1, np.array([edge])).tolist() == [edge]
    X1[edge, 1] = 0.0  # onto B: closer than the thickness
    assert r.onb.leaving(X1, np.array([edge])).tolist() == [edge]
    X1[edge, 1] = 0.02  # back inside
    assert r.onb.leaving(X1, np.array([edge])).size == 0
    asked.clear()
    X1[edge, 1] = 0.015  # inside, nearer than its distance at the last answer: not asked
    assert r.onb.leaving(X1, np.array([edge])).size == 0 and asked == []


def _asking_refiner():
    """A refiner on a flat cut in the unit box, its inner vertices, and the list that records the size of every
    question asked of B from now on."""
    mesh = flat_cut()
    BV, BF = box([0, 0, 0], [1, 1, 1], (8, 8, 8))
    r = Refiner(mesh, two_weak_sheets(), BV, BF, RefineParams(), np.random.default_rng(0))
    asked = []
    closest = r.B.closest
    r.B.closest = lambda P: (asked.append(len(P)), closest(P))[1]
    return mesh, r, np.flatnonzero((np.abs(mesh.V[:, 1:] - 0.5) < 0.3).all(axis=1)), asked


def test_a_split_vertex_inside_its_parents_clear_balls_is_not_asked_about():
    """BoundaryOnB.leaving: a vertex made by a split has never been asked about, but it lies within the balls
    free of B around its parents' last answers: B is not asked about it, unless its move takes it out
    of them (then it is asked, and reported if it leaves)."""
    mesh, r, inner, asked = _asking_refiner()
    r.onb.closest(inner)
    table = r.edges()
    a, b = inner[0], inner[np.argmin(np.linalg.norm(mesh.V[inner[1:]] - mesh.V[inner[0]], axis=1)) + 1]
    assert table.find(np.array([[a, b]]))[0] >= 0  # neighbours
    new = mesh.split_edges(np.array([[a, b]]), np.array([0.5]))[0]
    r.state.grow(len(mesh.V))
    asked.clear()
    X1 = mesh.V.copy()
    X1[new, 0] += 0.02
    assert r.onb.leaving(X1, np.array([new])).size == 0 and asked == []
    assert clearance(mesh.F, X1, r.state.near_at, r.state.near_d2, np.array([new]))[0] > 0.1
    X1[new, 0] = 1.1  # out through the face x = 1, beyond every neighbour's ball
    assert r.onb.leaving(X1, np.array([new])).tolist() == [new] and asked == [1]



def test_a_vertex_two_rings_from_any_answer_is_proved_clear_by_its_neighbours_proofs():
    """BoundaryOnB.leaving keeps what the answers prove as the vertex's own: split an edge, then an edge from
    the new vertex, and the second new vertex, whose neighbours were never asked about, is proved clear by
    the first one's proof; B is not asked about either. Without kept proofs the second is asked."""
    mesh, r, inner, asked = _asking_refiner()
    a = inner[np.argmin(np.linalg.norm(mesh.V[inner, 1:] - 0.5, axis=1))]
    r.onb.closest(np.array([a]))  # the only answer
    nbr = np.unique(mesh.F[(mesh.F == a).any(axis=1)])
    b = nbr[nbr != a][0]
    first = mesh.split_edges(np.array([[a, b]]), np.array([0.5]))[0]
    r.state.grow(len(mesh.V))
    asked.clear()
    X1 = mesh.V.copy()
    assert r.onb.leaving(X1, np.array([first])).size == 0 and asked == []  # proved by a's answer
    assert np.array_equal(r.state.clear_at[first], X1[first]) and r.state.clear_d2[first] > 0.0
    far = [v for v in np.unique(mesh.F[(mesh.F == first).any(axis=1)]) if v not in (a, first)][0]
    second = mesh.split_edges(np.array([[first, far]]), np.array([0.5]))[0]
    r.state.grow(len(mesh.V))
    X1 = mesh.V.copy()
    ring = np.unique(mesh.F[(mesh.F == second).any(axis=1)])
    assert a not in ring  # two rings from the only answer
    assert r.onb.leaving(X1, np.array([second])).size == 0 and asked == []
    r.state.clear_at[:] = np.nan  # no kept proofs: B is asked
    assert r.onb.leaving(X1, np.array([second])).size == 0 and asked == [1]

def test_the_clearance_bound_is_the_same_on_one_thread_and_two():
    import numba

    V, F = box([0, 0, 0], [1, 1, 1], (6, 6, 6))
    rng = np.random.default_rng(0)
    at = V + rng.normal(0, 0.01, V.shape)
    d2 = rng.random(len(V)) * 0.04
    d2[::7] = np.nan  # unknown
    at[::11] = np.nan  # forgotten
    X = V + rng.normal(0, 0.02, V.shape)
    ids = np.arange(0, len(V), 2)
    # what the bound is by its definition: over the vertex and its neighbours in F
    nbrs = [set() for _ in range(len(V))]
    for f in F:
        for i in f:
            nbrs[i].update(f.tolist())
    expect = np.array([max([np.sqrt(d2[j]) - np.linalg.norm(X[i] - at[j]) for j in nbrs[i]
                            if np.isfinite(d2[j]) and not np.isnan(at[j, 0])] or [-np.inf]) for i in ids])
    before = numba.get_num_threads()
    try:
        out = []
        for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(threads)
            out.append(clearance(F, X, at, d2, ids))
    finally:
        numba.set_num_threads(before)
    assert np.isfinite(expect).sum() > len(ids) // 2
    for bound in out:
        np.testing.assert_allclose(bound, expect, rtol=0, atol=1e-12)


def _climbing_refiner(search=None):
    """A flow that climbs psi (its field term turned around) on a flat sheet, which has no area term to
    lower, with a split rule that always splits: every step raises the functional."""
    from fracture.refine.flow import PsiFlow
    from fracture.refine.remesh import LongEdgeSplits

    class Climbing(PsiFlow):
        def gradient(self, grad):
            return -grad

    BV, BF = box([0, 0, 0], [1, 1, 1], (8, 8, 8))
    mesh = flat_cut()
    params = RefineParams(stage_iterations=10, iterations=100, max_triangles=100000)
    return mesh, Refiner(mesh, two_weak_sheets(), BV, BF, params, np.random.default_rng(0), search=search,
                         flow=Climbing(), splits=LongEdgeSplits(0.02))


def test_a_stage_whose_step_raises_the_functional_at_every_tau_ends_without_spending_its_iterations():
    """Every step of the climbing flow raises the functional, halved down to the least tau. The stage has
    settled there (the surface is at a minimum of what the step can reach), though the split rule still
    splits every iteration (before, the first stage went on splitting flat triangles for 9 iterations,
    until no edge was left to split)."""
    mesh, r = _climbing_refiner()
    stages = len(r.stages())
    assert stages > 1
    log = r.run()
    per_stage = np.bincount(np.asarray(log.stage[1:]) - min(log.stage[1:]))
    assert len(per_stage) == stages and per_stage.max() <= 3  # the least tau after two iterations' halvings
    assert per_stage.max() > 1  # a flow from the coarse surface goes on after its first rejected iteration
    assert all(s > 0 for s in log.splits[1:])  # the split rule still split in every one of them
    assert log.stop == "settled"
    assert np.array_equal(log.functional, log.functional_before)  # no step was taken ...
    assert np.allclose(mesh.V[:, 0], 0.52)  # ... and the sheet stayed where it was


def test_the_polish_of_a_searched_surface_settles_at_its_first_iteration_that_no_attempt_descends():
    """On a searched surface (here the search gives back the coarse sheet) the polish has settled after the
    first iteration whose four attempts all raise the functional: the search puts the sheets on psi's
    valley floors, where the step cannot descend."""
    from fracture.refine.search import SearchResult

    def search(mesh, pyramid, B, volumes):
        copy = FractureSurface.from_coarse(mesh.V.copy(), mesh.F.copy(), mesh.sides.copy())
        return SearchResult(copy, travel=np.zeros(len(copy.V)), functional=(1.0, 1.0))

    mesh, r = _climbing_refiner(search)
    log = r.run()
    assert log.stage[1] == SEARCH_STAGE and r.searched
    polish = np.asarray(log.stage[2:])
    assert len(polish) == 1 and log.retries[2] == 4 and log.splits[2] > 0  # one iteration, four attempts
    assert log.stop == "settled"
    assert np.allclose(mesh.V[:, 0], 0.52)


def _held_tilted_sheet():
    """A weak sheet tilted from a flat cut 4 voxels off, with a stress term that holds the cut (psi lowered by
    exp(-d / 2 cells) at distance d from it, as deep as the sheet): the coarser stages' blurred fields carry
    the surface off the cone's valley, a fraction of a cell wide at level 0, toward the sheet."""
    from fields.stress import distance_to_surface
    from fracture.coarse.scenes.weak_sheets import weak_sheet_case

    case = weak_sheet_case("tilted", 4.0)
    d = distance_to_surface(case.grid.points(), case.cut_V, case.cut_F).reshape(case.grid.shape)
    pyramid = StrengthPyramid(case.grid, case.zeta - np.exp(-d / (2.0 * case.h)), levels=5, sigma=1.0)
    mesh = FractureSurface.from_coarse(case.cut_V, case.cut_F, np.tile([0, 1], (len(case.cut_F), 1)))
    return Refiner(mesh, pyramid, case.BV, case.BF, RefineParams(search="none", max_triangles=12000),
                   np.random.default_rng(0))


def test_a_last_stage_that_ends_above_the_coarse_surface_runs_again_from_it():
    r = _held_tilted_sheet()
    log = r.run()
    ended, start, again = r.again
    assert ended > 1.05 * start and again < 1.01 * start  # 0.901 and 0.8257 against 0.825
    assert "and ran again from it" in log.stop and log.stop.endswith(", kept")
    assert abs(log.sampled[1] - again) < 1e-3 * again
    assert len(log.functional) == len(log.stage) == len(log.triangles) == len(log.tau)
    assert log.triangles[-1] == len(r.mesh.F)


def test_a_last_stage_run_again_that_ends_higher_gives_the_first_end_back(monkeypatch):
    """The stage run again is made to end far above (its surface moved two cells off): the first end is the
    result, and the log's last entry."""
    r = _held_tilted_sheet()
    calls, real = [], Refiner._stage

    def stage(self, iterations, done, callback=None, sampled=False):
        out = real(self, iterations, done, callback, sampled)
        calls.append(len(self.mesh.F))
        if self.again is None and len(calls) == len(self.stages()) + 1:  # the stage run again
            self.mesh.V = self.mesh.V + [2.0 * self.h, 0.0, 0.0]
        return out

    monkeypatch.setattr(Refiner, "_stage", stage)
    log = r.run()
    ended, start, again = r.again
    assert again > ended > start and log.stop.endswith("not lower; the first kept")
    assert len(r.mesh.F) == calls[-2] == log.triangles[-1]  # the first end's triangles
    assert abs(log.sampled[1] - ended) < 1e-3 * ended


def test_a_return_to_an_earlier_surface_takes_back_its_volumes_and_holds():
    """A surface given back (the last stage's first end, the search's) comes with the pieces' volumes and the
    holds of its own run: the notes name the pieces held on the way to the surface kept, not those of a run
    that was dropped."""
    import copy

    r = _held_tilted_sheet()
    assert r.volumes is not None
    surface, volume = copy.deepcopy(r.mesh), r.volumes.volume.copy()
    r.volumes.held = {0}
    kept = r._volume()
    r.volumes.held.add(1)
    r.volumes.volume = 0.5 * volume
    assert kept.held == {0} and np.array_equal(kept.volume, volume)  # a copy, not the live record
    r._take(surface, kept)
    assert r.volumes.held == {0} and np.array_equal(r.volumes.volume, volume)
    r.volumes.held.add(1)
    assert kept.held == {0}  # the snapshot stays as it was


def test_kernel_threads_run_small_work_on_the_calling_thread_and_restore_the_count():
    import numba
    import pytest

    from fracture.threads import kernel_threads

    before = numba.get_num_threads()
    with kernel_threads(10, parallel_from=100):
        assert numba.get_num_threads() == 1
    with kernel_threads(100, parallel_from=100):
        assert numba.get_num_threads() == before
    with pytest.raises(RuntimeError), kernel_threads(10, parallel_from=100):
        raise RuntimeError("inside")
    assert numba.get_num_threads() == before


def test_a_refinement_makes_the_same_surface_with_its_kernels_on_one_thread_or_on_every_one(monkeypatch):
    """The iterations' kernels run on one thread below a size (fracture.threads): the surface may not depend
    on it, to the bit."""
    import numba
    import pytest

    import fracture.refine.engine as engine
    from fracture.threads import kernel_threads

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one thread only: nothing to compare")
    pyramid = two_weak_sheets()
    BV, BF = box([0, 0, 0], [1, 1, 1], (8, 8, 8))
    ends, threads = [], []
    for parallel_from in (0, 10**12):  # every iteration on every thread, then every one on one
        def spy(elements, _from=parallel_from):
            threads.append((_from, elements))
            return kernel_threads(elements, _from)

        monkeypatch.setattr(engine, "kernel_threads", spy)
        mesh = flat_cut()
        log = Refiner(mesh, pyramid, BV, BF, RefineParams(iterations=12), np.random.default_rng(0)).run()
        ends.append((mesh.V.copy(), mesh.F.copy(), log.functional[-1]))
    assert {f for f, _ in threads} == {0, 10**12}  # both ways ran
    (V0, F0, E0), (V1, F1, E1) = ends
    assert np.array_equal(F0, F1) and np.array_equal(V0, V1) and E0 == E1


def test_the_last_stage_of_a_flow_from_the_coarse_surface_settles_when_its_sampled_functional_stops_falling():
    """Smooth noise under a flat cut, triangles no finer than half a cell: the last stage's splits and moves go
    on at every iteration (the move and split test alone ran it 13 of its 15 iterations), while its functional
    on dense samples stops falling after a few. The stage ends at the first iteration whose functional on dense
    samples is less than half a percent below that of three iterations before."""
    from scipy import ndimage

    from fracture.refine import engine

    n = 40
    grid = Grid.from_bounds([-0.05] * 3, [1.05] * 3, (n, n, n))
    psi = ndimage.gaussian_filter(np.random.default_rng(0).standard_normal((n, n, n)), 3.0)
    pyramid = StrengthPyramid(grid, psi, levels=4, sigma=1.0)
    BV, BF = box([0, 0, 0], [1, 1, 1], (8, 8, 8))
    params = RefineParams(search="none", max_triangles=100000, min_edge=0.5, keep_volume=0.0)
    r = Refiner(flat_cut(x=0.5), pyramid, BV, BF, params, np.random.default_rng(0))
    last = []  # the last stage's functional on dense samples after each of its iterations
    log = r.run(lambda it, ref: last.append(ref.sampled_functional()) if ref.first == 0 else None)
    span, gain = engine._SETTLE_SPAN, engine._SETTLE_GAIN
    assert span < len(last) < params.stage_iterations
    assert "levels [2, 1]" in log.stop and "0]" not in log.stop  # the coarser stages spent theirs; the last settled
    falls = [last[k - span] - last[k] for k in range(span, len(last))]
    assert falls[-1] < gain * abs(last[-1])
    assert all(f >= gain * abs(v) for f, v in zip(falls[:-1], last[span:-1]))  # it ended at the first such
    assert log.stage.count(0) == len(last)
