import igl
import numpy as np
import pytest

from fracture.mesh.primitives import box
from fracture.mesh.topology import (corner_groups, directed_edge_face, directed_edges, fan, orient_sheets, signed_volume,
                                    unique_edges, winding_numbers)


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


def test_the_volume_of_a_box_far_from_the_origin_keeps_its_digits():
    V, F = box([0, 0, 0], [1, 1, 1], (3, 3, 3))
    for offset in (0.0, 1e4, 1e7):
        assert signed_volume(V + offset, F) == pytest.approx(1.0, rel=1e-9)
        assert signed_volume(V + offset, F[:, ::-1]) == pytest.approx(-1.0, rel=1e-9)


def test_a_polygon_with_a_corner_on_a_straight_edge_is_fanned_without_a_flat_triangle():
    """An exporter's pentagon whose fifth corner lies on the edge from its first to its fourth: fanned from the
    first corner one triangle has no area; fanned from where none is flat, the pentagon's area is kept."""
    V = np.array([[0, 0, 0], [0, 1, 0], [1, 1, 0], [1, 0, 0], [0.5, 0, 0]], float)
    pentagon = np.array([0, 1, 2, 3, 4])
    T = fan([pentagon])[0]
    area = lambda T: 0.5 * np.linalg.norm(np.cross(V[T[:, 1]] - V[T[:, 0]], V[T[:, 2]] - V[T[:, 0]]), axis=1)  # noqa: E731
    assert area(T).min() == 0.0  # the plain fan
    T, owner = fan([np.array([0, 1, 2]), pentagon], V)
    assert np.array_equal(T[0], [0, 1, 2]) and np.array_equal(owner, [0, 1, 1, 1])
    assert area(T[1:]).min() > 0.1 and area(T[1:]).sum() == pytest.approx(1.0)
    assert sorted(map(sorted, T[1:].tolist())) != sorted(map(sorted, fan([pentagon])[0].tolist()))


def test_orient_sheets_makes_each_sheet_agree_and_leaves_junctions_alone():
    rng = np.random.default_rng(3)
    # three sheets meeting at the line x = y = 0 (a Y junction), each a 4 x 4 grid
    from fracture.mesh.primitives import grid_faces

    sheets = []
    for k, angle in enumerate((0.0, 2.1, 4.2)):
        u, z = np.meshgrid(np.linspace(0, 1, 5), np.linspace(0, 1, 5), indexing="ij")
        V = np.stack([u.ravel() * np.cos(angle), u.ravel() * np.sin(angle), z.ravel()], 1)
        sheets.append((V, grid_faces(5, 5)))
    V = np.concatenate([s[0] for s in sheets])
    F = np.concatenate([s[1] + 25 * k for k, s in enumerate(sheets)])
    _, V_index = np.unique(V.round(12), axis=0, return_inverse=True)  # the junction line is shared
    F = V_index.ravel()[F]
    F[1::2] = F[1::2, ::-1]  # mixed orientations
    turn = rng.random(len(F)) < 0.5
    F[turn] = F[turn, ::-1]
    G, turned, conflict = orient_sheets(F)
    assert conflict is None and 0 < turned < len(F)
    edges, count = unique_edges(G)
    manifold = count == 2
    # across every two-triangle edge the triangles run it in opposite directions
    D = np.sort(directed_edges(G), axis=1)
    key = D[:, 0] * (G.max() + 1) + D[:, 1]
    for e in edges[manifold]:
        rows = np.flatnonzero(key == e[0] * (G.max() + 1) + e[1])
        a, b = directed_edges(G)[rows]
        assert a[0] == b[1] and a[1] == b[0]
    assert (count == 3).sum() == 4  # the junction's edges keep three triangles
    assert np.array_equal(orient_sheets(G)[0], G) and orient_sheets(G)[1] == 0


def test_orient_sheets_reports_a_moebius_strip():
    n = 12
    # vertices i (top) and n + i (bottom); after a half turn the strip joins top to bottom
    F = []
    for i in range(n - 1):
        F += [[i, n + i, i + 1], [i + 1, n + i, n + i + 1]]
    F += [[n - 1, 2 * n - 1, n], [n, 2 * n - 1, 0]]  # the twist
    _, _, conflict = orient_sheets(np.array(F))
    assert conflict is not None


def test_closed_oriented_asks_every_edge_once_each_way():
    from fracture.mesh.topology import closed_oriented

    tet = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    assert closed_oriented(tet)
    assert not closed_oriented(tet[:3])  # a hole
    assert not closed_oriented(np.r_[tet[:3], tet[3:, ::-1]])  # a face turned
    assert not closed_oriented(np.r_[tet, tet[:1]])  # a face twice
    assert closed_oriented(np.zeros((0, 3), np.int64))


def test_nearly_coplanar_triangles_side_by_side_do_not_cross():
    """Two triangles a hundred-billionth of their size off one plane, side by side: an edge whose one end
    lies within the tolerance of the other's plane touches it there, not on its extension."""
    from fracture.mesh.intersect import self_intersections

    T1 = [[0.49947789920479796, 0.3094645672319407, 0.26985823162203876],
          [0.4994778991950582, 0.30592707550088083, 0.25592440253973936],
          [0.49947789920261376, 0.3217045037131283, 0.2664440247211729]]
    T2 = [[0.49947789920330465, 0.29538871462488125, 0.266444024719279],
          [0.49947789921152225, 0.30592707556480125, 0.28224018895123504],
          [0.49947789921067415, 0.29185122304348604, 0.2788259819290885]]
    V = np.array(T1 + T2)
    assert self_intersections(V, np.array([[0, 1, 2], [3, 4, 5]])) == 0
    c = V[:3].mean(axis=0)  # a triangle through the first one's middle, across its plane: crossing
    V[3:] = c + np.array([[1e-3, 0.0, -2e-3], [-1e-3, 0.0, -2e-3], [0.0, 0.0, 2e-3]])
    assert self_intersections(V, np.array([[0, 1, 2], [3, 4, 5]])) == 1


def test_corner_groups_are_the_unique_sorted_rows_with_or_without_packing():
    rng = np.random.default_rng(3)
    for n in (6, 1 << 22):  # ids packed into one integer, and too large to pack
        F = rng.integers(0, n, (300, 3))
        F = np.vstack([F, F[:40, ::-1], F[40:60, [1, 2, 0]]])  # the same corners, either orientation
        _, inverse, count = np.unique(np.sort(F, axis=1), axis=0, return_inverse=True, return_counts=True)
        group, size = corner_groups(F)
        assert np.array_equal(group, inverse.ravel()) and np.array_equal(size, count)
        assert (size[group[:60]] >= 2).all()


def test_across_edges_and_one_fan():
    """The triangle across each edge of a closed oriented surface, and which vertices are a single fan (libigl's
    test) on two tetrahedra that share a corner (a pinch)."""
    from fracture.mesh.topology import across_edges, manifold_vertices, one_fan

    tet = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    across = across_edges(tet)
    for f in range(4):
        for k in range(3):
            g = across[f, k]
            a, b = tet[f, k], tet[f, (k + 1) % 3]
            assert g != f and b in tet[g] and a in tet[g]
            i = list(tet[g]).index(b)
            assert tet[g, (i + 1) % 3] == a  # along the edge the other way
    assert across_edges(tet[:3]) is None and across_edges(np.r_[tet, tet[:1]]) is None
    two = np.r_[tet, tet + 3]  # vertex 3 is both tetrahedra's
    assert one_fan(two, across_edges(two), 7).tolist() == igl.is_vertex_manifold(two).ravel().tolist()
    assert one_fan(two, across_edges(two), 7).tolist() == [True, True, True, False, True, True, True]
    assert manifold_vertices(two).tolist() == [True, True, True, False, True, True, True]
    V, F = box([0, 0, 0], [1, 2, 3], (3, 4, 5))
    assert one_fan(F, across_edges(F), len(V)).all()


def test_manifold_vertices_agree_with_libigl_on_pinched_closed_surfaces_and_open_ones():
    """Convex hulls glued at a few vertices (pinches, closed and oriented: :func:`one_fan`'s union-find, with
    faces of 64 and 32 bits), and the same with a triangle taken out, which is open and goes to libigl (the
    test checks that it is sent there); hull points inside the hull are vertices no triangle names."""
    from scipy.spatial import ConvexHull

    from fracture.mesh.topology import across_edges, manifold_vertices

    rng = np.random.default_rng(3)
    pinched = 0
    for trial in range(40):
        parts, n = [], 0
        for _ in range(int(rng.integers(2, 5))):
            P = rng.normal(size=(30, 3))
            H = ConvexHull(P).simplices
            out = np.einsum("ij,ij->i", P[H[:, 0]] - P.mean(axis=0),
                            np.cross(P[H[:, 1]] - P[H[:, 0]], P[H[:, 2]] - P[H[:, 0]])) < 0
            H[out] = H[out][:, ::-1]
            parts.append(H + n)
            n += 30
        glue = np.arange(n)
        at = rng.choice(np.unique(parts[0]))  # a vertex of the first hull, and one of each other hull on it
        for H in parts[1:]:
            if rng.random() < 0.8:
                glue[rng.choice(np.unique(H))] = at
        F = glue[np.concatenate(parts)]
        for G in (F, F.astype(np.int32), F[1:]):
            assert (across_edges(G) is not None) == (len(G) == len(F))
            ours = manifold_vertices(G)
            assert np.array_equal(ours, np.asarray(igl.is_vertex_manifold(G.astype(np.int64)), bool).ravel()), trial
        pinched += int(not manifold_vertices(F)[at])
    assert pinched >= 20  # most of the glued surfaces have a pinch
    with pytest.raises(ValueError, match="expected fewer than n = 3"):
        from fracture.mesh.topology import one_fan

        one_fan(F, across_edges(F), 3)



def test_winding_numbers_count_the_turns_of_closed_surfaces_and_agree_with_libigl_on_open_ones():
    """Inside a closed box 1, outside 0, inside a box turned over -1, inside two nested boxes 2; on an open
    surface (half the box's triangles) the solid angle's share, as libigl's exact winding number gives it."""
    V, F = box([0, 0, 0], [1, 1, 1], (3, 2, 4))
    rng = np.random.default_rng(5)
    inside = rng.uniform(0.05, 0.95, (40, 3))
    outside = rng.uniform(-1.0, 2.0, (400, 3))
    outside = outside[np.any((outside < -0.05) | (outside > 1.05), axis=1)]
    np.testing.assert_allclose(winding_numbers(V, F, inside), 1.0, atol=1e-12)
    np.testing.assert_allclose(winding_numbers(V, F, outside), 0.0, atol=1e-12)
    np.testing.assert_allclose(winding_numbers(V, F[:, ::-1], inside), -1.0, atol=1e-12)
    W, G = box([-1, -1, -1], [2, 2, 2], (2, 2, 2))
    both = np.concatenate([V, W]), np.concatenate([F, G + len(V)])
    np.testing.assert_allclose(winding_numbers(*both, inside), 2.0, atol=1e-12)
    half = F[: len(F) // 2]
    P = np.concatenate([inside, outside[:40]])
    np.testing.assert_allclose(winding_numbers(V, half, P), igl.winding_number(V, half, P), atol=1e-12)
    assert winding_numbers(V, F[:0], P).shape == (len(P),) and not winding_numbers(V, F[:0], P).any()
