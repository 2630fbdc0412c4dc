"""Certified vertex fans: the triangles around a passing vertex cannot meet during the step."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import colliding_vertices, grid_sheet
from fracture.refine.fans import certified_fans, closed_vertices
from fracture.mesh.edges import edge_table


def _fan(k=6, turns=1, lift=0.0):
    """Vertex 0 at the origin and a ring of k vertices winding ``turns`` times around it, climbing
    ``lift`` per vertex; triangles (0, i, i + 1) counter-clockwise seen from +z."""
    angle = 2 * np.pi * turns * np.arange(k) / k
    V = np.vstack([[0, 0, 0], np.c_[np.cos(angle), np.sin(angle), lift * np.arange(k)]])
    ring = np.arange(1, k + 1)
    return V, np.c_[np.zeros(k, int), ring, np.roll(ring, -1)]


def _passes(X0, F, X1=None):
    closed = closed_vertices(F, len(X0), edge_table(F, len(X0)))
    return certified_fans(X0, X0 if X1 is None else X1, F, closed)


def test_a_flat_fan_passes_and_only_its_closed_centre_can():
    V, F = _fan()
    ok = _passes(V, F)
    assert ok[0] and not ok[1:].any()  # the ring is on the fan's boundary


def test_a_fan_that_winds_twice_around_its_vertex_fails():
    """A helical fan of 12 triangles spanning 4 pi: every triangle faces +z, and it does not cut
    itself, but its projection covers the plane twice, which the test cannot tell from a fold."""
    V, F = _fan(12, turns=2, lift=0.05)
    normals = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    assert (normals[:-1, 2] > 0).all()
    assert not _passes(V, F)[0]
    V1, F1 = _fan(12, lift=0.05)  # the same helix over one turn passes
    assert _passes(V1, F1)[0]


def test_a_folded_fan_fails():
    V, F = _fan(8)
    V[3, :2] = -0.3 * V[3, :2] + 0.2 * V[4, :2]  # pulled through the centre: two triangles turn over
    assert not _passes(V, F)[0]


def test_fans_on_open_non_manifold_or_inconsistent_edges_fail():
    V, F = _fan()
    assert not _passes(V, F[:-1])[0]  # a gap: the centre is on two boundary edges
    fin = np.vstack([F, [[0, 1, 7]]])  # a third triangle on edge (0, 1)
    assert not _passes(np.vstack([V, [[0.5, 0.0, 1.0]]]), fin)[0]
    turned = F.copy()
    turned[2] = turned[2, ::-1]  # one triangle listed the other way round
    assert not _passes(V, turned)[0]


def test_a_triangle_turning_over_in_mid_step_fails_the_fan():
    """Two ring vertices move so that triangle (0, 1, 2) faces up at both ends of the step and down
    half-way: its normal's z is 1 - 16 t (1 - t)."""
    angle = np.radians([120, 160, 200, 240, 280, 320])
    rest = np.c_[5 * np.cos(angle), 5 * np.sin(angle), np.zeros(6)]
    X0 = np.vstack([[0, 0, 0], [1, 0, 0], [4, 1, 0], rest])
    X1 = np.vstack([[0, 0, 0], [1, 4, 0], [0, 1, 0], rest])
    F = _fan(8)[1]
    mid = 0.5 * (X0 + X1)
    assert np.cross(mid[1], mid[2])[2] < 0 < np.cross(X0[1], X0[2])[2] and np.cross(X1[1], X1[2])[2] > 0
    assert _passes(X0, F)[0] and _passes(X1, F)[0]
    assert not _passes(X0, F, X1)[0]


def _crumpled_sheet(seed, n=10, noise=0.02, move=0.05):
    rng = np.random.default_rng(seed)
    V, F = grid_sheet(n, 0.0)
    V = V + rng.normal(0, noise, V.shape)
    return V, F, V + rng.normal(0, move, V.shape)


def _fan_collides(X0, X1, F, s):
    """Whether any vertex-triangle or edge-edge pair of the triangles around s, sharing no vertex,
    meets during the step (every pair tested)."""
    return colliding_vertices(X0, X1, F[(F == s).any(1)], 1e-12).any()


def test_the_static_test_agrees_with_a_step_that_moves_nothing():
    X0, F, _ = _crumpled_sheet(0, move=0.0)
    X0[:, :2] += np.random.default_rng(1).normal(0, 0.04, (len(X0), 2))  # folds some fans
    static = _passes(X0, F)
    assert 0.2 < static.mean() < 0.5  # of 0.64 closed
    assert np.array_equal(_passes(X0, F, X0.copy()), static)


@pytest.mark.parametrize("move", [0.03, 0.05])
def test_no_fan_that_passes_has_a_colliding_pair(move):
    """Random moves of a crumpled sheet make many fans fold onto themselves; none of the fans that
    pass does, and a good share of the fans pass."""
    passed = folded = 0
    for seed in range(6):
        X0, F, X1 = _crumpled_sheet(seed, move=move)
        ok = _passes(X0, F, X1)
        for s in range(len(X0)):
            hit = _fan_collides(X0, X1, F, s)
            assert not (ok[s] and hit), (seed, s)
            passed += ok[s]
            folded += hit
    assert folded >= 30 and passed >= 150  # of 384 closed vertices


def test_stopping_collisions_with_or_without_the_fans_gives_the_same_step(monkeypatch):
    from fracture.mesh.intersect import self_intersections
    from fracture.refine import collide
    results = []
    for use_fans in (True, False):
        if not use_fans:
            monkeypatch.setattr(collide, "certified_fans", lambda X0, X1, F, closed: np.zeros(len(X0), bool))
        out = []
        for seed in range(4):
            X0, F, X1 = _crumpled_sheet(seed, move=0.03)
            assert self_intersections(X0, F) == 0
            assert _passes(X0, F, X1).sum() > 30 or not use_fans  # of 64 closed vertices
            stopped, pairs = collide.stop_collisions(X0, X1, F, 1e-9)
            out.append((stopped, X1, pairs))
            assert self_intersections(X1, F) == 0
        results.append(out)
    assert sum(r[0].sum() for r in results[0]) > 10  # some vertices were stopped
    for (s1, x1, p1), (s2, x2, p2) in zip(*results):
        assert np.array_equal(s1, s2) and np.array_equal(x1, x2)
