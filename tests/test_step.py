"""The step control: backward Euler on the area term of Eq. 3, the move limits and the step size."""

from __future__ import annotations

import igl
import numpy as np
import pytest
from test_flow import bumpy_sheet, icosphere

from fracture.refine.flow import energy_gradient, velocity
from fracture.refine.step import (ImplicitStep, StepSize, cotangent_weights, implicit_step, limit_moves,
                                  weighted_cotangent_laplacian)


def test_weighted_laplacian_is_the_area_term_of_eq_3():
    """(L_w x)_i = -sum_j w_j dA_j/dx_i: with grad psi = 0 and per-triangle weights equal to the mean psi
    of the corners, the explicit flow is L_w x / A."""
    V, F = bumpy_sheet()
    psi = 0.5 + np.random.default_rng(0).random(len(V))
    dE, area = energy_gradient(V, F, psi, np.zeros((len(V), 3)))
    L = weighted_cotangent_laplacian(V, F, psi[F].mean(axis=1))
    assert np.allclose(L @ V, -dE, atol=1e-12)
    # psi = 1: libigl's cotangent Laplacian
    assert np.allclose(weighted_cotangent_laplacian(V, F, np.ones(len(F))).toarray(), igl.cotmatrix(V, F).toarray())


def test_non_manifold_edges_add_every_triangle():
    """Three triangles on one edge: each adds its cotangent to the edge's weight."""
    V = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0], [0.5, 0, 1]], float)
    F = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    L = weighted_cotangent_laplacian(V, F, np.array([1.0, 2.0, 3.0])).toarray()
    cot = 0.75  # every apex sits 1 above the edge's midpoint, its halves 0.5 long: cot(2 atan 0.5) = 0.75
    assert L[0, 1] == pytest.approx(0.5 * cot * (1 + 2 + 3))
    assert np.allclose(L.sum(axis=1), 0.0)


@pytest.mark.parametrize("mesh", [icosphere, bumpy_sheet], ids=["closed", "open"])
def test_implicit_step_agrees_with_the_explicit_one_for_small_steps(mesh):
    V, F = mesh()
    rng = np.random.default_rng(1)
    psi = 0.5 + rng.random(len(V))
    grad = rng.standard_normal((len(V), 3))
    dE, area = energy_gradient(V, F, psi, grad)
    v = -dE / area[:, None]
    w = psi[F].mean(axis=1)
    errors = []
    h2 = igl.avg_edge_length(V, F) ** 2  # the explicit step's stability limit scales with it
    for tau in (1e-2 * h2, 1e-3 * h2):
        d = implicit_step(cotangent_weights(V, F, w), area, v, tau)
        errors.append(np.abs(d - tau * v).max() / np.abs(tau * v).max())
    assert errors[1] < 1e-2
    assert errors[1] < 0.2 * errors[0]  # first order: the difference shrinks like tau


def test_implicit_step_is_stable_where_the_explicit_one_explodes():
    """Mean-curvature flow of a sphere with a step 100 times the explicit limit: the implicit step
    shrinks the sphere a little and keeps it round; the explicit one throws vertices far out."""
    V, F = icosphere(3)
    psi = np.ones(len(V))
    dE, area = energy_gradient(V, F, psi, np.zeros((len(V), 3)))
    v = -dE / area[:, None]
    h = igl.avg_edge_length(V, F)
    tau = 100 * h * h
    d = implicit_step(cotangent_weights(V, F, np.ones(len(F))), area, v, tau)
    r = np.linalg.norm(V + d, axis=1)
    assert r.max() < 1.0 and r.std() < 0.02 * r.mean()
    r_explicit = np.linalg.norm(V + tau * v, axis=1)
    assert r_explicit.max() > 1.5


def test_implicit_step_has_the_fixed_points_of_the_flow():
    """A plane under a linear psi with an in-plane gradient: Eq. 3 vanishes, so does the step."""
    from fracture.mesh.primitives import sheet
    V, F = sheet(lambda u, v: np.stack([u, v, np.zeros_like(u)], 1), (0, 1), (0, 1), 7, 7)
    g = np.array([0.7, -1.3, 0.0])
    psi = 2.0 + V @ g
    inner = (V[:, 0] > 0) & (V[:, 0] < 1) & (V[:, 1] > 0) & (V[:, 1] < 1)
    v = velocity(V, F, psi, np.tile(g, (len(V), 1)))
    v[~inner] = 0.0  # the sheet's rim is held (the engine's boundary constraint)
    _, area = energy_gradient(V, F, psi, np.tile(g, (len(V), 1)))
    d = implicit_step(cotangent_weights(V, F, psi[F].mean(axis=1)), area, v, 10.0)
    assert np.abs(d).max() < 1e-10


def test_the_implicit_system_is_solved_exactly_on_a_non_manifold_surface():
    """The system written straight into the factorisation's form (upper triangle by columns) is the
    matrix M - tau L_w: the displacement solves it, on a surface with three triangles on an edge."""
    V, F = bumpy_sheet()
    fin = np.array([[0, 1, len(V)]])  # a third triangle on the sheet's first edge
    V = np.vstack([V, V[[0, 1]].mean(axis=0) + [0.0, 0.0, 0.3]])
    F = np.vstack([F, fin])
    rng = np.random.default_rng(7)
    w = 0.5 + rng.random(len(F))
    area = 0.1 + rng.random(len(V))
    v = rng.standard_normal((len(V), 3))
    tau = 3.0
    d = implicit_step(cotangent_weights(V, F, w), area, v, tau)
    K = np.diag(area) - tau * weighted_cotangent_laplacian(V, F, w).toarray()
    assert np.allclose(K @ d, tau * area[:, None] * v, atol=1e-10)
    assert np.allclose(d, np.linalg.solve(K, tau * area[:, None] * v), atol=1e-10)


def test_a_retried_step_reuses_the_factorisation_and_solves_the_new_system():
    """A step tried again with tau halved (the engine's retry) keeps the order and symbolic analysis
    and gives what a fresh factorisation gives; a matrix of another pattern is factorised again."""
    V, F = icosphere(3)
    rng = np.random.default_rng(4)
    psi = 0.5 + rng.random(len(V))
    dE, area = energy_gradient(V, F, psi, rng.standard_normal((len(V), 3)))
    v = -dE / area[:, None]
    L = cotangent_weights(V, F, psi[F].mean(axis=1))
    tau = 50 * igl.avg_edge_length(V, F) ** 2
    solve = ImplicitStep()
    solve(L, area, v, tau)
    for t in (tau / 2, tau / 4, tau * 0.37):
        d = solve(L, area, v, t)
        exact = implicit_step(L, area, v, t)
        assert np.abs(d - exact).max() < 1e-10 * np.abs(exact).max()
    assert (solve.factorisations, solve.reuses) == (1, 3)
    V2, F2 = icosphere(2)
    _, area2 = energy_gradient(V2, F2, np.ones(len(V2)), np.zeros((len(V2), 3)))
    solve(cotangent_weights(V2, F2, np.ones(len(F2))), area2, np.zeros((len(V2), 3)), tau)
    assert solve.factorisations == 2


def test_limit_moves_caps_length_and_relative_motion():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    F = np.array([[0, 1, 2]])
    d = np.array([[0, 0, 3.0], [0, 0, 3.0], [0, 0, 3.0]])  # a rigid move: only the cap applies
    limit_moves(V, F, d, 0.5, 1.0)
    assert np.allclose(d[:, 2], 1.0)
    d = np.array([[0.9, 0, 0], [0, 0, 0], [0, 0, 0]])  # vertex 0 onto vertex 1: the fold limit
    assert limit_moves(V, F, d, 0.5, 10.0) == 3  # every vertex of a limited edge (the others stand still)
    altitude = 1.0 / np.sqrt(2.0)  # twice the area over the longest edge
    assert np.allclose(d[0], [0.5 * altitude, 0, 0])


def test_step_size_grows_shrinks_and_has_a_floor():
    s = StepSize(0.5, h=0.1)
    assert s.begin(2.0) == pytest.approx(0.025)
    for _ in range(20):
        s.accepted()
    assert s.tau == pytest.approx(4 * 0.025)
    for _ in range(20):
        s.rejected()
    assert s.at_least and s.tau == pytest.approx(0.025 / 64)
