import numpy as np
import pytest

from fields.colormap import colorbar, colormap
from fields.grid import Grid
from fields.slices import axis_slice, slice_image


def _field():
    grid = Grid.from_bounds([0, 0, 0], [1, 2, 3], (5, 6, 7))
    values = grid.points() @ np.array([1.0, 10.0, 100.0])
    return grid, values.reshape(grid.shape)


def test_slice_ends_are_the_boundary_planes():
    grid, values = _field()
    for axis in range(3):
        lo, info = axis_slice(grid, values, axis, 0.0)
        hi, _ = axis_slice(grid, values, "xyz"[axis], 1.0)
        np.testing.assert_allclose(lo, np.take(values, 0, axis=axis))
        np.testing.assert_allclose(hi, np.take(values, -1, axis=axis))
        assert info["position"] == pytest.approx(grid.lo[axis])


def test_slice_interpolates_between_planes():
    grid, values = _field()
    plane, info = axis_slice(grid, values, "z", 0.3)
    z = info["position"]
    assert z == pytest.approx(0.3 * 3.0)
    Y, X = np.meshgrid(grid.axes()[1], grid.axes()[0])
    np.testing.assert_allclose(plane, X + 10 * Y + 100 * z, atol=1e-9)
    assert info["extent"] == [[0.0, 1.0], [0.0, 2.0]]


def test_slice_image_has_v_up_and_colormap_ends():
    grid, values = _field()
    plane, _ = axis_slice(grid, values, "x", 0.5)  # u = y, v = z
    img = slice_image(plane, "viridis", scale=3)
    assert img.shape == (7 * 3, 6 * 3, 3) and img.dtype == np.uint8
    # Highest values (largest y and z) at the top right, lowest at the bottom left.
    np.testing.assert_array_equal(img[0, -1], (colormap(np.array(1.0), "viridis", 0, 1) * 255).round())
    np.testing.assert_array_equal(img[-1, 0], (colormap(np.array(0.0), "viridis", 0, 1) * 255).round())


def test_colormap_and_colorbar():
    rgb = colormap(np.linspace(0, 1, 11), "coolwarm")
    assert rgb.shape == (11, 3) and rgb.min() >= 0 and rgb.max() <= 1
    assert rgb[0, 2] > rgb[0, 0] and rgb[-1, 0] > rgb[-1, 2]  # cool to warm
    lum = colormap(np.linspace(0, 1, 50), "viridis") @ np.array([0.2126, 0.7152, 0.0722])
    assert np.all(np.diff(lum) > 0)  # viridis brightens monotonically
    bar = colorbar("magma", 64, 8)
    assert bar.shape == (64, 8, 3)
    with pytest.raises(ValueError, match="unknown colour map"):
        colormap(np.zeros(3), "jet")
    with pytest.raises(ValueError, match="offset"):
        axis_slice(*_field(), "x", 1.5)
    with pytest.raises(ValueError, match="axis"):
        axis_slice(*_field(), "w", 0.5)
