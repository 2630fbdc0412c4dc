"""Edge flips: Delaunay on a plane, never across junctions or component changes."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import Delaunay

from fracture.mesh.intersect import self_intersections
from fracture.refine.flips import flip_edges
from fracture.mesh.topology import unique_edges


def _min_angle(V, F):
    out = []
    for k in range(3):
        a, b, c = V[F[:, k]], V[F[:, (k + 1) % 3]], V[F[:, (k + 2) % 3]]
        u, v = b - a, c - a
        cos = np.einsum("ij,ij->i", u, v) / np.linalg.norm(u, axis=1) / np.linalg.norm(v, axis=1)
        out.append(np.arccos(np.clip(cos, -1, 1)))
    return np.degrees(np.min(out))


def test_flips_make_a_planar_triangulation_delaunay():
    rng = np.random.default_rng(1)
    P = rng.random((80, 2))
    V = np.column_stack([P, np.zeros(len(P))])
    F = Delaunay(P).simplices.astype(np.int64)
    F = np.where((np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])[:, 2] < 0)[:, None], F[:, ::-1], F)
    good = _min_angle(V, F)
    # spoil it: the Delaunay triangulation of a stretched copy is poor for the points themselves
    Vs = V.copy()
    Vs[:, 1] *= 8.0  # in a stretched copy the Delaunay edges differ
    Fs = F.copy()
    flip_edges(Vs, Fs, np.zeros((len(F), 2), np.int64))
    assert _min_angle(V, Fs) < good
    n = flip_edges(V, Fs, np.zeros((len(F), 2), np.int64))
    assert n > 0
    assert abs(_min_angle(V, Fs) - good) < 1e-9  # back to the Delaunay triangulation's smallest angle
    assert flip_edges(V, Fs, np.zeros((len(F), 2), np.int64)) == 0  # the later passes missed no edge
    assert len(unique_edges(Fs)[0]) == len(unique_edges(F)[0])


def test_flips_respect_junctions_and_component_changes():
    # two triangles with different side pairs share an edge: never flipped
    V = np.array([[0, 0, 0], [1, 0, 0], [0.5, 0.05, 0], [0.5, -0.05, 0]], float)
    F = np.array([[0, 1, 2], [1, 0, 3]])
    assert flip_edges(V.copy(), F.copy(), np.array([[0, 1], [0, 1]])) == 1
    F2 = F.copy()
    assert flip_edges(V.copy(), F2, np.array([[0, 1], [0, 2]])) == 0 and np.array_equal(F2, F)
    # a third sheet on the edge makes it a junction: never flipped
    V3 = np.vstack([V, [0.5, 0, 1]])
    F3 = np.vstack([F, [0, 1, 4]])
    assert flip_edges(V3, F3, np.array([[0, 1], [0, 1], [1, 0]])) == 0


def test_safe_flips_flip_like_plain_ones_when_nothing_intersects():
    rng = np.random.default_rng(2)
    P = rng.random((60, 2))
    V = np.column_stack([P, 0.01 * np.sin(5 * P[:, 0])])
    F = Delaunay(P * [1.0, 8.0]).simplices.astype(np.int64)  # poor for the points themselves
    F = np.where((np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])[:, 2] < 0)[:, None], F[:, ::-1], F)
    sides = np.zeros((len(F), 2), np.int64)
    plain, safe = F.copy(), F.copy()
    n = flip_edges(V, plain, sides, max_passes=3)
    assert n > 0
    assert flip_edges(V, safe, sides, max_passes=3, safe=True) == n
    assert np.array_equal(plain, safe)


def test_a_safe_flip_that_would_cut_another_sheet_is_refused():
    # a ridge u-v over the valley w-x: the flip to w-x passes through a small
    # vertical sheet under the ridge, which the ridge itself does not touch
    V = np.array([[-1, 0, 0.5], [1, 0, 0.5], [0, -0.3, 0], [0, 0.3, 0],
                  [-0.05, 0, 0.1], [0.05, 0, 0.1], [0, 0, -0.5]], float)
    F = np.array([[0, 1, 2], [1, 0, 3], [4, 5, 6]], np.int64)
    sides = np.array([[0, 1], [0, 1], [1, 2]])
    assert self_intersections(V, F) == 0
    plain = F.copy()
    assert flip_edges(V, plain, sides) == 1 and self_intersections(V, plain) > 0
    safe = F.copy()
    assert flip_edges(V, safe, sides, safe=True) == 0 and np.array_equal(safe, F)
    far = V.copy()
    far[4:, 0] += 5.0  # the sheet elsewhere: the flip goes ahead
    assert flip_edges(far, F.copy(), sides, safe=True) == 1


def _sheet(rng, n, stretch):
    """A Delaunay triangulation of ``n`` random points of the unit square, made poor by a stretch."""
    P = rng.random((n, 2))
    F = Delaunay(P * [1.0, stretch]).simplices.astype(np.int64)
    turn = np.cross(np.c_[P[F[:, 1]] - P[F[:, 0]], np.zeros(len(F))], np.c_[P[F[:, 2]] - P[F[:, 0]], np.zeros(len(F))])
    return P, np.where((turn[:, 2] < 0)[:, None], F[:, ::-1], F)


def _two_sheets(seed, n=300):
    """Two crumpled sheets 0.04 apart, triangulated differently (one poorly in x, one in y)."""
    rng = np.random.default_rng(seed)
    (P1, F1), (P2, F2) = _sheet(rng, n, 6.0), _sheet(rng, n, 0.2)
    V = np.vstack([np.c_[P1, 0.02 * rng.standard_normal(len(P1))],
                   np.c_[P2, 0.04 + 0.02 * rng.standard_normal(len(P2))]])
    sides = np.r_[np.tile([[0, 1]], (len(F1), 1)), np.tile([[1, 2]], (len(F2), 1))]
    return V, np.vstack([F1, F2 + len(P1)]), sides


def _plain_passes(V, F, sides, passes):
    from fracture.refine.flips import flip_passes, pair_buffer
    from fracture.mesh.edges import edge_table
    t = edge_table(F, len(V))
    pairs = pair_buffer(len(F), passes)
    flipped = flip_passes(V, F, sides, passes, pairs, t.arrays())
    return pairs[:flipped].copy()


@pytest.mark.parametrize("seed", [19, 22, 32])
def test_testing_the_flipped_triangles_at_once_or_one_by_one_agrees(seed):
    """Some flips cut the other sheet, and some cut a triangle another flip changed (which the old
    triangles' boxes need not contain)."""
    from fracture.mesh.intersect import triangle_grid
    from fracture.refine.fans import certified_fans, closed_vertices
    from fracture.refine.flips import flip_regions, unsafe_flips, unsafe_flips_all
    from fracture.mesh.edges import edge_table
    V, F, sides = _two_sheets(seed)
    start = F.copy()
    closed = closed_vertices(F, len(V), edge_table(F, len(V)))
    grid = triangle_grid(V, start)
    group = flip_regions(len(F), _plain_passes(V, F, sides, 3))
    is_changed = group >= 0
    none = np.zeros(len(V), bool)
    one_by_one = unsafe_flips(V, F, grid, group, none)
    assert 0 < one_by_one.sum() < is_changed.sum()
    assert np.array_equal(unsafe_flips_all(V, F, is_changed, none), one_by_one)
    # the fans that do not fold after the flips (closed before them stay closed) skip
    # most pairs and hide no meeting
    sure = certified_fans(V, V, F, closed)
    assert sure.mean() > 0.5
    assert np.array_equal(unsafe_flips(V, F, grid, group, sure), one_by_one)
    assert np.array_equal(unsafe_flips_all(V, F, is_changed, sure), one_by_one)
    assert np.array_equal(closed_vertices(F, len(V), edge_table(F, len(V))), closed)


@pytest.mark.parametrize("seed", [3, 4])
def test_triangles_joined_by_flips_cover_the_same_polygon_before_and_after(seed):
    """What makes undoing a group of flips sound: its triangles' boundary edges never change."""
    from fracture.refine.flips import flip_regions
    V, F, sides = _two_sheets(seed)
    start = F.copy()
    group = flip_regions(len(F), _plain_passes(V, F, sides, 3))
    roots, sizes = np.unique(group[group >= 0], return_counts=True)
    assert sizes.max() > 2  # chains of flips over several passes

    def boundary(T):
        E = np.sort(np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]]), axis=1)
        E, count = np.unique(E, axis=0, return_counts=True)
        return E[count == 1]

    for r in roots:
        ids = np.flatnonzero(group == r)
        assert np.array_equal(boundary(start[ids]), boundary(F[ids]))
    assert np.array_equal(start[group < 0], F[group < 0])


def test_a_given_edge_table_flips_like_a_built_one():
    from fracture.mesh.edges import edge_table
    rng = np.random.default_rng(6)
    P = rng.random((200, 2))
    V = np.column_stack([P, 0.02 * np.sin(7 * P[:, 1])])
    F = Delaunay(P * [1.0, 5.0]).simplices.astype(np.int64)
    F = np.where((np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])[:, 2] < 0)[:, None], F[:, ::-1], F)
    sides = np.zeros((len(F), 2), np.int64)
    built, given = F.copy(), F.copy()
    n = flip_edges(V, built, sides, max_passes=3, safe=True)
    assert n > 0
    assert flip_edges(V, given, sides, max_passes=3, safe=True, table=edge_table(F, len(V))) == n
    assert np.array_equal(built, given)


def test_safe_flips_between_two_close_sheets_leave_nothing_crossing():
    """Flips undone in groups (the kept ones tested again against what went back) end intersection-free."""
    inputs = refused = 0
    for seed in range(40):
        rng = np.random.default_rng(seed)
        (P1, F1), (P2, F2) = _sheet(rng, 200, 6.0), _sheet(rng, 200, 0.2)
        V = np.vstack([np.c_[P1, 0.01 * rng.standard_normal(len(P1))],
                       np.c_[P2, 0.04 + 0.01 * rng.standard_normal(len(P2))]])
        F = np.vstack([F1, F2 + len(P1)])
        if self_intersections(V, F):
            continue
        inputs += 1
        sides = np.r_[np.tile([[0, 1]], (len(F1), 1)), np.tile([[1, 2]], (len(F2), 1))]
        plain, safe = F.copy(), F.copy()
        n_plain = flip_edges(V, plain, sides, max_passes=3)
        n_safe = flip_edges(V, safe, sides, max_passes=3, safe=True)
        assert self_intersections(V, safe) == 0
        E = np.sort(np.concatenate([safe[:, [0, 1]], safe[:, [1, 2]], safe[:, [2, 0]]]), axis=1)
        assert np.unique(E, axis=0, return_counts=True)[1].max() <= 2  # going back made no edge twice
        refused += n_safe < n_plain or not np.array_equal(plain, safe)
    assert inputs >= 10 and refused >= 3


def test_an_edge_is_flipped_only_if_an_angle_opposite_it_is_obtuse():
    # the dot-product shortcut skips the cotangents where neither opposite angle is obtuse:
    # the angles then add up to at most pi, so the cotangent test would not flip either
    from fracture.refine.flips import corner_cot, corner_obtuse
    rng = np.random.default_rng(4)
    flips = 0
    for _ in range(20000):
        V = rng.normal(size=(4, 3)) * [1.0, 1.0, rng.choice([1.0, 0.05, 0.0])]
        wants = corner_cot(V, 2, 0, 1) + corner_cot(V, 3, 1, 0) < -1e-12
        flips += wants
        assert not wants or corner_obtuse(V, 2, 0, 1) or corner_obtuse(V, 3, 1, 0)
        assert corner_obtuse(V, 2, 0, 1) == (np.dot(V[0] - V[2], V[1] - V[2]) < 0.0)
    assert flips > 2000


@pytest.mark.parametrize("seed", [3, 4])
def test_the_edges_tried_first_are_those_whose_opposite_angles_add_up_to_more_than_pi(seed):
    """The first pass's candidates, found on every thread at once: the edges with two triangles whose
    opposite angles, measured here with arccos, add up to more than pi."""
    from fracture.mesh.edges import edge_table
    from fracture.refine.flips import _not_delaunay
    V, F, _ = _two_sheets(seed)
    V = V + np.random.default_rng(seed).normal(scale=0.02, size=V.shape)  # some angles obtuse
    table = edge_table(F, len(V))
    got = _not_delaunay(V, F, table.first, table.second, table.count)

    def angle(f, k):  # the angle at corner k of triangle f
        a, b, c = V[F[f, k]], V[F[f, (k + 1) % 3]], V[F[f, (k + 2) % 3]]
        u, v = b - a, c - a
        return np.arccos(np.clip(u @ v / np.linalg.norm(u) / np.linalg.norm(v), -1.0, 1.0))

    two = np.flatnonzero(table.count == 2)
    # directed edge r = 3 f + k runs from corner k to k + 1: the corner opposite it is k + 2
    total = np.array([angle(r // 3, (r + 2) % 3) + angle(s // 3, (s + 2) % 3)
                      for r, s in zip(table.first[two], table.second[two])])
    clear = np.abs(total - np.pi) > 1e-9
    assert 20 < got[two].sum() < len(two) // 2
    assert np.array_equal(got[two][clear], (total > np.pi)[clear]) and not got[table.count != 2].any()


def test_the_flipped_triangles_meet_the_same_ones_on_one_thread_and_two():
    import numba

    from fracture.mesh.intersect import triangle_grid
    from fracture.refine.flips import flip_regions, unsafe_flips
    V, F, sides = _two_sheets(3)
    grid = triangle_grid(V, F.copy())
    group = flip_regions(len(F), _plain_passes(V, F, sides, 3))
    out, before = [], numba.get_num_threads()
    try:
        for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(threads)
            out.append(unsafe_flips(V, F, grid, group, np.zeros(len(V), bool)))
    finally:
        numba.set_num_threads(before)
    assert 0 < out[0].sum() < len(out[0]) and np.array_equal(out[0], out[1])
