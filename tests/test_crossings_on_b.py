"""Boundary curves crossing on B: the segment test seen along B's normal."""

import numpy as np

from fracture.refine.crossings_on_b import candidate_pairs, close_pairs, crossing_pairs, splits_would_cross

UP = lambda P: np.tile([0.0, 0.0, 1.0], (len(P), 1))  # noqa: E731  (B is the plane z = 0)


def test_crossing_segments_on_a_plane_are_found_whatever_their_depth():
    X = np.array([[0, 0, 0], [1, 1, 0], [0, 1, -0.3], [1, 0, 0.2],  # an X, the second chord deeper
                  [3, 0, 0], [4, 0, 0], [3, 1, 0], [4, 1, 0]], float)  # two parallels a unit apart
    E = np.array([[0, 1], [2, 3], [4, 5], [6, 7]])
    assert crossing_pairs(X, E, UP).tolist() == [[0, 1]]
    # closer than the gap counts too
    assert sorted(crossing_pairs(X, E, UP, gap=1.5).tolist()) == [[0, 1], [2, 3]]


def test_edges_sharing_a_vertex_never_cross():
    X = np.array([[0, 0, 0], [1, 0, 0], [0.5, 0, 0]], float)
    E = np.array([[0, 1], [1, 2]])  # overlapping, but meeting at vertex 1
    assert len(crossing_pairs(X, E, UP, gap=0.1)) == 0


def test_a_split_whose_midpoint_lands_across_a_curve_is_flagged():
    X = np.array([[0, 0, 0], [2, 0, 0], [1, 0.3, 0], [1, 2, 0]], float)
    E = np.array([[0, 1], [2, 3]])  # the second curve starts just above the first edge's middle
    assert len(crossing_pairs(X, E, UP)) == 0
    # the first edge's middle projected to (1.2, 1): its halves cross the second curve
    assert splits_would_cross(X, E, np.array([0]), np.array([[1.2, 1.0, 0.0]]), UP).tolist() == [True]
    # projected to (1, -0.2): clear of it
    assert splits_would_cross(X, E, np.array([0]), np.array([[1.0, -0.2, 0.0]]), UP).tolist() == [False]


def test_every_crossing_is_found_among_short_and_long_edges():
    """Many short edges and a few long ones (a refined boundary keeps long chords along flat faces of B):
    the pairs found are exactly those whose segments properly cross, by a test of every pair."""
    rng = np.random.default_rng(5)
    n = 600
    A = rng.uniform(0, 10, (n, 2))
    length = np.where(rng.random(n) < 0.05, rng.uniform(2, 6, n), rng.uniform(0.05, 0.4, n))
    angle = rng.uniform(0, np.pi, n)
    B = A + length[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
    X = np.column_stack([np.concatenate([A, B]), rng.uniform(-0.1, 0.1, 2 * n)])  # depths differ
    E = np.column_stack([np.arange(n), n + np.arange(n)])

    def turn(p, q, r):
        return np.sign((q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0]))

    i, j = np.triu_indices(n, 1)
    a, b, c, d = A[i], B[i], A[j], B[j]
    cross = (turn(a, b, c) * turn(a, b, d) < 0) & (turn(c, d, a) * turn(c, d, b) < 0)
    want = {(int(p), int(q)) for p, q in zip(i[cross], j[cross])}
    got = {tuple(sorted(map(int, p))) for p in crossing_pairs(X, E, UP)}
    assert len(want) > 20 and got == want


def test_the_candidates_of_a_move_hold_every_pair_close_after_it():
    """candidate_pairs(X, E, gap, move): the pairs that come within the gap at any positions within ``move``
    of X are among them (and the checks of close_pairs among them give its own answer)."""
    rng = np.random.default_rng(5)
    X = rng.uniform(0, 1, (400, 3)) * [1, 1, 0.01]  # a thin slab: edges on a plane, as on a face of B
    E = np.stack([np.arange(0, 400, 2), np.arange(1, 400, 2)], 1)
    X[E[:, 1]] = X[E[:, 0]] + rng.normal(0, 0.03, (200, 3)) * [1, 1, 0]
    gap, move = 0.01, 0.02
    candidates = candidate_pairs(X, E, gap, move)
    known = {tuple(p) for p in candidates.tolist()}
    for _ in range(5):
        d = rng.normal(size=X.shape)
        Y = X + move * rng.uniform(0, 1, (len(X), 1)) * d / np.linalg.norm(d, axis=1)[:, None]
        pairs, crossing = close_pairs(Y, E, UP, gap)
        assert {tuple(p) for p in pairs.tolist()} <= known
        with_candidates = close_pairs(Y, E, UP, gap, candidates)
        assert np.array_equal(with_candidates[0], pairs) and np.array_equal(with_candidates[1], crossing)
    assert len(candidate_pairs(X, E, gap)) < len(candidates)  # the move widens the search


def test_per_vertex_moves_widen_only_their_own_edges_search():
    """With each edge's ends' largest move: every pair that comes within the gap at positions within each
    vertex's own move is among the candidates, and one vertex that moves far does not pair every edge
    with every other (as one distance for all would)."""
    rng = np.random.default_rng(6)
    X = rng.uniform(0, 1, (400, 3)) * [1, 1, 0.01]
    E = np.stack([np.arange(0, 400, 2), np.arange(1, 400, 2)], 1)
    X[E[:, 1]] = X[E[:, 0]] + rng.normal(0, 0.03, (200, 3)) * [1, 1, 0]
    gap = 0.01
    move = rng.uniform(0, 0.02, len(X))
    move[7] = 0.5  # one far move
    candidates = candidate_pairs(X, E, gap, move[E].max(axis=1))
    known = {tuple(p) for p in candidates.tolist()}
    for _ in range(5):
        d = rng.normal(size=X.shape)
        Y = X + (move * rng.uniform(0, 1, len(X)))[:, None] * d / np.linalg.norm(d, axis=1)[:, None]
        pairs, _ = close_pairs(Y, E, UP, gap)
        assert {tuple(p) for p in pairs.tolist()} <= known
    assert len(candidates) < 0.25 * len(candidate_pairs(X, E, gap, float(move.max())))
