import numpy as np
import pytest

from fields.grid import Grid
from fields.pyramid import StrengthPyramid, gaussian_level, level_sigmas


def _grid(shape=(24, 16, 12)):
    return Grid.from_bounds([0.0, 0.0, 0.0], [1.2, 0.75, 0.55], shape)


def test_gradient_of_a_linear_field_is_exact_on_every_level():
    grid = _grid()
    a = np.array([1.5, -0.5, 3.0])
    psi = (grid.points() @ a + 2.0).reshape(grid.shape)
    pyr = StrengthPyramid(grid, psi, levels=5, sigma=1.5)
    P = np.random.default_rng(0).uniform(grid.lo, grid.hi, (2000, 3))
    for k in range(pyr.n_levels):
        # Odd reflection keeps linear fields linear up to the grid boundary.
        np.testing.assert_allclose(pyr.level_gradient(k, P), np.broadcast_to(a, P.shape), atol=1e-9)
    value, grad = pyr.value_and_gradient(P)
    np.testing.assert_allclose(grad, np.broadcast_to(a, P.shape), atol=1e-9)
    np.testing.assert_allclose(value, P @ a + 2.0, atol=1e-12)


def test_mean_gradient_equals_average_of_level_gradients():
    grid = _grid()
    psi = np.random.default_rng(1).normal(size=grid.shape)
    pyr = StrengthPyramid(grid, psi, levels=4, sigma=1.0)
    P = np.random.default_rng(2).uniform(grid.lo, grid.hi, (500, 3))
    average = np.mean([pyr.level_gradient(k, P) for k in range(4)], axis=0)
    np.testing.assert_allclose(pyr.gradient(P), average, atol=1e-10)


def test_a_window_of_levels_is_their_mean_and_its_gradient_the_mean_of_theirs():
    grid = _grid()
    psi = np.random.default_rng(3).normal(size=grid.shape)
    pyr = StrengthPyramid(grid, psi, levels=5, sigma=1.0)
    P = np.random.default_rng(4).uniform(grid.lo, grid.hi, (300, 3))
    for first, count in [(3, 2), (0, 2), (1, 3), (4, 2), (0, 5)]:
        used = range(first, min(first + count, 5))
        value, psibar, grad = pyr.coarse_field(first, P, count)
        np.testing.assert_allclose(value, pyr.value(P), atol=1e-12)
        np.testing.assert_allclose(psibar, np.mean([pyr.level_value(k, P) for k in used], axis=0), atol=1e-10)
        np.testing.assert_allclose(grad, np.mean([pyr.level_gradient(k, P) for k in used], axis=0), atol=1e-10)
        lowest, span = pyr.window_range(first, count)
        table = np.mean(pyr.levels[first:first + count], axis=0)
        assert lowest == pytest.approx(table.min()) and span == pytest.approx(np.ptp(table))
        # the compiled table: NumPy's differences, bit for bit
        want = np.stack(np.gradient(table, *grid.spacing, edge_order=1), axis=3)
        np.testing.assert_array_equal(pyr.coarse_table(first, count)[..., 2:], want)
        np.testing.assert_array_equal(pyr.coarse_table(first, count)[..., 1], table)
    np.testing.assert_allclose(pyr.coarse_field(0, P)[2], pyr.gradient(P), atol=1e-10)  # every level: the paper's
    with pytest.raises(ValueError):
        pyr.coarse_table(5, 1)
    with pytest.raises(ValueError):
        pyr.coarse_table(0, 0)


def test_level_zero_is_the_field_and_levels_get_smoother():
    grid = _grid((32, 32, 32))
    psi = np.random.default_rng(3).normal(size=grid.shape)
    pyr = StrengthPyramid(grid, psi, levels=5, sigma=1.0)
    np.testing.assert_array_equal(pyr.levels[0], psi)
    roughness = [np.abs(np.diff(level, axis=0)).mean() for level in pyr.levels]
    assert all(b < 0.75 * a for a, b in zip(roughness, roughness[1:])), roughness


def test_gaussian_level_attenuates_a_sinusoid_as_predicted():
    # A Gaussian of width s multiplies a sinusoid of angular frequency w by exp(-s^2 w^2 / 2).
    n = 128
    grid = Grid.from_bounds([0, 0, 0], [1, 1, 1], (n, 8, 8))
    x = grid.axes()[0]
    w = 2 * np.pi * 6
    psi = np.broadcast_to(np.sin(w * x)[:, None, None], grid.shape).copy()
    for k, s in enumerate(level_sigmas(grid, 4, 1.0)):
        smooth = gaussian_level(psi, s)[:, 4, 4]
        sigma_world = s[0] * grid.spacing[0]
        expected = np.exp(-0.5 * (sigma_world * w) ** 2) * np.sin(w * x)
        inner = slice(n // 4, 3 * n // 4)
        np.testing.assert_allclose(smooth[inner], expected[inner], atol=2e-3, err_msg=f"level {k}")


def test_level_sigmas_are_isotropic_in_material_space():
    grid = Grid.from_bounds([0, 0, 0], [3.0, 1.0, 0.2], (150, 50, 10))
    s = level_sigmas(grid, 5, 1.0)
    world = s * grid.spacing
    assert np.all(world[0] == 0)
    np.testing.assert_allclose(world[1:, 0], world[1:, 1])
    np.testing.assert_allclose(world[1:, 0], world[1:, 2])
    np.testing.assert_allclose(world[2:, 0] / world[1:-1, 0], 2.0)


def test_finite_difference_gradient_converges_quadratically():
    errors = []
    for n in (9, 17, 33, 65):
        grid = Grid.from_bounds([0, 0, 0], [1, 1, 1], (n, n, n))
        X = grid.points()
        psi = (np.sin(2 * X[:, 0]) * np.cos(X[:, 1]) + X[:, 2] ** 2).reshape(grid.shape)
        pyr = StrengthPyramid(grid, psi, levels=1)
        P = np.random.default_rng(4).uniform(0.25, 0.75, (400, 3))
        exact = np.stack([2 * np.cos(2 * P[:, 0]) * np.cos(P[:, 1]), -np.sin(2 * P[:, 0]) * np.sin(P[:, 1]), 2 * P[:, 2]], 1)
        errors.append(np.abs(pyr.gradient(P) - exact).max())
    rates = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(rates > 1.7), (errors, rates)


def test_pyramid_rejects_bad_input():
    grid = _grid()
    with pytest.raises(ValueError, match="shape"):
        StrengthPyramid(grid, np.zeros((3, 3, 3)))
    bad = np.zeros(grid.shape)
    bad[1, 2, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        StrengthPyramid(grid, bad)


def test_the_pyramid_of_a_weighted_sum_is_the_weighted_sum_of_pyramids():
    """psi = a zeta - b xi: its pyramid combined from those of zeta and xi (a new weighting needs no smoothing)
    agrees with the pyramid of psi built directly, levels, table and every window."""
    rng = np.random.default_rng(3)
    grid = Grid.from_bounds([0, 0, 0], [1.0, 0.6, 0.4], (21, 13, 9))
    zeta, xi = rng.random(grid.shape), rng.random(grid.shape)
    a, b = 0.8, 1.7
    direct = StrengthPyramid(grid, a * zeta - b * xi, levels=4, sigma=1.0)
    combined = StrengthPyramid.combine([(a, StrengthPyramid(grid, zeta, levels=4, sigma=1.0)),
                                        (-b, StrengthPyramid(grid, xi, levels=4, sigma=1.0))])
    np.testing.assert_array_equal(combined.levels[0], a * zeta - b * xi)
    np.testing.assert_allclose(combined.levels, direct.levels, rtol=0, atol=1e-12)
    P = rng.uniform([0, 0, 0], [1.0, 0.6, 0.4], (200, 3))
    for first in range(4):
        for got, want in zip(combined.coarse_field(first, P, 2), direct.coarse_field(first, P, 2)):
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-10)
    other = StrengthPyramid(Grid.from_bounds([0, 0, 0], [1, 1, 1], (5, 5, 5)), np.zeros((5, 5, 5)), levels=4)
    with pytest.raises(ValueError, match="cannot be combined"):
        StrengthPyramid.combine([(1.0, direct), (1.0, other)])
