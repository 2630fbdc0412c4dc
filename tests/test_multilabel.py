"""Multi-material marching tetrahedra (fracture/mesh/multilabel.py): B is closed and oriented around the
pieces, the sheets meet it, and a grid of any size gives the same surfaces."""

import numpy as np
import pytest

from fracture.mesh.multilabel import contour_labels
from fracture.mesh.topology import closed_oriented, signed_volume, unique_edges


def _middle(P0, P1, la, lb):
    return np.full(len(P0), 0.5)


def _ball_in_three(n, radius):
    """Labels of a ball of ``radius`` nodes in a grid of ``n`` nodes a side: three pieces (a plane and a half
    plane cut it), 0 outside."""
    c = (n - 1) / 2.0
    i, j, k = np.meshgrid(*[np.arange(n) - c] * 3, indexing="ij")
    label = np.zeros((n, n, n), np.int64)
    inside = i * i + j * j + k * k <= radius * radius
    label[inside & (i < 0.3)] = 1
    label[inside & (i >= 0.3) & (j < 0.2)] = 2
    label[inside & (i >= 0.3) & (j >= 0.2)] = 3
    return label


def test_a_ball_cut_in_three_gives_a_closed_b_and_sheets_meeting_it():
    label = _ball_in_three(24, 9.0)
    c = contour_labels(label, np.zeros(3), np.ones(3), _middle)
    assert closed_oriented(c.exterior_F)
    # B holds about the ball's volume (the marching tetrahedra's polyhedron inside the sphere through the crossings)
    assert signed_volume(c.V, c.exterior_F) == pytest.approx(4.0 / 3.0 * np.pi * 9.0 ** 3, rel=0.06)
    # three sheets; every open edge of the fracture surface lies on an edge of B
    assert {tuple(s) for s in c.sides.tolist()} == {(0, 1), (0, 2), (1, 2)}  # pieces: labels - 1
    e, n = unique_edges(c.fracture_F)
    rims = {tuple(x) for x in e[n == 1].tolist()}
    b_edges = {tuple(x) for x in unique_edges(c.exterior_F)[0].tolist()}
    assert rims and rims <= b_edges
    # each piece's part of B faces away from it
    assert set(np.unique(c.exterior_piece)) == {0, 1, 2}


def test_a_grid_of_more_than_two_million_nodes_gives_the_same_surfaces():
    """The same labels in a 12^3 grid and placed in a 140^3 one (2.7 million nodes, where keys of three node
    ids would overflow 64 bits): the same points, as many triangles, the same area and volume (a quad's
    diagonal may differ: the points are numbered otherwise)."""
    small = _ball_in_three(12, 4.5)
    big = np.zeros((140, 140, 140), np.int64)
    at = np.array([70, 3, 121])
    big[at[0]:at[0] + 12, at[1]:at[1] + 12, at[2]:at[2] + 12] = small
    a = contour_labels(small, np.zeros(3), np.ones(3), _middle)
    b = contour_labels(big, np.zeros(3), np.ones(3), _middle)
    assert closed_oriented(b.exterior_F)
    for F, G in ((a.exterior_F, b.exterior_F), (a.fracture_F, b.fracture_F)):
        assert len(F) == len(G)
        assert np.allclose(_points(a.V, F), _points(b.V - at, G))
        assert _area(a.V, F) == pytest.approx(_area(b.V, G), rel=1e-9)
    assert signed_volume(b.V, b.exterior_F) == pytest.approx(signed_volume(a.V, a.exterior_F), rel=1e-9)


def _points(V, F):
    P = np.round(V[np.unique(F)], 9)
    return P[np.lexsort(P.T[::-1])]


def _area(V, F):
    T = V[F]
    return float(np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1).sum() / 2)


def test_the_mixed_cubes_are_those_whose_corners_differ_each_in_kuhns_six_tetrahedra():
    """Every cube with two labels or more among its eight corners, in C order, split into Kuhn's six
    tetrahedra (the nodes of each by flat id); no cube with one label; no cube in a grid one node thin."""
    from fracture.mesh.multilabel import _KUHN, _mixed_tets

    rng = np.random.default_rng(3)
    label = rng.integers(0, 2, (5, 4, 3)) * rng.integers(1, 4, (5, 4, 3))
    label[:2] = 1  # the first row of cubes has one label
    tets = _mixed_tets(label)
    expected = []
    for c in np.ndindex(4, 3, 2):
        if len(np.unique(label[c[0]:c[0] + 2, c[1]:c[1] + 2, c[2]:c[2] + 2])) > 1:
            for tet in _KUHN:
                expected.append([np.ravel_multi_index(tuple(np.add(c, corner)), label.shape) for corner in tet])
    assert tets.tolist() == expected and len(expected) > 0
    assert len(_mixed_tets(np.ones((1, 4, 4), np.int64))) == 0
    # of those, pieces_only keeps the tetrahedra with two pieces or more among their corners (0 is no piece)
    pieces = [len(set(label.ravel()[t].tolist()) - {0}) for t in tets]
    kept = _mixed_tets(label, pieces_only=True)
    assert kept.tolist() == [t for t, n in zip(tets.tolist(), pieces) if n >= 2]
    assert 0 < len(kept) < len(tets)
