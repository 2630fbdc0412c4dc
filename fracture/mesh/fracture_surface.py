"""The refined fracture surface and its mesh operations (Section 4.4), vectorised.

One shared non-manifold surface: every triangle once, with the components on
its two sides. The operations here (1-to-3 triangle splits, edge splits that
split every triangle on the edge) keep each triangle's orientation and side
ids, and record every new vertex in the barycentric tree: its parent
vertices and weights at the moment it was made. :meth:`FractureSurface.tree_matrix`
composes the tree into one sparse map from the coarse vertices to every
vertex (rows sum to 1), which Section 5 uses to carry the coarse animation's
deformation to the refined surface.

The refinement renumbers vertices and triangles now and then so that
neighbours stay near in memory (:meth:`FractureSurface.reorder`); the tree speaks
of vertices by creation order (``label``), and
:meth:`FractureSurface.creation_order` gives the order that restores it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np
import scipy.sparse as sp

from fracture.mesh.edges import edge_table


@dataclass
class FractureSurface:
    """A fracture surface under refinement.

    Attributes
    ----------
    V : (n, 3) float
    F : (m, 3) int
    sides : (m, 2) int
    n_coarse : int
        The coarse surface's vertices are the first ``n_coarse`` in creation order.
    parents, weights : list of (k, 3) arrays
        Per batch of new vertices (in creation order), their parents (by
        creation order) and barycentric weights (an edge split has a zero
        third weight).
    created : list of (k, 3) arrays
        Positions of the new vertices when they were made (for checks).
    label : (n,) int
        Creation order of every vertex (a permutation of ``0..n-1``; the
        identity unless :meth:`reorder` was called).
    base : csr (n_coarse, k) or None
        Where the first ``n_coarse`` vertices are not the coarse surface's own
        ``k`` vertices but a surface found from it (the global search): each
        one's barycentric weights on the coarse vertices.
    """

    V: np.ndarray
    F: np.ndarray
    sides: np.ndarray
    n_coarse: int = 0
    parents: list = field(default_factory=list)
    weights: list = field(default_factory=list)
    created: list = field(default_factory=list)
    label: np.ndarray | None = None
    base: sp.csr_matrix | None = None

    def __post_init__(self):
        if self.label is None:
            self.label = np.arange(len(self.V))

    @classmethod
    def from_coarse(cls, V, F, sides) -> FractureSurface:
        V = np.array(V, np.float64)
        return cls(V, np.array(F, np.int64), np.array(sides, np.int64), n_coarse=len(V))

    def reorder(self, vorder: np.ndarray, forder: np.ndarray | None = None) -> np.ndarray:
        """Renumber the vertices (new vertex ``i`` is old ``vorder[i]``) and the triangles
        (new triangle ``j`` is old ``forder[j]``); returns the old-to-new vertex map."""
        vorder = np.asarray(vorder, np.int64)
        new = np.empty(len(vorder), np.int64)
        new[vorder] = np.arange(len(vorder))
        self.V, self.label = self.V[vorder], self.label[vorder]
        F = new[self.F]
        if forder is not None:
            F, self.sides = F[forder], self.sides[forder]
        self.F = np.ascontiguousarray(F)
        return new

    def creation_order(self) -> np.ndarray:
        """The vertex order that numbers them in creation order again (coarse ones first), for :meth:`reorder`."""
        return np.argsort(self.label)

    def _add_vertices(self, parents: np.ndarray, weights: np.ndarray) -> np.ndarray:
        P = np.einsum("kj,kjc->kc", weights, self.V[parents])
        ids = np.arange(len(self.V), len(self.V) + len(P))
        self.V = np.concatenate([self.V, P])
        self.label = np.concatenate([self.label, ids])  # vertices are never removed: the next in creation order
        self.parents.append(self.label[parents].astype(np.int64))
        self.weights.append(weights.astype(np.float64))
        self.created.append(P.copy())
        return ids

    def split_triangles(self, faces: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """Split each triangle ``faces[i]`` 1-to-3 at barycentric point ``bary[i]``; returns the new vertex ids."""
        faces = np.asarray(faces, np.int64)
        T = self.F[faces]
        p = self._add_vertices(T, np.asarray(bary, np.float64))
        a, b, c = T.T
        self.F[faces] = np.stack([a, b, p], 1)
        self.F = np.concatenate([self.F, np.stack([b, c, p], 1), np.stack([c, a, p], 1)])
        self.sides = np.concatenate([self.sides, self.sides[faces], self.sides[faces]])
        return p

    def split_edges(self, edges: np.ndarray, t: np.ndarray, rows: np.ndarray | None = None,
                    which: np.ndarray | None = None) -> np.ndarray:
        """Split edges ``(a, b)`` at ``(1 - t) a + t b``, and every triangle on them in two.

        A triangle may carry at most one of the split edges. ``rows`` (directed
        triangle edges ``3 f + k`` on the split edges) and ``which`` (the split
        edge of each) may be given when the caller has an edge table already.
        Returns the new vertex ids.
        """
        edges = np.asarray(edges, np.int64).reshape(-1, 2)
        t = np.asarray(t, np.float64)
        if rows is None:
            table = edge_table(self.F, len(self.V))
            ids = table.find(edges)
            if (ids < 0).any():
                raise ValueError(f"edge {edges[np.argmax(ids < 0)].tolist()} is not an edge of the surface")
            rows, which = table.rows_of(ids)
        parents = np.column_stack([edges, edges[:, 0]])
        p = self._add_vertices(parents, np.column_stack([1 - t, t, np.zeros_like(t)]))
        face, k = rows // 3, rows % 3
        if len(np.unique(face)) != len(face):
            raise ValueError("a triangle carries two of the edges to split")
        # triangle (u, v, w) with split edge u -> v becomes (u, p, w) and (p, v, w)
        u = self.F[face, k]
        v = self.F[face, (k + 1) % 3]
        w = self.F[face, (k + 2) % 3]
        mid = p[which]
        self.F[face] = np.stack([u, mid, w], 1)
        self.F = np.concatenate([self.F, np.stack([mid, v, w], 1)])
        self.sides = np.concatenate([self.sides, self.sides[face]])
        return p

    def tree_matrix(self) -> sp.csr_matrix:
        """Sparse ``(n, n_coarse)`` map from the coarse vertices (in creation order) to every vertex
        (in the current order); rows sum to 1. With a ``base``, the map from the coarse surface's
        vertices through it, ``(n, k)``.

        Row by row in creation order, each new vertex's row the weighted sum of its parents' rows
        (:func:`_tree_rows`, compiled: composing batch by batch with sparse products re-stacked the
        growing map once per batch)."""
        n = self.n_coarse + sum(len(p) for p in self.parents)
        parents = np.concatenate(self.parents) if self.parents else np.zeros((0, 3), np.int64)
        weights = np.concatenate(self.weights) if self.weights else np.zeros((0, 3))
        indptr, indices, data = _tree_rows(self.n_coarse, np.ascontiguousarray(parents, np.int64),
                                           np.ascontiguousarray(weights, np.float64))
        W = sp.csr_matrix((data, indices, indptr), shape=(n, self.n_coarse))
        if not np.array_equal(self.label, np.arange(len(self.label))):
            W = W[self.label]
        if self.base is not None:
            W = (W @ self.base).tocsr()
        return W

    def tree_arrays(self) -> dict[str, np.ndarray]:
        """The barycentric tree as a run stores it (``refined/tree.npz``): ``n_coarse``; per new vertex in
        creation order its three ``parents`` (vertex ids), their ``weights`` and the position it was
        ``created`` at; and the composed map of :meth:`tree_matrix` as CSR (``map_data``,
        ``map_indices``, ``map_indptr``, ``map_shape``)."""
        W = self.tree_matrix()
        empty = np.zeros((0, 3))
        return dict(
            n_coarse=np.int64(self.n_coarse),
            parents=np.concatenate(self.parents) if self.parents else empty.astype(np.int64),
            weights=np.concatenate(self.weights) if self.weights else empty,
            created=np.concatenate(self.created) if self.created else empty,
            map_data=W.data, map_indices=W.indices.astype(np.int64), map_indptr=W.indptr.astype(np.int64),
            map_shape=np.array(W.shape, np.int64),
        )

    def replace(self, other: "FractureSurface") -> None:
        """Take ``other``'s vertices, triangles, sides and tree, in place (a new surface found from this
        one, which callers hold)."""
        for f in ("V", "F", "sides", "n_coarse", "parents", "weights", "created", "label", "base"):
            setattr(self, f, getattr(other, f))


@numba.njit(cache=True)
def _tree_rows(n_coarse, parents, weights):
    """CSR rows of the tree map: the coarse vertices' unit rows, then per new vertex the sum of its
    parents' rows weighted, accumulated as SciPy's sparse product does (parents by increasing id, a
    repeated parent's weights summed first; columns in the reverse order of their first appearance;
    sums of exactly zero left out), so the map is the same, bit for bit, as the product's."""
    m = parents.shape[0]
    indptr = np.zeros(n_coarse + m + 1, np.int64)
    cap = max(16, 4 * (n_coarse + m))
    indices = np.empty(cap, np.int64)
    data = np.empty(cap)
    for i in range(n_coarse):
        indices[i], data[i] = i, 1.0
        indptr[i + 1] = i + 1
    nnz = n_coarse
    sums = np.zeros(n_coarse)
    nxt = np.full(n_coarse, -1, np.int64)
    order = np.empty(3, np.int64)
    for r in range(m):
        # the row's entries by parent id, a parent named twice once with its weights summed
        order[:] = np.argsort(parents[r], kind="mergesort")
        head, length = -2, 0
        k = 0
        while k < 3:
            p = parents[r, order[k]]
            v = weights[r, order[k]]
            while k + 1 < 3 and parents[r, order[k + 1]] == p:
                k += 1
                v += weights[r, order[k]]
            k += 1
            for jj in range(indptr[p], indptr[p + 1]):
                c = indices[jj]
                sums[c] += v * data[jj]
                if nxt[c] == -1:
                    nxt[c] = head
                    head = c
                    length += 1
        if nnz + length > indices.shape[0]:
            grown = max(2 * indices.shape[0], nnz + length)
            indices2, data2 = np.empty(grown, np.int64), np.empty(grown)
            indices2[:nnz], data2[:nnz] = indices[:nnz], data[:nnz]
            indices, data = indices2, data2
        for _ in range(length):
            if sums[head] != 0.0:
                indices[nnz], data[nnz] = head, sums[head]
                nnz += 1
            c = head
            head = nxt[c]
            nxt[c], sums[c] = -1, 0.0
        indptr[n_coarse + r + 1] = nnz
    return indptr, indices[:nnz].copy(), data[:nnz].copy()
