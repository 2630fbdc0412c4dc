import numpy as np
import pytest

from fields.build import build_fields
from fields.stress import distance_to_surface, modified_strength, stress_from_distance
from fracture.mesh.primitives import box, sheet


def _segment_distance(P, A, B):
    AB = B - A
    t = np.clip(((P[:, None] - A) * AB).sum(-1) / (AB * AB).sum(-1), 0, 1)
    return np.linalg.norm(P[:, None] - (A + t[..., None] * AB), axis=-1)


def brute_force_distance(P, V, F):
    """Distance to every triangle (plane if the projection is inside, else the edges); minimum."""
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(B - A, C - A)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    h = ((P[:, None] - A) * n).sum(-1)
    Q = P[:, None] - h[..., None] * n
    inside = np.ones(h.shape, bool)
    for X, Y in ((A, B), (B, C), (C, A)):
        inside &= (np.cross(Y - X, Q - X) * n).sum(-1) >= 0
    edges = np.minimum.reduce([_segment_distance(P, A, B), _segment_distance(P, B, C), _segment_distance(P, C, A)])
    return np.where(inside, np.abs(h), edges).min(axis=1)


def test_distance_matches_brute_force_on_a_small_mesh():
    V, F = sheet(lambda u, v: np.stack([u, v, 0.3 * np.sin(3 * u) * v], 1), (0, 1), (0, 1), 4, 3)
    F = np.concatenate([F, F[:2, ::-1] + 0])  # a non-manifold duplicate does not matter
    P = np.random.default_rng(0).uniform(-0.5, 1.5, (3000, 3))
    np.testing.assert_allclose(distance_to_surface(P, V, F), brute_force_distance(P, V, F), atol=1e-10)


def test_stress_is_one_on_the_surface_and_decays():
    d = np.array([0.0, 0.05, 0.1, 0.3])
    xi = stress_from_distance(d, 0.1)
    assert xi[0] == 1.0 and np.all(np.diff(xi) < 0)
    assert xi[2] == pytest.approx(np.exp(-1.0))


def test_psi_is_monotone_in_the_stress_weight():
    rng = np.random.default_rng(1)
    zeta, xi = rng.uniform(0, 1, 1000), rng.uniform(0, 1, 1000)
    previous = modified_strength(zeta, xi, 1.0, 0.0)
    np.testing.assert_array_equal(previous, zeta)
    for w in (0.5, 1.0, 2.0, 4.0):
        psi = modified_strength(zeta, xi, 1.0, w)
        assert np.all(psi <= previous)
        previous = psi


def test_stronger_stress_weight_keeps_the_minimum_closer_to_the_coarse_surface():
    # A flat coarse cut at x = 1 and a weak sheet at x = 1.25: the minimum of psi along x
    # moves from the weak sheet toward the cut as the stress weight grows.
    V, F = box([0, 0, 0], [2, 1, 1], (4, 2, 2))
    SV, SF = sheet(lambda u, v: np.stack([np.full_like(u, 1.0), u, v], 1), (0, 1), (0, 1), 2, 2)
    weak = {"kind": "radial", "weight": -1.0, "axis": "y", "center": [0.625, 0.0, 0.25], "radius": 0.05,
            "inner": 1.0, "outer": 0.0, "exponent": 1.0}  # -(1 - r/R): a valley along the line x = 1.25, z = 0.5
    minima = []
    for w in (0.2, 1.0, 3.0, 10.0):
        fs = build_fields(V, SV, SF, resolution=[81, 5, 41], padding=0.0, layers=[weak], seed=0,
                          stress_length=0.2, stress_weight=w, levels=1)
        line = fs.psi[:, 2, 20]
        minima.append(fs.grid.axes()[0][np.argmin(line)])
    assert minima[0] == pytest.approx(1.25, abs=0.03)
    assert all(b <= a for a, b in zip(minima, minima[1:]))
    assert minima[-1] == pytest.approx(1.0, abs=0.03)
