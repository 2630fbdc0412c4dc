"""Deformation transfer from the coarse animation to the pieces (Section 5).

Every coarse location ``X_s`` moving with component ``c`` has, per frame, an
affine deformation ``x = A X + b`` (the coarse animation's deformation
gradient there, and the offset that maps ``X_s`` to its position). A vertex
of a piece takes a weighted mean of such maps and applies it to its own
material position:

* a vertex of the refined fracture surface: the coarse fracture vertices
  and weights of the barycentric tree (Section 4.4), with the piece's
  component;
* a vertex of B off the cut: the nearest location on the coarse surface of
  its own component (barycentric weights of that coarse triangle).

Early fracture: a fracture vertex carries a fracture time (the coarse
vertices' first separation frames, interpolated through the tree); before
it, every piece that holds the vertex uses one shared component's maps, so
no gap opens before the coarse animation separates. Components that meet
only across virtual fracture move as one (their shared representative's
maps), so virtual fracture never opens.

All of it is linear in the maps: with ``P`` the sparse matrix of weights
times ``[X, 1]`` and ``G_t`` the stacked maps of frame ``t``, the positions
are ``P @ G_t``: one sparse product per frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import igl
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from fracture.coarse import CoarseFracture
from fracture.pieces import Pieces


@dataclass
class Transfer:
    """Per-frame positions of every piece vertex.

    Attributes
    ----------
    own : csr (rows, 4 s)
        Weights times ``[X, 1]`` against the maps of each row's own component.
    shared : csr (k, 4 s)
        The same for the ``k`` rows that have a fracture time, against the
        shared component's maps, rows sorted by decreasing time.
    shared_rows : (k,) int
        Which row each ``shared`` row is; ``shared_time`` their times.
    maps : (T, 4 s, 3) float
        Per frame, each slot's ``A^T`` (4 rows per slot, first three) and ``b``.
    offsets : (pieces + 1,) int
        Rows of piece ``c`` are ``offsets[c]:offsets[c + 1]``.
    time : (rows,) float
        Fracture time of every row (0 for rows that always move on their own).
    vertex : (rows,) int
        The shared vertex (``Pieces.V`` id) each row is a copy of.
    """

    own: sp.csr_matrix
    shared: sp.csr_matrix
    shared_rows: np.ndarray
    shared_time: np.ndarray
    maps: np.ndarray
    offsets: np.ndarray
    time: np.ndarray
    vertex: np.ndarray

    @property
    def n_frames(self) -> int:
        return self.maps.shape[0]

    def positions(self, t: int) -> np.ndarray:
        """Positions ``(rows, 3)`` of every piece vertex at frame ``t`` (0-based)."""
        G = self.maps[t]
        X = self.own @ G
        k = int(np.searchsorted(-self.shared_time, -t, side="left"))  # rows whose time is after t
        if k:
            X[self.shared_rows[:k]] = self.shared[:k] @ G
        return X

    def piece(self, X: np.ndarray, c: int) -> np.ndarray:
        return X[self.offsets[c]:self.offsets[c + 1]]


def bonded_representatives(cf: CoarseFracture) -> np.ndarray:
    """Per component, the component whose motion it takes: components joined only by virtual fracture move as one."""
    C = cf.n_components
    pair = np.sort(cf.sides, axis=1)
    key = pair[:, 0] * C + pair[:, 1]
    real = np.zeros(C * C, bool)
    real[key[~cf.virtual]] = True
    bonded = np.unique(key[cf.virtual & ~real[key]])
    graph = sp.coo_matrix((np.ones(len(bonded)), (bonded // C, bonded % C)), shape=(C, C))
    _, label = connected_components(graph, directed=False)
    rep = np.full(label.max() + 1, C)
    np.minimum.at(rep, label, np.arange(C))
    return rep[label]


def _nearest_coarse(cf: CoarseFracture, c: int, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Coarse points (ids into ``[cf.V; cf.exterior_V]``) and weights of the nearest location on component c's coarse surface."""
    n0 = len(cf.V)
    K = np.concatenate([cf.V, cf.exterior_V])
    faces = np.concatenate([cf.exterior_F[cf.exterior_component == c] + n0,
                            cf.F[(cf.sides == c).any(axis=1)]]).astype(np.int64)
    _, f, P = igl.point_mesh_squared_distance(np.ascontiguousarray(X), K, faces)
    T = faces[f]
    bary = igl.barycentric_coordinates(np.ascontiguousarray(P), np.ascontiguousarray(K[T[:, 0]]),
                                       np.ascontiguousarray(K[T[:, 1]]), np.ascontiguousarray(K[T[:, 2]]))
    return T, np.clip(bary, 0.0, 1.0) / np.clip(bary, 0.0, 1.0).sum(axis=1, keepdims=True)


def build_transfer(cf: CoarseFracture, pieces: Pieces, tree: sp.csr_matrix) -> Transfer:
    """The transfer for ``pieces`` given the tree map ``tree`` (fracture vertices x coarse fracture vertices)."""
    C = cf.n_components
    K = np.concatenate([cf.V, cf.exterior_V])
    rep = bonded_representatives(cf)
    nf = pieces.n_fracture
    tree = sp.csr_matrix(tree)

    # per fracture vertex: the shared component (lowest among the pieces that
    # hold it) and the fracture time interpolated through the tree
    shared_comp = np.full(nf, C)
    for c in range(C):
        verts = np.unique(pieces.faces[c])
        verts = verts[verts < nf]
        shared_comp[verts] = np.minimum(shared_comp[verts], c)
    vtime = tree @ cf.vertex_fracture_time.astype(np.float64)

    rows_v, rows_c, ent_row, ent_k, ent_w, ent_c = [], [], [], [], [], []
    offsets = [0]
    start = 0
    for c in range(C):
        ids = np.unique(pieces.faces[c])
        rows_v.append(ids)
        rows_c.append(np.full(len(ids), c))
        frac = ids < nf
        r = start + np.flatnonzero(frac)
        sub = tree[ids[frac]].tocoo()
        ent_row.append(r[sub.row]), ent_k.append(sub.col), ent_w.append(sub.data), ent_c.append(np.full(sub.nnz, c))
        ext = np.flatnonzero(~frac)
        if len(ext):
            T, w = _nearest_coarse(cf, c, pieces.V[ids[ext]])
            ent_row.append(np.repeat(start + ext, 3)), ent_k.append(T.ravel()), ent_w.append(w.ravel())
            ent_c.append(np.full(w.size, c))
        start += len(ids)
        offsets.append(start)
    vertex = np.concatenate(rows_v)
    comp = np.concatenate(rows_c)
    row, k, w, c_own = (np.concatenate(a) for a in (ent_row, ent_k, ent_w, ent_c))
    c_own = rep[c_own]
    is_frac = vertex < nf
    time = np.where(is_frac, vtime[np.minimum(vertex, nf - 1)], 0.0)
    c_shared_row = np.where(is_frac, rep[shared_comp[np.minimum(vertex, nf - 1)]], rep[comp])
    # rows whose shared component differs from their own need the shared matrix
    pending = np.flatnonzero((time > 0) & (c_shared_row != rep[comp]))
    in_pending = np.full(len(vertex), -1)
    order = pending[np.argsort(-time[pending], kind="stable")]
    in_pending[order] = np.arange(len(order))
    sel = in_pending[row] >= 0
    c_sh = c_shared_row[row[sel]]

    keys_own = k * C + c_own
    keys_sh = k[sel] * C + c_sh
    slots, inv = np.unique(np.concatenate([keys_own, keys_sh]), return_inverse=True)
    s_own, s_sh = inv[:len(keys_own)], inv[len(keys_own):]
    X = pieces.V[vertex]
    S = len(slots)

    def matrix(r, s, weight, n_rows, Xr):
        cols = np.concatenate([4 * s + j for j in range(4)])
        vals = np.concatenate([weight * Xr[:, 0], weight * Xr[:, 1], weight * Xr[:, 2], weight])
        return sp.csr_matrix((vals, (np.tile(r, 4), cols)), shape=(n_rows, 4 * S))

    own = matrix(row, s_own, w, len(vertex), X[row])
    shared = matrix(in_pending[row[sel]], s_sh, w[sel], len(order), X[row[sel]])

    anim = cf.animation
    Xs, cs = K[slots // C], slots % C
    maps = np.zeros((anim.n_frames, 4 * S, 3))
    for c in np.unique(cs):
        m = np.flatnonzero(cs == c)
        for t in range(anim.n_frames):
            A = anim.gradient(int(c), t, Xs[m])  # (k, 3, 3)
            b = anim.deform(int(c), t, Xs[m]) - np.einsum("kab,kb->ka", A, Xs[m])
            for j in range(3):
                maps[t, 4 * m + j] = A[:, :, j]
            maps[t, 4 * m + 3] = b
    return Transfer(own=own, shared=shared, shared_rows=order, shared_time=time[order], maps=maps,
                    offsets=np.asarray(offsets), time=time, vertex=vertex)


def load_transfer(path) -> Transfer:
    """Read ``animation/transfer.npz`` written by the animate stage."""
    with np.load(path) as z:
        def csr(name):
            return sp.csr_matrix((z[f"{name}_data"], z[f"{name}_indices"], z[f"{name}_indptr"]),
                                 shape=tuple(z[f"{name}_shape"]))
        return Transfer(own=csr("own"), shared=csr("shared"), shared_rows=z["shared_rows"],
                        shared_time=z["shared_time"], maps=z["maps"], offsets=z["offsets"], time=z["time"],
                        vertex=z["vertex"])
