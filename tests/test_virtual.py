import igl
import numpy as np
import pytest
import triangle

from conftest import mesh_area as area

from fracture.mesh import primitives
from fracture.coarse.surface import special_edges
from fracture.errors import InputError
from fracture.coarse.virtual import crack_front, extend_cuts


def cylinder(r=0.5, h=3.0, n=64, m=12):
    return primitives.cylinder(r, h, n, m)


def partial_cut(r=0.5, z=1.5, x_front=0.1, n_arc=24, n_front=6):
    """A flat cut z = const over the part x <= x_front of the disc: an incomplete cut.

    Its arc vertices are projected onto the cylinder (as the pipeline projects
    boundary vertices onto B); the straight edge x = x_front is the crack front.
    """
    t0 = np.arccos(x_front / r)
    arc = np.linspace(t0, 2 * np.pi - t0, n_arc)
    arc_pts = np.stack([r * np.cos(arc), r * np.sin(arc)], 1)
    ys = np.linspace(arc_pts[-1, 1], arc_pts[0, 1], n_front + 1)[1:-1]
    front = np.stack([np.full_like(ys, x_front), ys], 1)
    ring = np.concatenate([arc_pts, front])
    k = len(ring)
    tri = triangle.triangulate({"vertices": ring, "segments": np.stack([np.arange(k), (np.arange(k) + 1) % k], 1)},
                               "pq30a0.01YQ")
    V = np.column_stack([tri["vertices"], np.full(len(tri["vertices"]), z)])
    BV, BF = cylinder(r)
    on_arc = np.abs(np.linalg.norm(V[:, :2], axis=1) - r) < 1e-9
    V[on_arc] = igl.point_mesh_squared_distance(V[on_arc], BV, BF)[2]
    return V, tri["triangles"].astype(np.int64)



def test_partial_cut_is_extended_to_a_complete_cut():
    BV, BF = cylinder()
    V, F = partial_cut()
    assert len(crack_front(V, F, BV, BF)) == 6  # the straight edge x = 0.1
    V2, F2, virtual = extend_cuts(V, F, BV, BF)
    assert virtual.sum() > 0 and not virtual[: len(F)].any()
    np.testing.assert_array_equal(F2[: len(F)], F)
    # nothing ends inside the object any more: every boundary vertex lies on B
    assert len(crack_front(V2, F2, BV, BF)) == 0
    sp = special_edges(F2, len(V2))
    d2, _, _ = igl.point_mesh_squared_distance(V2[sp.boundary_vertices], BV, BF)
    assert np.sqrt(d2).max() < 1e-9
    # the extension stays in the cut's plane and the cut now spans the cross-section,
    # up to the chords between the last tips (spaced like the front's vertices)
    assert np.allclose(V2[:, 2], 1.5)
    cross_section = 0.5 * 64 * 0.25 * np.sin(2 * np.pi / 64)  # area of the 64-gon
    assert area(V2, F2) == pytest.approx(cross_section, rel=0.03)
    assert area(V2, F2) <= cross_section
    # consistent orientation: every interior edge is used once in each direction
    D = F2[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    assert len({tuple(e) for e in D.tolist()}) == len(D)


def test_extended_cut_separates_the_cylinder():
    BV, BF = cylinder()
    V2, F2, _ = extend_cuts(*partial_cut(), BV, BF)
    # points just above and below the cut plane: the winding number of the
    # closed surface "cut + one half of B" tells the sides apart everywhere
    rng = np.random.default_rng(0)
    P = np.column_stack([rng.uniform(-0.35, 0.35, (400, 2)), np.zeros(400)])
    below, above = P + [0, 0, 1.4], P + [0, 0, 1.6]
    lower = BF[(BV[BF].mean(axis=1)[:, 2] < 1.5)]
    # closing the lower half of B with the cut (oriented to face up or down)
    Vc = np.concatenate([BV, V2])
    for Fc in (np.concatenate([lower, F2 + len(BV)]), np.concatenate([lower, F2[:, ::-1] + len(BV)])):
        w_below = igl.winding_number(Vc, Fc, below)
        w_above = igl.winding_number(Vc, Fc, above)
        if abs(w_below).mean() > 0.9:
            break
    assert np.all(np.abs(w_below) > 0.9) and np.all(np.abs(w_above) < 0.1)


def test_complete_cut_is_left_alone_and_bad_front_reported():
    BV, BF = cylinder()
    V, F = partial_cut(x_front=0.49999, n_front=0)
    V2, F2, virtual = extend_cuts(V, F, BV, BF)
    assert not virtual.any() and len(F2) == len(F)
    V, F = partial_cut()
    with pytest.raises(InputError, match="did not reach the exterior"):
        extend_cuts(V, F, BV, BF, step=1e-3, max_steps=5)
