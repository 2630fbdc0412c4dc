import numpy as np
import pytest

from fields.grid import Grid, grid_shape_for_box
from fields.interpolate import trilinear


def linear(P, a=(0.7, -1.3, 2.1), b=0.4):
    return P @ np.asarray(a) + b


def test_trilinear_reproduces_linear_fields():
    grid = Grid.from_bounds([-1.0, 0.5, 2.0], [2.0, 1.5, 2.3], (13, 7, 4))  # anisotropic voxels
    values = linear(grid.points()).reshape(grid.shape)
    P = np.random.default_rng(0).uniform(grid.lo, grid.hi, (5000, 3))
    np.testing.assert_allclose(trilinear(grid, values, P), linear(P), atol=1e-12)


def test_trilinear_interpolates_nodes_and_clamps_outside():
    grid = Grid.from_bounds([0, 0, 0], [1, 2, 3], (4, 5, 6))
    values = np.random.default_rng(1).normal(size=grid.shape)
    np.testing.assert_allclose(trilinear(grid, values, grid.points()), values.ravel(), atol=1e-12)
    # Outside the box a point takes the value of its clamped position.
    P = np.array([[-5.0, 1.0, 1.5], [0.3, 9.0, -2.0]])
    np.testing.assert_allclose(trilinear(grid, values, P), trilinear(grid, values, np.clip(P, grid.lo, grid.hi)))


def test_trilinear_is_bilinear_in_a_cell():
    # f = xyz is trilinear, so interpolation is exact for it too.
    grid = Grid.from_bounds([0, 0, 0], [1, 1, 1], (2, 2, 2))
    X = grid.points()
    values = (X[:, 0] * X[:, 1] * X[:, 2]).reshape(grid.shape)
    P = np.random.default_rng(2).uniform(0, 1, (100, 3))
    np.testing.assert_allclose(trilinear(grid, values, P), P.prod(axis=1), atol=1e-12)


def test_trilinear_channels_and_errors():
    grid = Grid.from_bounds([0, 0, 0], [1, 1, 1], (3, 3, 3))
    X = grid.points()
    values = np.stack([linear(X), 2 * linear(X)], axis=1).reshape(grid.shape + (2,))
    out = trilinear(grid, values, np.array([[0.2, 0.4, 0.6]]))
    assert out.shape == (1, 2) and out[0, 1] == pytest.approx(2 * out[0, 0])
    with pytest.raises(ValueError, match="grid shape"):
        trilinear(grid, np.zeros((2, 3, 3)), X)
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        trilinear(grid, np.zeros(grid.shape), np.zeros((4, 2)))


def test_grid_shape_for_box():
    assert grid_shape_for_box([0, 0, 0], [3, 1, 0.2], [150, 50, 10]) == (150, 50, 10)
    shape = grid_shape_for_box([0, 0, 0], [2, 1, 0.1], 41)
    assert shape == (41, 21, 4)  # near-cubic voxels, at least 4 nodes per axis
    with pytest.raises(ValueError):
        Grid.from_bounds([0, 0, 0], [1, 0, 1], (3, 3, 3))


def test_grid_round_trips_through_dict():
    grid = Grid.from_bounds([0, -1, 2], [1, 1, 3], (3, 4, 5))
    again = Grid.from_dict(grid.to_dict())
    np.testing.assert_array_equal(again.points(), grid.points())
