"""Boundary curves crossing on B: the segment test seen along B's normal."""

import numpy as np

from fracture.refine.crossings_on_b import crossing_pairs, splits_would_cross

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
