import numpy as np
import pytest

from fracture.primitives import box
from fracture.topology import directed_edge_face, directed_edges, fan, signed_volume, unique_edges


def test_directed_edge_face_finds_the_owner_or_minus_one():
    F = np.array([[0, 1, 2], [2, 1, 3]])
    E = np.array([[0, 1], [1, 0], [1, 3], [3, 1], [2, 0], [5, 6]])
    np.testing.assert_array_equal(directed_edge_face(F, E), [0, -1, 1, -1, 0, -1])
    D = directed_edges(F)
    np.testing.assert_array_equal(directed_edge_face(F, D), np.repeat([0, 1], 3))


def test_unique_edges_of_a_closed_box():
    V, F = box([0, 0, 0], [1, 1, 1], (2, 2, 2))
    edges, count = unique_edges(F)
    assert np.all(count == 2) and len(edges) == 3 * len(F) // 2
    assert signed_volume(V, F) == pytest.approx(1.0)
    assert signed_volume(V, F[:, ::-1]) == pytest.approx(-1.0)


def test_fan_triangulates_polygons():
    T, owner = fan([np.array([0, 1, 2, 3, 4]), np.array([5, 6, 7])])
    np.testing.assert_array_equal(T, [[0, 1, 2], [0, 2, 3], [0, 3, 4], [5, 6, 7]])
    np.testing.assert_array_equal(owner, [0, 0, 0, 1])
    assert fan([])[0].shape == (0, 3)
