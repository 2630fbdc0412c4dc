"""Mesh operations of the refinement: splits keep area, orientation, sides and the tree."""

from __future__ import annotations

import numpy as np
import pytest

from fracture.mesh.topology import face_frames
from fracture.mesh.primitives import sheet
from fracture.refine.order import spatial_order
from fracture.mesh.fracture_surface import FractureSurface
from fracture.mesh.topology import unique_edges


def junction():
    """Three sheets meeting along the edge (0, 1): a non-manifold surface with sides."""
    V = np.array([[0, 0, 0], [0, 0, 1], [1, 0, 0.5], [-0.5, 0.8, 0.5], [-0.5, -0.8, 0.5]], float)
    F = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    sides = np.array([[0, 1], [1, 2], [2, 0]])
    return FractureSurface.from_coarse(V, F, sides)


def normals_and_area(m):
    A, N = face_frames(m.V, m.F)
    return A, N


def test_triangle_split_keeps_area_orientation_and_sides():
    m = junction()
    A0, N0 = normals_and_area(m)
    p = m.split_triangles([0, 2], np.array([[0.2, 0.3, 0.5], [1 / 3, 1 / 3, 1 / 3]]))
    A, N = normals_and_area(m)
    assert len(m.F) == 7 and A.sum() == pytest.approx(A0.sum())
    # children point like their parent and separate the same components
    parent = np.array([0, 1, 2, 0, 2, 0, 2])
    assert np.allclose(N, N0[parent]) and np.array_equal(m.sides, np.array([[0, 1], [1, 2], [2, 0]])[parent])
    assert np.allclose(m.V[p[0]], 0.2 * m.V[0] + 0.3 * m.V[1] + 0.5 * m.V[2])


def test_edge_split_on_a_junction_splits_every_sheet():
    m = junction()
    A0, _ = normals_and_area(m)
    p = m.split_edges(np.array([[1, 0]]), np.array([0.25]))
    assert len(m.F) == 6
    edges, count = unique_edges(m.F)
    assert count[(edges == np.sort([0, p[0]])).all(axis=1)] == 3  # still a junction, now in two pieces
    assert not ((edges == [0, 1]).all(axis=1)).any()
    A, _ = normals_and_area(m)
    assert A.sum() == pytest.approx(A0.sum())
    assert np.allclose(m.V[p[0]], 0.75 * m.V[1] + 0.25 * m.V[0])
    with pytest.raises(ValueError, match="two of the edges"):
        m.split_edges(np.array([[0, p[0]], [p[0], 2]]), np.array([0.5, 0.5]))


def test_tree_reproduces_every_vertex_from_the_coarse_ones():
    rng = np.random.default_rng(0)
    m = junction()
    for _ in range(6):
        before = m.V.copy()
        f = rng.choice(len(m.F), size=min(3, len(m.F)), replace=False)
        p = m.split_triangles(f, rng.dirichlet([2, 2, 2], size=len(f)))
        # the record reproduces the new vertices from their parents' positions at that moment
        assert np.allclose(np.einsum("kj,kjc->kc", m.weights[-1], before[m.parents[-1]]), m.V[p])
        m.V[m.n_coarse:] += 0.01 * rng.standard_normal((len(m.V) - m.n_coarse, 3))  # the flow moves them
    W = m.tree_matrix()
    assert W.shape == (len(m.V), m.n_coarse)
    assert np.allclose(np.asarray(W.sum(axis=1)).ravel(), 1.0)
    # with no motion, the composed tree gives every vertex from the coarse vertices
    still = junction()
    for _ in range(4):
        f = rng.choice(len(still.F), size=2, replace=False)
        still.split_triangles(f, rng.dirichlet([1, 1, 1], size=2))
        e, _ = unique_edges(still.F)
        still.split_edges(e[:1], np.array([0.3]))
    assert np.allclose(still.tree_matrix() @ still.V[: still.n_coarse], still.V)


def test_renumbering_keeps_the_surface_and_the_tree():
    """Splits between renumberings: the tree still gives every vertex, and creation order comes back."""
    rng = np.random.default_rng(1)
    m, ref = junction(), junction()  # the same splits on a mesh that is never renumbered
    for _ in range(5):
        f = rng.choice(len(m.F), size=2, replace=False)
        w = rng.dirichlet([1, 1, 1], size=2)
        g = [int(np.flatnonzero((ref.F == m.label[m.F[i]]).all(axis=1))[0]) for i in f]
        ref.split_triangles(g, w)
        m.split_triangles(f, w)
        m.reorder(rng.permutation(len(m.V)), rng.permutation(len(m.F)))
    assert sorted(m.label) == list(range(len(m.V)))
    # the tree maps the coarse vertices (creation order) to every vertex in the current order
    coarse = m.V[np.argsort(m.label)[: m.n_coarse]]
    assert np.allclose(m.tree_matrix() @ coarse, m.V)
    new = m.reorder(m.creation_order())
    assert (m.label == np.arange(len(m.V))).all() and len(new) == len(m.V)
    assert np.array_equal(m.V, ref.V)
    assert {tuple(t) for t in m.F.tolist()} == {tuple(t) for t in ref.F.tolist()}  # same corners, same order
    assert (m.tree_matrix() != ref.tree_matrix()).nnz == 0
    assert np.allclose(np.concatenate(m.created), m.V[m.n_coarse:])


def test_spatial_order_puts_neighbours_near_in_memory():
    V, F = sheet(lambda u, v: np.stack([u, v, 0.1 * np.sin(3 * u)], 1), (0, 1), (0, 1), 60, 60)
    rng = np.random.default_rng(0)
    shuffle = rng.permutation(len(V))
    m = FractureSurface.from_coarse(V[shuffle], np.argsort(shuffle)[F], np.tile([0, 1], (len(F), 1)))
    m.F = m.F[rng.permutation(len(F))]
    spread = lambda: np.abs(np.diff(m.F[:, [0, 1, 2, 0]], axis=1)).mean()  # noqa: E731
    shuffled = spread()
    vorder, forder = spatial_order(m.V, m.F)
    assert sorted(vorder) == list(range(len(V))) and sorted(forder) == list(range(len(F)))
    m.reorder(vorder, forder)
    assert spread() < 0.1 * shuffled  # edges join vertices close in the numbering
    lowest = m.F.min(axis=1)
    assert (np.diff(lowest) >= 0).all()  # triangles by their first vertex


def test_the_compiled_tree_map_is_the_composition_of_the_batches():
    """tree_matrix: the map made row by row equals, bit for bit, the batches composed by sparse products
    (each batch's rows the product of its parents' weights with the map so far), with edge splits (a
    parent named twice, one weight zero) and face splits on a corner (a zero weight) among them."""
    import scipy.sparse as sp

    rng = np.random.default_rng(7)
    m = junction()
    for _ in range(8):
        f = rng.choice(len(m.F), size=min(4, len(m.F)), replace=False)
        bary = rng.dirichlet([1, 1, 1], size=len(f))
        bary[0] = [0.5, 0.5, 0.0]  # on an edge of its triangle
        m.split_triangles(f, bary)
        e, _ = unique_edges(m.F)
        m.split_edges(e[rng.choice(len(e), 1)], rng.uniform(0.2, 0.8, 1))
    W = sp.identity(m.n_coarse, format="csr")
    for parents, weights in zip(m.parents, m.weights):
        k = len(parents)
        P = sp.csr_matrix((weights.ravel(), (np.repeat(np.arange(k), 3), parents.ravel())), shape=(k, W.shape[0]))
        W = sp.vstack([W, P @ W], format="csr")
    W.eliminate_zeros()
    got = m.tree_matrix()
    assert np.array_equal(got.indptr, W.indptr) and np.array_equal(got.indices, W.indices)
    assert np.array_equal(got.data, W.data)
