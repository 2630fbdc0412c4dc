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


def _l_prism(divisions=3):
    """An L-shaped prism (a concave edge along z, two concave corners): its L cut into three squares, each a
    box, and their shared faces removed (the boxes' faces on x = 1 or y = 1 between two of the squares)."""
    squares = [(0, 0), (1, 0), (0, 1)]
    V, F = [], []
    for x, y in squares:
        Vb, Fb = box([x, y, 0], [x + 1, y + 1, 1], (divisions, divisions, divisions))
        c = Vb[Fb].mean(axis=1)
        inner = np.zeros(len(Fb), bool)
        for ox, oy in squares:  # a face on the side shared with another square is inside the L
            if (ox, oy) != (x, y):
                on = np.isclose(c[:, 0], max(x, ox)) if ox != x else np.isclose(c[:, 1], max(y, oy))
                inside = (c[:, 1] > min(y, oy)) & (c[:, 1] < min(y, oy) + 1) if ox != x else \
                    (c[:, 0] > min(x, ox)) & (c[:, 0] < min(x, ox) + 1)
                inner |= on & inside
        F.append(Fb[~inner] + sum(len(v) for v in V))
        V.append(Vb)
    from fracture.mesh.topology import weld

    V, F = np.concatenate(V), np.concatenate(F)
    V, remap = weld(V, 1e-9)
    return V, remap[F]


def _inside_l(P):
    return (P[:, 2] > 0) & (P[:, 2] < 1) & (P[:, 0] > 0) & (P[:, 1] > 0) & ((P[:, 0] < 1) & (P[:, 1] < 2) |
                                                                       (P[:, 0] < 2) & (P[:, 1] < 1))


def _inside_pinch(P):
    return np.all((P > 0) & (P < 1), axis=1) | np.all((P > 1) & (P < 2), axis=1)


def _pinch():
    """Two cubes that share one corner, (1, 1, 1): a closed oriented surface whose corner there is a pinch."""
    V0, F0 = box([0, 0, 0], [1, 1, 1], (2, 2, 2))
    V1, F1 = box([1, 1, 1], [2, 2, 2], (2, 2, 2))
    V, F = np.concatenate([V0, V1]), np.concatenate([F0, F1 + len(V0)])
    from fracture.mesh.topology import weld

    V, remap = weld(V, 1e-9)
    return V, remap[F]


def _spike():
    """A tall thin tetrahedron: its edges and corners are sharp (normals more than a right angle apart), where
    one triangle's normal tells the side of a point beyond its edge wrongly."""
    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.6, 0.0], [0.2, 0.2, 3.0]])
    return V, np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])


def _inside_spike(P):
    V = _spike()[0]
    w = np.linalg.solve((V[1:] - V[0]).T, (P - V[0]).T).T  # barycentric weights of corners 1, 2, 3
    return (w > 0).all(axis=1) & (w.sum(axis=1) < 1)


@pytest.mark.parametrize("shape", ["box", "l", "hollow", "pinch", "spike"])
def test_the_side_of_b_from_closest_points_is_the_winding_numbers(shape):
    """Pseudonormals (of the closest point's triangle, edge or corner) tell inside from outside as the winding
    numbers do, on convex and concave edges and corners, a cavity, and a pinch (where a corner's normal does
    not tell, and the winding number is asked); close to B and far from it."""
    from fracture.mesh.topology import closed_oriented

    V, F = {"box": lambda: box([0, 0, 0], [1, 2, 3], (2, 3, 4)), "l": _l_prism,
            "hollow": lambda: _hollow_box((3, 3, 3)), "pinch": _pinch, "spike": _spike}[shape]()
    assert closed_oriented(F)
    B = Exterior(V, F)
    rng = np.random.default_rng(3)
    lo, hi = V.min(axis=0) - 0.5, V.max(axis=0) + 0.5
    far = lo + rng.random((4000, 3)) * (hi - lo)
    # near B: around its corners (the closest point at a corner or on an edge) and its faces
    corners = V[rng.integers(0, len(V), 3000)] + rng.normal(0, 0.05, (3000, 3))
    t = rng.integers(0, len(F), 3000)
    faces = V[F[t]].mean(axis=1) + rng.normal(0, 0.02, (3000, 3))
    t, u = rng.integers(0, len(F), 3000), rng.random((3000, 1))  # around the edges
    edges = V[F[t, 0]] * u + V[F[t, 1]] * (1 - u) + rng.normal(0, 0.05, (3000, 3))
    P = np.concatenate([far, corners, faces, edges])
    d2, tri, C = B.closest(P)
    away = d2 > 1e-12
    got = B.inside_near(P, tri, C)
    assert np.array_equal(got[away], B.inside(P)[away])
    if shape in ("l", "pinch", "spike"):
        truth = {"l": _inside_l, "pinch": _inside_pinch, "spike": _inside_spike}[shape](P)
        assert np.array_equal(got[away], truth[away])


def test_the_side_of_b_needs_no_winding_numbers_on_a_closed_b_and_takes_them_on_an_open_one():
    V, F = _l_prism()
    B = Exterior(V, F)
    inside, _ = B.grid_nodes(np.array([-0.35, -0.35, -0.35]), np.full(3, 0.1), (29, 29, 18), 0.01)
    assert "_wn" not in vars(B)  # the dearest query near B, never built
    assert inside.sum() > 0 and not inside.all()
    # a B with a hole is answered by winding numbers (its pseudonormals would not tell)
    P = np.random.default_rng(4).random((500, 3)) * 2.0
    opened = Exterior(V, F[1:])
    d2, tri, C = opened.closest(P)
    assert np.array_equal(opened.inside_near(P, tri, C), opened.inside(P))
