"""Continuous collision detection and the self-intersection count."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import colliding_vertices, grid_sheet
from fracture.mesh.intersect import meeting_pairs, self_intersections
from fracture.refine.collide import stop_collisions


def test_a_vertex_through_a_triangle_is_stopped_and_a_miss_is_not():
    # the tip (vertex 3) of an upright triangle moves down through the flat one, or beside it
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, 1.0], [0.25, 0.2, 3.0], [0.2, 0.25, 3.0]])
    F = np.array([[0, 1, 2], [3, 4, 5]])
    X1 = V.copy()
    X1[3, 2] = -1.0
    stopped, pairs = stop_collisions(V, X1, F, 1e-9)
    assert pairs >= 1 and stopped[:4].all() and np.array_equal(X1, V)
    X1 = V.copy()
    X1[3] = [2.0, 2.0, -1.0]  # passes beside the triangle
    stopped, pairs = stop_collisions(V, X1, F, 1e-9)
    assert pairs == 0 and not stopped.any() and X1[3, 2] == -1.0


def test_crossing_edges_are_stopped():
    # two triangles in the planes x = 0 and y = 0; only their first edges ever cross
    V = np.array([[0, -1, 1], [0, 1, 1], [0, 0, 3], [-1, 0, 0], [1, 0, 0], [0, 0, -3]], float)
    F = np.array([[0, 1, 2], [3, 4, 5]])
    X1 = V.copy()
    X1[:3, 2] -= 2.0
    stopped, pairs = stop_collisions(V, X1, F, 1e-9)
    assert pairs == 1 and stopped[[0, 1, 3, 4]].all() and not stopped[[2, 5]].any()
    assert np.array_equal(X1[:2], V[:2]) and X1[2, 2] == 1.0  # the apex, on no colliding edge, moved
    X1 = V.copy()
    X1[:3, 0] += 3.0  # the moving triangle passes beside
    assert stop_collisions(V, X1, F, 1e-9)[1] == 0


def test_random_moves_of_two_close_sheets_never_leave_them_intersecting():
    crossed = 0
    for seed in range(12):
        rng = np.random.default_rng(seed)
        V1, F1 = grid_sheet(12, 0.0)
        V2, F2 = grid_sheet(12, 0.03, 0.013)
        V = np.vstack([V1, V2]) + rng.normal(0, 0.004, (2 * len(V1), 3))
        F = np.vstack([F1, F2 + len(V1)])
        assert self_intersections(V, F) == 0
        X1 = V + rng.normal(0, 0.03, V.shape)
        crossed += self_intersections(X1, F) > 0
        stopped, _ = stop_collisions(V, X1, F, 1e-9)
        assert self_intersections(X1, F) == 0
        assert not stopped.all()  # most vertices still moved
    assert crossed >= 10  # the unconstrained moves do make the sheets cross


def test_testing_only_the_moving_vertices_stops_the_same_ones():
    rng = np.random.default_rng(5)
    V1, F1 = grid_sheet(12, 0.0)
    V2, F2 = grid_sheet(12, 0.03, 0.013)
    V = np.vstack([V1, V2]) + rng.normal(0, 0.004, (2 * len(V1), 3))
    F = np.vstack([F1, F2 + len(V1)])
    moving = rng.choice(len(V), 40, replace=False)
    X1 = V.copy()
    X1[moving] += rng.normal(0, 0.03, (40, 3))
    everything, pairs = stop_collisions(V, Xa := X1.copy(), F, 1e-9)
    assert everything.any()  # some of them do collide
    stopped, found = stop_collisions(V, Xb := X1.copy(), F, 1e-9, moving=moving)
    assert np.array_equal(stopped[moving], everything[moving])
    assert found == pairs  # every colliding pair has a moving vertex, and is counted once
    assert np.array_equal(Xa, Xb) and self_intersections(Xb, F) == 0


def test_a_few_moving_vertices_look_up_their_pairs_and_stop_as_the_full_listing_does(monkeypatch):
    """Few moving vertices (the boundary settling onto B) take their triangles' pairs from one look-up
    each (:func:`~fracture.mesh.hashgrid.pairs_with`), not from the listing of every pair."""
    from fracture.mesh import hashgrid
    rng = np.random.default_rng(6)
    V1, F1 = grid_sheet(20, 0.0)
    V2, F2 = grid_sheet(20, 0.03, 0.013)
    V = np.vstack([V1, V2]) + rng.normal(0, 0.002, (2 * len(V1), 3))
    F = np.vstack([F1, F2 + len(V1)])
    moving = rng.choice(len(V1), 8, replace=False)  # on the first sheet, pushed through the second
    X1 = V.copy()
    X1[moving, 2] += rng.uniform(0.02, 0.06, len(moving))
    everything, pairs = stop_collisions(V, Xa := X1.copy(), F, 1e-3)
    assert 0 < everything[moving].sum() < len(moving)
    listed = hashgrid.pairs
    monkeypatch.setattr(hashgrid, "pairs", lambda grid: pytest.fail("every pair was listed"))
    stopped, found = stop_collisions(V, Xb := X1.copy(), F, 1e-3, moving=moving)
    monkeypatch.undo()
    assert np.array_equal(stopped[moving], everything[moving]) and found == pairs
    assert np.array_equal(Xa, Xb) and self_intersections(Xb, F) == 0
    # the pairs looked up are the listing's rows with a triangle on a moving vertex
    from fracture.mesh.intersect import box_grid, swept_boxes
    lo, hi = swept_boxes(V, X1, F, 1e-3)
    grid = box_grid(lo, hi, V, F)
    on = np.isin(F, moving).any(axis=1)
    every = listed(grid)
    every = every[on[every[:, 0]] | on[every[:, 1]]]
    assert np.array_equal(hashgrid.pairs_with(grid, lo, hi, np.flatnonzero(on)),
                          every[np.lexsort((every[:, 1], every[:, 0]))])


def _brute_force_pairs(V, F):
    from fracture.mesh.intersect import triangles_intersect
    from fracture.tolerances import tol
    return {(f, g) for f in range(len(F)) for g in range(f + 1, len(F))
            if triangles_intersect(V, F, f, g, tol.static_test)}


def test_the_square_root_free_side_test_rejects_only_segments_the_full_test_rejects():
    from fracture.mesh import vec
    from fracture.mesh.intersect import clearly_one_side, segment_hits_triangle
    from fracture.tolerances import tol
    rng = np.random.default_rng(11)
    rejected = 0
    for flat in (1.0, 1e-9, 1e-13, 0.0):  # the segment's ends ever closer to the plane, then in it
        for _ in range(4000):
            a, b, c, p, q = rng.normal(size=(5, 3))
            p[2], q[2] = p[2] * flat, q[2] * flat
            a[2] = b[2] = c[2] = 0.0
            e1, e2 = tuple(b - a), tuple(c - a)
            n = vec.cross(e1, e2)
            nn2 = vec.dot(n, n)
            P, Q, A = tuple(p), tuple(q), tuple(a)
            for eps in (tol.static_test, 1e-3):
                if clearly_one_side(P, Q, A, n, nn2, eps):
                    rejected += 1
                    assert not segment_hits_triangle(P, Q, A, e1, e2, n, np.sqrt(nn2), eps)
    assert rejected > 4000  # most segments well off the plane are decided without square roots


def test_self_intersection_count_finds_every_crossing_pair():
    V1, F1 = grid_sheet(9, 0.0)
    V2, F2 = grid_sheet(9, 0.0, 0.031)
    V2 = V2[:, [0, 2, 1]] + [0, 0.5, -0.5]  # a vertical sheet through the middle of the first
    V, F = np.vstack([V1, V2]), np.vstack([F1, F2 + len(V1)])
    count, pairs = self_intersections(V, F, report=1000)
    # the hashed grid misses no pair and counts none twice
    assert count > 0 and {tuple(sorted(p)) for p in pairs.tolist()} == _brute_force_pairs(V, F)
    assert self_intersections(V1, F1) == 0
    from fracture.mesh.primitives import box
    BV, BF = box([0, 0, 0], [1, 2, 3], (4, 5, 6))
    assert self_intersections(BV, BF) == 0
    # the pairs are tested on every thread: the same count and the same first pairs on one
    import numba

    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = self_intersections(V, F, report=7)
    finally:
        numba.set_num_threads(before)
    two = self_intersections(V, F, report=7)
    assert one[0] == two[0] == count and len(one[1]) == 7 and np.array_equal(one[1], two[1])

    # every meeting pair listed, or those of some triangles only: the full list filtered
    every = {tuple(sorted(p)) for p in meeting_pairs(V, F).tolist()}
    assert every == _brute_force_pairs(V, F)
    for stride in (2, 9):  # many triangles (the full list kept), a few (a look-up each)
        some = np.zeros(len(F), bool)
        some[::stride] = True
        assert {tuple(sorted(p)) for p in meeting_pairs(V, F, some).tolist()} == {
            p for p in every if some[p[0]] or some[p[1]]}
    assert len(meeting_pairs(V, F, np.zeros(len(F), bool))) == 0


def _two_sheets_with_a_fin(seed):
    """Two close noisy sheets, and a fin on an edge of the first (a non-manifold edge), moved at random."""
    rng = np.random.default_rng(seed)
    V1, F1 = grid_sheet(8, 0.0)
    V2, F2 = grid_sheet(8, 0.03, 0.013)
    V = np.vstack([V1, V2, [[0.3, 0.5, -0.2]]]) + rng.normal(0, 0.004, (2 * len(V1) + 1, 3))
    a, b = F1[20, 0], F1[20, 1]
    F = np.vstack([F1, F2 + len(V1), [[a, b, len(V) - 1]]])
    return V, F, V + rng.normal(0, 0.03, V.shape)


def test_every_vertex_and_edge_is_represented_once_by_a_triangle_on_it():
    from fracture.refine.collide import represented_features
    from fracture.mesh.edges import edge_table
    V, F, _ = _two_sheets_with_a_fin(0)
    table = edge_table(F, len(V))
    rep = represented_features(F, len(V), table.eid)
    edges = np.zeros(len(table.count), int)
    vertices = np.zeros(len(V), int)
    for f, k in zip(*np.nonzero(rep[:, None] & (8 << np.arange(3)))):
        edges[table.eid[3 * f + k]] += 1
    for f, k in zip(*np.nonzero(rep[:, None] & (1 << np.arange(3)))):
        vertices[F[f, k]] += 1  # bit k is the triangle's own vertex k, so it is on it
    assert (table.count == 3).sum() == 1 and (edges == 1).all() and (vertices == 1).all()
    assert (rep == 0).mean() > 0.3  # features are packed: about half the triangles represent none


def test_the_representatives_find_the_colliding_features_that_testing_all_of_them_finds():
    """On one thread and on two (the pairs are tested in chunks, one thread each)."""
    import numba

    from fracture.mesh import hashgrid
    from fracture.mesh.intersect import box_grid, swept_boxes
    from fracture.refine.collide import feature_tests, path_boxes, represented_features
    from fracture.mesh.edges import edge_table
    eta = 1e-3
    before = numba.get_num_threads()
    try:
        for seed in range(3):
            X0, F, X1 = _two_sheets_with_a_fin(seed)
            table = edge_table(F, len(X0))
            expect = colliding_vertices(X0, X1, F, eta)
            lo, hi = swept_boxes(X0, X1, F, eta)
            pairs = hashgrid.pairs(box_grid(lo, hi, X0, F))
            counts = []
            for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
                numba.set_num_threads(threads)
                stop = np.zeros(len(X0), bool)
                counts.append(feature_tests(X0, X1, F, path_boxes(X0, X1), lo, hi,
                                            represented_features(F, len(X0), table.eid), pairs, eta, True,
                                            np.zeros(len(X0), bool), np.zeros(len(X0), bool), stop))
                assert expect.sum() > 20 and np.array_equal(stop, expect)
            assert counts[0] == counts[1] > 0
    finally:
        numba.set_num_threads(before)


def test_the_pairs_touching_moved_vertices_are_the_same_on_one_thread_and_two():
    import numba

    from fracture.mesh import hashgrid
    from fracture.mesh.intersect import box_grid, swept_boxes
    from fracture.refine.collide import _pairs_touching

    X0, F, X1 = _two_sheets_with_a_fin(5)
    lo, hi = swept_boxes(X0, X1, F, 1e-3)
    pairs = hashgrid.pairs(box_grid(lo, hi, X0, F))
    on = np.zeros(len(X0), bool)
    on[: len(X0) // 10] = True
    out = []
    before = numba.get_num_threads()
    try:
        for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(threads)
            out.append(_pairs_touching(F, pairs, on))
    finally:
        numba.set_num_threads(before)
    # the pairs with a vertex in ``on``, in their order
    expect = pairs[on[F[pairs[:, 0]]].any(axis=1) | on[F[pairs[:, 1]]].any(axis=1)]
    assert 0 < len(expect) < len(pairs)
    assert all(np.array_equal(o, expect) for o in out)
