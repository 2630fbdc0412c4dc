"""Deformation transfer from the coarse animation to the pieces (Section 5).

Every coarse location ``X_s`` moving with component ``c`` has, per frame, an
affine deformation ``x = A X + b`` (the coarse animation's deformation
gradient there, and the offset that maps ``X_s`` to its position). A vertex
of a piece takes a weighted mean of such maps and applies it to its own
material position:

* a vertex of the refined fracture surface: the coarse fracture vertices
  and weights of the barycentric tree (Section 4.4), with the piece's
  component (a vertex the resolution of a crossing made on an S triangle:
  the tree rows of the triangle's corners, blended by its barycentric
  weights);
* a vertex of B off the cut: the nearest location on the coarse surface of
  its own component (barycentric weights of that coarse triangle).

Early fracture: a fracture vertex carries a fracture time (the coarse
vertices' first separation frames, interpolated through the tree); before
it, every piece that holds the vertex uses one shared component's maps, so
no gap opens before the coarse animation separates. Components that meet
only across virtual fracture move as one (their shared representative's
maps), so virtual fracture never opens.

All of it is linear in the maps: a frame is one sparse product of the
weights with the frame's maps, each row's blended map applied to its own
material position (:func:`_apply`, compiled: a row reads its few weights and
12 numbers per slot, four times less memory than the product of an
expanded ``(rows, 4 s)`` matrix with ``(4 s, 3)`` maps in scipy).
"""

from __future__ import annotations

from dataclasses import dataclass

import igl
import numba
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from fracture.coarse.surface import CoarseFracture
from fracture.pieces.assembly import Pieces
from fracture.mesh.topology import barycentric_weights

# The maps of a component's slots at a frame that agree within this (their translations relative to the
# scene's size) are stored once (transfer_arrays): exact for the rigid and affine motions that agree to
# rounding, far below the 1e-6 of the scene's size that positions are checked to.
_SAME_MAP = 1e-10
# A scene smaller than this is measured against it (no division by a zero size).
_TINY_SIZE = 1e-30


@dataclass
class Transfer:
    """Per-frame positions of every piece vertex.

    Attributes
    ----------
    own : csr (rows, s)
        Weights of each row's slots (a coarse location moving with the row's own component).
    shared : csr (k, s)
        The same for the ``k`` rows that have a fracture time, with the
        shared component's slots, rows sorted by decreasing time.
    shared_rows : (k,) int
        Which row each ``shared`` row is; ``shared_time`` their times.
    maps : (T, s, 3, 4) float
        Per frame, each slot's affine map ``[A | b]``.
    offsets : (pieces + 1,) int
        Rows of piece ``c`` are ``offsets[c]:offsets[c + 1]``.
    time : (rows,) float
        Fracture time of every row (0 for rows that always move on their own).
    vertex : (rows,) int
        The shared vertex (``Pieces.V`` id) each row is a copy of.
    material : (rows, 3) float
        Material-space position of every row.
    slot_component : (s,) int or None
        The component each slot moves with (what lets a rigid or affine motion be stored once per
        component and frame: :func:`transfer_arrays`).
    """

    own: sp.csr_matrix
    shared: sp.csr_matrix
    shared_rows: np.ndarray
    shared_time: np.ndarray
    maps: np.ndarray
    offsets: np.ndarray
    time: np.ndarray
    vertex: np.ndarray
    material: np.ndarray
    slot_component: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return self.maps.shape[0]

    @property
    def size(self) -> float:
        """The scene's size: the diagonal of the box of the pieces' material positions (B's box)."""
        X = self.material
        return float(np.linalg.norm(X.max(axis=0) - X.min(axis=0))) if len(X) else 1.0

    def positions(self, t: int) -> np.ndarray:
        """Positions ``(rows, 3)`` of every piece vertex at frame ``t`` (0-based)."""
        M = self.maps[t]
        out = np.empty((len(self.vertex), 3))
        A = self.own
        _apply(A.indptr, A.indices, A.data, self.material, M, np.arange(len(self.vertex)), out)
        k = int(np.searchsorted(-self.shared_time, -t, side="left"))  # rows whose time is after t
        if k:
            B = self.shared
            _apply(B.indptr[:k + 1], B.indices, B.data, self.material, M, self.shared_rows[:k], out)
        return out

    def piece(self, X: np.ndarray, c: int) -> np.ndarray:
        return X[self.offsets[c]:self.offsets[c + 1]]


def rest_points(transfer: Transfer) -> list[np.ndarray]:
    """Every piece's material-space points (what a frame's motion moves)."""
    return [transfer.piece(transfer.material, c) for c in range(len(transfer.offsets) - 1)]


def frame_points(transfer: Transfer):
    """Per frame, the list of every piece's points (a generator: one frame in memory at a time)."""
    for t in range(transfer.n_frames):
        X = transfer.positions(t)
        yield [transfer.piece(X, c) for c in range(len(transfer.offsets) - 1)]


@numba.njit(cache=True, fastmath=True)
def _apply(indptr, indices, data, X, M, rows, out):
    """``out[rows[i]] = (sum_p data[p] M[indices[p]]) @ [X[rows[i]], 1]`` for every row ``i`` of the CSR weights.

    The 3 x 4 blend is written out in scalars: with a (3, 4) scratch array
    and loops, numba keeps it in memory and a frame is four times slower.
    """
    for i in range(indptr.shape[0] - 1):
        m00 = m01 = m02 = m03 = m10 = m11 = m12 = m13 = m20 = m21 = m22 = m23 = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            s, w = indices[p], data[p]
            m00 += w * M[s, 0, 0]
            m01 += w * M[s, 0, 1]
            m02 += w * M[s, 0, 2]
            m03 += w * M[s, 0, 3]
            m10 += w * M[s, 1, 0]
            m11 += w * M[s, 1, 1]
            m12 += w * M[s, 1, 2]
            m13 += w * M[s, 1, 3]
            m20 += w * M[s, 2, 0]
            m21 += w * M[s, 2, 1]
            m22 += w * M[s, 2, 2]
            m23 += w * M[s, 2, 3]
        r = rows[i]
        x, y, z = X[r, 0], X[r, 1], X[r, 2]
        out[r, 0] = m00 * x + m01 * y + m02 * z + m03
        out[r, 1] = m10 * x + m11 * y + m12 * z + m13
        out[r, 2] = m20 * x + m21 * y + m22 * z + m23


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


def _nearest_coarse(cf: CoarseFracture, K: np.ndarray, c: int, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Coarse points (ids into ``K = [cf.V; cf.exterior_V]``) and weights of the nearest location on component c's coarse surface."""
    n0 = len(cf.V)
    faces = np.concatenate([cf.exterior_F[cf.exterior_component == c] + n0,
                            cf.F[(cf.sides == c).any(axis=1)]]).astype(np.int64)
    _, f, P = igl.point_mesh_squared_distance(np.ascontiguousarray(X), K, faces)
    T = faces[f]
    return T, barycentric_weights(P, K[T])


def shared_components(pieces: Pieces, n_components: int) -> np.ndarray:
    """Per fracture vertex, the component whose motion it follows once its pieces are apart.

    A vertex of S is held by every piece it bounds and follows the lowest of them. A vertex
    the resolution of crossings made on an S triangle is held by one piece; it follows its
    triangle's corners so that it stays with its neighbours, or its own piece when no piece
    holds any of the corners (the triangle lies outside B). A vertex no piece holds gets
    ``n_components``.
    """
    nf = pieces.n_fracture
    shared = np.full(nf, n_components)
    for c in range(n_components):
        verts = pieces.piece(c)[0]
        verts = verts[verts < nf]
        shared[verts] = np.minimum(shared[verts], c)
    if nf > pieces.n_surface:
        D = pieces.derived
        corners = np.minimum.reduceat(shared[D.indices], D.indptr[:-1])
        shared[pieces.n_surface:] = np.where(corners < n_components, corners, shared[pieces.n_surface:])
    return shared


def build_transfer(cf: CoarseFracture, pieces: Pieces, tree: sp.csr_matrix) -> Transfer:
    """The transfer for ``pieces`` given the tree map ``tree`` (fracture vertices x coarse fracture vertices)."""
    C = cf.n_components
    K = np.concatenate([cf.V, cf.exterior_V])
    rep = bonded_representatives(cf)
    nf = pieces.n_fracture
    tree = pieces.fracture_tree(tree)

    shared_comp = shared_components(pieces, C)
    vtime = tree @ cf.vertex_fracture_time.astype(np.float64)

    rows_v, rows_c, ent_row, ent_k, ent_w, ent_c = [], [], [], [], [], []
    offsets = [0]
    start = 0
    for c in range(C):
        ids = pieces.piece(c)[0]
        rows_v.append(ids)
        rows_c.append(np.full(len(ids), c))
        frac = ids < nf
        r = start + np.flatnonzero(frac)
        sub = tree[ids[frac]].tocoo()
        ent_row.append(r[sub.row]), ent_k.append(sub.col), ent_w.append(sub.data), ent_c.append(np.full(sub.nnz, c))
        ext = np.flatnonzero(~frac)
        if len(ext):
            T, w = _nearest_coarse(cf, K, c, pieces.V[ids[ext]])
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
    # (a fracture vertex no piece holds has the sentinel C: only the rows of fracture vertices, which
    # pieces hold, read their shared component)
    c_shared_row = rep[comp].copy()
    c_shared_row[is_frac] = rep[shared_comp[vertex[is_frac]]]
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

    own = sp.csr_matrix((w, (row, s_own)), shape=(len(vertex), S))
    shared = sp.csr_matrix((w[sel], (in_pending[row[sel]], s_sh)), shape=(len(order), S))

    anim = cf.animation
    Xs, cs = K[slots // C], slots % C
    maps = np.zeros((anim.n_frames, S, 3, 4))
    for c in np.unique(cs):
        m = np.flatnonzero(cs == c)
        for t in range(anim.n_frames):
            A = anim.gradient(int(c), t, Xs[m])  # (k, 3, 3)
            b = anim.deform(int(c), t, Xs[m]) - np.einsum("kab,kb->ka", A, Xs[m])
            maps[t, m, :, :3] = A
            maps[t, m, :, 3] = b
    return Transfer(own=own, shared=shared, shared_rows=order, shared_time=time[order], maps=maps,
                    offsets=np.asarray(offsets), time=time, vertex=vertex, material=X, slot_component=cs)


def _slots_of(slot_component: np.ndarray, n_components: int) -> list[np.ndarray]:
    """Per component, its slots (ascending)."""
    order = np.argsort(slot_component, kind="stable")
    bounds = np.searchsorted(slot_component[order], np.arange(n_components + 1))
    return [order[bounds[c]:bounds[c + 1]] for c in range(n_components)]


def _common_maps(tr: Transfer, size: float) -> tuple[np.ndarray, np.ndarray]:
    """Per frame and component, the one map all the component's slots have (rigid and affine motion: a
    2 x 2 x 2 lattice moved so has the same gradient everywhere), and whether they all have it (within
    :data:`_SAME_MAP` of the entries, its translations relative to ``size``)."""
    T, C = tr.n_frames, int(tr.slot_component.max(initial=-1)) + 1
    common = np.zeros((T, C, 3, 4))
    same = np.zeros((T, C), bool)
    scale = np.array([1.0, 1.0, 1.0, max(size, _TINY_SIZE)])
    for c, m in enumerate(_slots_of(tr.slot_component, C)):
        if not len(m):
            continue
        first = tr.maps[:, m[0]]
        common[:, c] = first
        same[:, c] = (np.abs(tr.maps[:, m] - first[:, None]) / scale).max(axis=(1, 2, 3)) <= _SAME_MAP
    return common, same


def transfer_arrays(tr: Transfer, size: float) -> dict[str, np.ndarray]:
    """The arrays of ``animation/transfer.npz`` (:func:`load_transfer` reads them back).

    A component's maps at a frame are stored once when all its slots share
    them (rigid and affine motion), per slot only for the frames where the
    component deforms (soft scenes); ``size`` is the scene's size, the
    scale of the translations. Indices are 32-bit integers and the material
    positions (relative to their box's low corner) 32-bit floats, whose
    error is below a ten-millionth of the box; the weights and the maps keep
    64 bits (a position far from the origin is their sum), and so do the
    fracture times (compared with whole frames).
    """
    out = {}
    for name in ("own", "shared"):
        A = getattr(tr, name)
        out.update({f"{name}_data": A.data, f"{name}_indices": A.indices.astype(np.int32),
                    f"{name}_indptr": A.indptr.astype(np.int64), f"{name}_shape": np.array(A.shape, np.int64)})
    lo = tr.material.min(axis=0) if len(tr.material) else np.zeros(3)
    out.update(shared_rows=tr.shared_rows.astype(np.int32), shared_time=tr.shared_time,
               offsets=tr.offsets.astype(np.int64), time=tr.time,
               vertex=tr.vertex.astype(np.int32), material_origin=lo,
               material=(tr.material - lo).astype(np.float32))
    if tr.slot_component is None:
        out["maps"] = tr.maps
        return out
    common, same = _common_maps(tr, size)
    t_own, c_own = np.nonzero(~same)  # (frame, component) pairs whose slots have maps of their own
    out.update(slot_component=tr.slot_component.astype(np.int32), common_maps=common, common_same=same)
    slots = _slots_of(tr.slot_component, same.shape[1])
    out["slot_maps"] = (np.concatenate([tr.maps[t, slots[c]] for t, c in zip(t_own, c_own)])
                        if len(t_own) else np.zeros((0, 3, 4)))
    return out


def load_transfer(path) -> Transfer:
    """Read ``animation/transfer.npz`` written by the animate stage (also the layout before
    :func:`transfer_arrays`, with every slot's maps)."""
    with np.load(path) as z:
        def csr(name):
            return sp.csr_matrix((z[f"{name}_data"], z[f"{name}_indices"], z[f"{name}_indptr"]),
                                 shape=tuple(z[f"{name}_shape"]))
        material = z["material"].astype(np.float64) + (z["material_origin"] if "material_origin" in z else 0.0)
        slot_component = z["slot_component"] if "slot_component" in z else None
        if "maps" in z:
            maps = z["maps"]
        else:
            common, same, slot_maps = z["common_maps"], z["common_same"], z["slot_maps"]
            maps = np.empty((len(common), len(slot_component), 3, 4))
            slots = _slots_of(slot_component, same.shape[1])
            k = 0
            for t, c in zip(*np.nonzero(np.ones_like(same))):  # in the order transfer_arrays wrote them
                if same[t, c]:
                    maps[t, slots[c]] = common[t, c]
                else:
                    maps[t, slots[c]] = slot_maps[k:k + len(slots[c])]
                    k += len(slots[c])
        return Transfer(own=csr("own"), shared=csr("shared"), shared_rows=z["shared_rows"].astype(np.int64),
                        shared_time=z["shared_time"].astype(np.float64), maps=maps,
                        offsets=z["offsets"].astype(np.int64), time=z["time"].astype(np.float64),
                        vertex=z["vertex"].astype(np.int64), material=material, slot_component=slot_component)
