"""Queries against the exterior surface B (fracture.mesh.exterior)."""

import numpy as np
import pytest

from fracture.mesh.exterior import Exterior
from fracture.mesh.primitives import box


def test_closest_points_distances_and_inside_on_a_box():
    V, F = box([0, 0, 0], [1, 2, 3], (2, 3, 4))
    B = Exterior(V, F)
    P = np.array([[2.0, 1.0, 1.5], [0.5, -1.0, 1.0], [0.25, 1.0, 1.5], [1.5, 2.5, 3.5]])
    d2, tri, C = B.closest(P)
    np.testing.assert_allclose(C, [[1.0, 1.0, 1.5], [0.5, 0.0, 1.0], [0.0, 1.0, 1.5], [1.0, 2.0, 3.0]], atol=1e-12)
    np.testing.assert_allclose(d2, [1.0, 1.0, 0.0625, 0.75], atol=1e-12)
    np.testing.assert_allclose(B.distance(P), np.sqrt([1.0, 1.0, 0.0625, 0.75]), atol=1e-12)
    # the triangle found holds the closest point, and its normal points out there
    for c, t, n in zip(C[:2], tri[:2], [[1, 0, 0], [0, -1, 0]]):
        a, b, e = V[F[t]]
        assert abs(np.dot(np.cross(b - a, e - a), c - a)) < 1e-12
        np.testing.assert_allclose(B.normals[t], n, atol=1e-12)
    assert B.inside(P).tolist() == [False, False, True, False]


def test_each_tree_is_built_by_its_first_query_only():
    V, F = box([0, 0, 0], [1, 1, 1])
    B = Exterior(V, F)
    assert "_tree" not in vars(B) and "_wn" not in vars(B)  # nothing built yet
    B.closest(np.zeros((1, 3)))
    assert "_tree" in vars(B) and "_wn" not in vars(B)  # closest points need no winding numbers
    B.inside(np.zeros((1, 3)))
    assert "_wn" in vars(B)


def test_a_segment_meets_the_box_where_it_leaves_it():
    B = Exterior(*box([0, 0, 0], [1, 1, 1]))
    inner = np.array([[0.5, 0.5, 0.5], [0.2, 0.3, 0.4], [0.5, 0.5, 0.5]])
    outer = np.array([[1.5, 0.5, 0.5], [0.2, 0.3, -0.6], [0.6, 0.5, 0.5]])  # the last stays inside
    t = B.crossing(inner, outer)
    np.testing.assert_allclose(t[:2], [0.5, 0.4], atol=1e-12)
    assert np.isnan(t[2])


def _hollow_box(resolution):
    """A box with a box-shaped cavity (the inner box's triangles turned inward), and a second box apart."""
    Vo, Fo = box([0, 0, 0], [2, 2, 2], resolution)
    Vi, Fi = box([0.6, 0.6, 0.6], [1.4, 1.4, 1.4], resolution)
    Va, Fa = box([2.7, 0.3, 0.3], [3.3, 0.9, 3.1], resolution)
    V = np.concatenate([Vo, Vi, Va])
    F = np.concatenate([Fo, Fi[:, ::-1] + len(Vo), Fa + len(Vo) + len(Vi)])
    return V, F


def test_grid_nodes_answer_as_asking_every_node():
    # B's triangles finer and coarser than the cells; nodes on B, in the cavity, in the box apart, outside
    for resolution in ((1, 1, 1), (12, 12, 12)):
        B = Exterior(*_hollow_box(resolution))
        origin, spacing, shape = np.array([-0.4, -0.4, -0.4]), np.array([0.1, 0.1, 0.2]), (42, 20, 18)
        idx = np.stack(np.unravel_index(np.arange(int(np.prod(shape))), shape), 1)
        P = origin + idx * spacing
        within = 0.02
        inside, on_b = B.grid_nodes(origin, spacing, shape, within)
        assert inside.ravel().tolist() == B.inside(P).tolist()
        assert on_b.ravel().tolist() == (B.closest(P)[0] < within * within).tolist()
        assert on_b.any() and inside.any() and not inside.all()
        # only the asked nodes are answered
        asked = np.random.default_rng(1).random(shape) < 0.3
        inside_a, on_b_a = B.grid_nodes(origin, spacing, shape, within, asked=asked)
        assert (inside_a == (inside & asked)).all() and (on_b_a == (on_b & asked)).all()


@pytest.mark.parametrize("offset", [0.0, 1e4, 1e6])
def test_winding_numbers_far_from_the_origin_tell_inside_from_outside(offset):
    """libigl's fast winding number holds single-precision coordinates: about the origin, a cube 1e6 away took
    points outside for inside; taken about the cube's centre it is exact to its own size."""
    from fracture.mesh.exterior import fast_winding
    from fracture.mesh.primitives import box

    V, F = box(np.zeros(3), np.ones(3))
    P = np.random.default_rng(0).random((4000, 3)) * 1.2 - 0.1
    inside = np.all((P > 0) & (P < 1), axis=1)
    away = np.array([offset, -0.5 * offset, 0.0])
    clear = np.all(np.abs(P - 0.5) < 0.499, axis=1) | np.any(np.abs(P - 0.5) > 0.501, axis=1)
    assert np.array_equal((fast_winding(V + away, F, P + away) > 0.5)[clear], inside[clear])
    assert np.array_equal(Exterior(V + away, F).inside(P + away)[clear], inside[clear])


def test_no_triangles_wind_about_no_point_and_an_empty_piece_is_checked_without_crashing():
    """A piece left without faces (random cut case 99 once) is measured, not a crash: libigl's fast winding
    number read memory it never wrote for no triangles (garbage, or a crash), its manifold test failed."""
    from fracture.mesh.exterior import fast_winding
    from fracture.pieces.assembly import mesh_checks

    V, P = np.random.default_rng(1).random((10, 3)), np.random.default_rng(2).random((3000, 3))
    none = np.zeros((0, 3), np.int64)
    for _ in range(5):
        assert np.array_equal(fast_winding(V, none, P), np.zeros(3000))
        assert np.array_equal(fast_winding(np.zeros((0, 3)), none, P), np.zeros(3000))
    checks = mesh_checks(V, none)
    assert checks["volume"] == 0.0 and checks["triangles"] == 0 and checks["self_intersections"] == 0
