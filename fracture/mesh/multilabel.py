"""Multi-material marching tetrahedra (Wu and Sullivan 2003): the interfaces between the labels of a
grid as one conforming surface.

Each cube of the grid whose corners carry several labels is split into
Kuhn's six tetrahedra; between two labels of a tetrahedron the interface is
the polygon through its edges' crossings, its three-label faces' points and,
with four labels, its own point. Between two pieces this is a fracture
polygon (its normal points into the second), between a piece and the
outside (label 0) a polygon of B. Tetrahedra have no ambiguous cases: B is a
closed, oriented 2-manifold and the sheets meet each other and B along
shared edges. Where an edge crosses is the caller's (a bisection of winding
numbers for imported pieces, B itself or the middle for a graph cut's
labels); points of faces and tetrahedra are means of their crossings (those
on B when there are some, so B keeps its plane where a sheet meets it).

Written here because no library at hand (libigl, pymeshlab, Open3D,
scikit-image) contours a grid of several labels into one conforming surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

# Crossings keep this fraction of the edge from its nodes.
_NODE_GAP = 0.02


@dataclass
class LabelContour:
    """The result of :func:`contour_labels`.

    Attributes
    ----------
    V : (n, 3) float
        Points of both surfaces.
    fracture_F : (m, 3) int
        Triangles between two pieces; the normal points from ``sides[:, 0]`` into ``sides[:, 1]``.
    sides : (m, 2) int
        Piece behind and in front of each fracture triangle (``sides[:, 0] < sides[:, 1]``).
    exterior_F : (k, 3) int
        Triangles between a piece and the outside, facing out.
    exterior_piece : (k,) int
        The piece each of them bounds.
    """

    V: np.ndarray
    fracture_F: np.ndarray
    sides: np.ndarray
    exterior_F: np.ndarray
    exterior_piece: np.ndarray


# Kuhn's split of a cube into 6 tetrahedra along its diagonal 000-111: every path from corner 000 to 111
# along the axes, corners as bit offsets (x, y, z). Neighbouring cubes split their common face alike.
_KUHN = np.array([[[0, 0, 0], a, a + b, [1, 1, 1]] for a, b in [
    (np.eye(3, dtype=int)[i], np.eye(3, dtype=int)[j]) for i in range(3) for j in range(3) if i != j]])


def _mixed_tets(label: np.ndarray, pieces_only: bool = False) -> np.ndarray:
    """Node ids ``(t, 4)`` of the Kuhn tetrahedra of every cube whose corners carry more than one label, the
    cubes in C order; with ``pieces_only`` only the tetrahedra whose corners carry two pieces or more (labels
    above 0)."""
    shape = label.shape
    strides = np.array([shape[1] * shape[2], shape[2], 1], np.int64)
    kuhn = (_KUHN @ strides).astype(np.int64)  # (6, 4) node offsets from a cube's first corner
    return _mixed_tets_compiled(np.ascontiguousarray(label, np.int64).ravel(), shape[0], shape[1], shape[2], kuhn,
                                pieces_only)


@numba.njit(cache=True)
def _pieces_in(lab, c, kuhn_row) -> int:
    """How many different pieces (labels above 0) the corners of one tetrahedron carry."""
    n = 0
    for b in range(4):
        x = lab[c + kuhn_row[b]]
        if x > 0:
            new = True
            for e in range(b):
                if lab[c + kuhn_row[e]] == x:
                    new = False
                    break
            n += new
    return n


@numba.njit(cache=True)
def _mixed_tets_compiled(lab, nx, ny, nz, kuhn, pieces_only):
    """:func:`_mixed_tets` in two passes over the cubes (count, then fill): the eight shifted views of the
    grid and their reductions took 0.08 s of the collapsing wall's contour (a box of 600,000 nodes), and
    the pieces' filter over the gathered tetrahedra 0.05 s more."""
    syz, sz = ny * nz, nz
    corner = np.array([0, 1, sz, sz + 1, syz, syz + 1, syz + sz, syz + sz + 1])
    out = np.empty((0, 4), np.int64)
    for fill in (False, True):
        t = 0
        for i in range(nx - 1):
            for j in range(ny - 1):
                for k in range(nz - 1):
                    c = i * syz + j * sz + k
                    mixed = False
                    for q in range(1, 8):
                        if lab[c + corner[q]] != lab[c]:
                            mixed = True
                            break
                    if not mixed:
                        continue
                    for a in range(6):
                        if pieces_only and _pieces_in(lab, c, kuhn[a]) < 2:
                            continue
                        if fill:
                            for b in range(4):
                                out[t, b] = c + kuhn[a, b]
                        t += 1
        if not fill:
            out = np.empty((t, 4), np.int64)
    return out


class _FaceKeys:
    """One integer per face of a tetrahedron of the grid (three nodes of one cube): its least node id times
    256 and the two others' offsets from it, each one of the 13 positive differences of two corners of a
    cube, as codes. (The ids themselves, ``(a n + b) n + c``, overflow 64 bits beyond two million nodes: a
    thin plank's grid.)"""

    def __init__(self, shape):
        d = np.array(list(np.ndindex(3, 3, 3))) - 1
        step = d @ np.array([shape[1] * shape[2], shape[2], 1])
        self.offsets = np.unique(step[step > 0])

    def encode(self, ids: np.ndarray) -> np.ndarray:
        ids = np.sort(ids, axis=-1).astype(np.int64)
        code = np.searchsorted(self.offsets, ids[:, 1:] - ids[:, :1])
        return ids[:, 0] * 256 + code[:, 0] * 16 + code[:, 1]

    def decode(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        a = keys // 256
        return a, a + self.offsets[(keys // 16) % 16], a + self.offsets[keys % 16]


class _NodePoints:
    """The points of grid nodes by flat id, ``nodes[ids]`` of any shape (``ids.shape + (3,)``): a box's
    nodes are many more than the contour asks about."""

    def __init__(self, origin, spacing, shape):
        self.origin, self.spacing = np.asarray(origin, np.float64), np.asarray(spacing, np.float64)
        self.shape = shape

    def __getitem__(self, ids) -> np.ndarray:
        return self.origin + np.stack(np.unravel_index(ids, self.shape), -1) * self.spacing


_PAIRS = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
_FACES = [(0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)]


def _interfaces(tets: np.ndarray, lab: np.ndarray, n_nodes: int, faces: _FaceKeys):
    """The points of the interfaces inside every tetrahedron (Wu and Sullivan's multi-material marching
    tetrahedra), each tagged with the interface it lies on.

    Between two labels A < B of a tetrahedron the interface polygon has the points of its edges whose
    ends carry A and B, of its faces that carry A, B and a third label, and its own point when it carries
    four labels (3 or 4 points). Returns, per tagged point: the tetrahedron, A, B, the point's kind
    (0 edge, 1 face, 2 tetrahedron) and key (the sorted node ids of an edge, ``faces``' key of a face, or the
    tetrahedron).
    """
    L = lab[tets]  # (t, 4)
    t_all = np.arange(len(tets))
    rec = []
    for i, j in _PAIRS:  # edges: one interface, their ends' labels
        a, b = L[:, i], L[:, j]
        sel = a != b
        u, v = tets[sel, i], tets[sel, j]
        rec.append((t_all[sel], np.minimum(a, b)[sel], np.maximum(a, b)[sel], np.zeros(sel.sum(), np.int64),
                    np.minimum(u, v) * n_nodes + np.maximum(u, v)))
    for f in _FACES:  # faces with three labels: the three interfaces between them
        la = L[:, list(f)]
        ls = np.sort(la, axis=1)
        sel = (ls[:, 0] != ls[:, 1]) & (ls[:, 1] != ls[:, 2])
        key = faces.encode(tets[sel][:, list(f)])
        for x, y in ((0, 1), (0, 2), (1, 2)):
            rec.append((t_all[sel], ls[sel, x], ls[sel, y], np.ones(sel.sum(), np.int64), key))
    Ls = np.sort(L, axis=1)
    four = (Ls[:, 0] != Ls[:, 1]) & (Ls[:, 1] != Ls[:, 2]) & (Ls[:, 2] != Ls[:, 3])
    for x, y in _PAIRS:
        rec.append((t_all[four], Ls[four, x], Ls[four, y], np.full(four.sum(), 2, np.int64), t_all[four]))
    return [np.concatenate(c) for c in zip(*rec)]


def _mean_preferring(P: np.ndarray, groups: np.ndarray, prefer: np.ndarray) -> np.ndarray:
    """Per row of ``groups`` (crossing ids), the mean of its preferred crossings, or of all when it has
    none."""
    if not len(groups):
        return np.zeros((0, 3))
    w = prefer[groups].astype(np.float64)
    w[w.sum(axis=1) == 0] = 1.0
    return np.einsum("gk,gki->gi", w, P[groups]) / w.sum(axis=1)[:, None]


def _positions(crossing, nodes, lab, edge_keys, face_keys, tet_ids, tets, n_nodes, faces: _FaceKeys):
    """Points of the edges (``crossing``, kept :data:`_NODE_GAP` from the nodes), faces and tetrahedra
    (the mean of their edges' crossings, of those on B where they have some: :func:`_mean_preferring`)."""
    u, v = edge_keys // n_nodes, edge_keys % n_nodes
    P0, P1 = nodes[u], nodes[v]
    t = np.asarray(crossing(P0, P1, lab[u], lab[v]), np.float64)
    # no point on a node: a triangle with two points there would have no area
    t = np.clip(t, _NODE_GAP, 1.0 - _NODE_GAP)
    PE = P0 + t[:, None] * (P1 - P0)

    def edge(x, y):  # the crossing ids of edges x - y (edge_keys is sorted)
        return np.searchsorted(edge_keys, np.minimum(x, y) * n_nodes + np.maximum(x, y))

    a, b, c = faces.decode(face_keys)
    Fg = np.stack([edge(a, b), edge(a, c), edge(b, c)], 1)
    # a tetrahedron with four labels: its six edges all cross
    T = tets[tet_ids]
    Tg = np.stack([edge(T[:, i], T[:, j]) for i, j in _PAIRS], 1).reshape(-1, 6)
    outside = (lab[u] == 0) | (lab[v] == 0)
    return PE, _mean_preferring(PE, Fg, outside), _mean_preferring(PE, Tg, outside)


@numba.njit(cache=True)
def _around_axes(index, first, size, corners, corner_labels, A, B, Xo):
    """``index`` (point ids grouped by polygon: ``first`` and ``size`` per polygon) with each polygon's
    points in counter-clockwise order around its axis, from the mean of its tetrahedron's corners
    ``corners`` ``(p, 4, 3)`` labelled ``A`` to the mean of those labelled ``B`` (``corner_labels``
    ``(p, 4)``), as seen at the points ``Xo``: their
    angles about the polygon's centre in the frame ``e1 = axis x helper``, ``e2 = axis x e1``, ties in the
    order given. One pass per polygon (the same NumPy steps over gathered copies of every point took half
    the contour's time on the collapsing wall)."""
    out = index.copy()
    ang = np.empty(4)
    ids = np.empty(4, np.int64)
    for g in range(first.shape[0]):
        f, m = first[g], size[g]
        sum_a = np.zeros(3)
        sum_b = np.zeros(3)
        na = nb = 0
        for b in range(4):
            la = corner_labels[g, b]
            na += la == A[g]
            nb += la == B[g]
            for x in range(3):
                sum_a[x] += corners[g, b, x] * (la == A[g])
                sum_b[x] += corners[g, b, x] * (la == B[g])
        axis = sum_b / nb - sum_a / na
        length = np.sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2])
        if abs(axis[0]) < 0.9 * length:
            hx, hy, hz = 1.0, 0.0, 0.0
        else:
            hx, hy, hz = 0.0, 1.0, 0.0
        e1x = axis[1] * hz - axis[2] * hy
        e1y = axis[2] * hx - axis[0] * hz
        e1z = axis[0] * hy - axis[1] * hx
        e2x = axis[1] * e1z - axis[2] * e1y
        e2y = axis[2] * e1x - axis[0] * e1z
        e2z = axis[0] * e1y - axis[1] * e1x
        cx = cy = cz = 0.0
        for k in range(m):
            i = index[f + k]
            cx += Xo[i, 0]
            cy += Xo[i, 1]
            cz += Xo[i, 2]
        cx, cy, cz = cx / m, cy / m, cz / m
        for k in range(m):
            i = index[f + k]
            qx, qy, qz = Xo[i, 0] - cx, Xo[i, 1] - cy, Xo[i, 2] - cz
            ang[k] = np.arctan2(qx * e2x + qy * e2y + qz * e2z, qx * e1x + qy * e1y + qz * e1z)
            ids[k] = i
        for k in range(1, m):  # insertion sort: stable, and a polygon has 3 or 4 points
            a, i = ang[k], ids[k]
            j = k - 1
            while j >= 0 and ang[j] > a:
                ang[j + 1], ids[j + 1] = ang[j], ids[j]
                j -= 1
            ang[j + 1], ids[j + 1] = a, i
        for k in range(m):
            out[f + k] = ids[k]
    return out


def contour_labels(label: np.ndarray, origin, spacing, crossing, pieces_only: bool = False,
                   order_by_points: bool = False) -> LabelContour:
    """The interfaces between the labels of a grid (module notes).

    ``label`` is ``(nx, ny, nz)`` int, 0 outside the object and ``p + 1`` in
    piece ``p``, on the nodes ``origin + (i, j, k) * spacing``.
    ``crossing(P0, P1, la, lb)`` gives, per grid edge from ``P0`` (label ``la``)
    to ``P1`` (label ``lb != la``), where along it (0 at ``P0``, 1 at ``P1``)
    the interface crosses it. ``pieces_only`` contours only the tetrahedra
    that hold two pieces or more: the fracture triangles are the same, and of B
    only the polygons beside them are made (and their edges' crossings asked for).
    A polygon's points are put in order around it by where the grid's edges,
    faces and tetrahedra have their middles, or, with ``order_by_points``, by
    the points themselves (crossings far from their edges' middles would
    otherwise fold a polygon over itself).
    """
    shape = label.shape
    lab = label.ravel()
    n_nodes = lab.size
    tets = _mixed_tets(label, pieces_only)
    if not len(tets):
        none = np.zeros((0, 3), np.int64)
        return LabelContour(np.zeros((0, 3)), none, np.zeros((0, 2), np.int64), none, np.zeros(0, np.int64))
    faces = _FaceKeys(shape)
    tet, A, B, kind, val = _interfaces(tets, lab, n_nodes, faces)
    edge_keys, face_keys, tet_ids = (np.unique(val[kind == k]) for k in range(3))
    nodes = _NodePoints(origin, spacing, shape)
    PE, PF, PT = _positions(crossing, nodes, lab, edge_keys, face_keys, tet_ids, tets, n_nodes, faces)
    X = np.concatenate([PE, PF, PT])
    index = np.empty(len(val), np.int64)
    start = 0
    for k, table in enumerate((edge_keys, face_keys, tet_ids)):
        sel = kind == k
        index[sel] = start + np.searchsorted(table, val[sel])
        start += len(table)
    if order_by_points:
        Xo = X
    else:  # the points' places before they were moved onto the surfaces, for the order around each polygon
        eu, ev = edge_keys // n_nodes, edge_keys % n_nodes
        fa, fb, fc = faces.decode(face_keys)
        Xo = np.concatenate([0.5 * (nodes[eu] + nodes[ev]), (nodes[fa] + nodes[fb] + nodes[fc]) / 3,
                             nodes[tets[tet_ids]].mean(axis=1)])

    # group the tagged points by polygon (tetrahedron, A, B)
    n_lab = int(lab.max()) + 1
    poly = (tet * n_lab + A) * n_lab + B
    order = np.argsort(poly, kind="stable")
    poly, index, tet, A, B = poly[order], index[order], tet[order], A[order], B[order]
    first = np.flatnonzero(np.r_[True, poly[1:] != poly[:-1]])
    size = np.diff(np.r_[first, len(poly)])
    if (size < 3).any() or (size > 4).any():
        raise AssertionError("marching tetrahedra: an interface polygon without 3 or 4 points")
    corners = tets[tet[first]]
    index = _around_axes(index, first, size, nodes[corners], lab[corners], A[first], B[first], np.ascontiguousarray(Xo))
    tris, tri_poly = [], []
    for m in (3, 4):
        sel = np.flatnonzero(size == m)
        if not len(sel):
            continue
        ids = index[first[sel, None] + np.arange(m)]  # (p, m), counter-clockwise around the axis
        for j in range(1, m - 1):
            tris.append(ids[:, [0, j, j + 1]])
            tri_poly.append(sel)
    T = np.concatenate(tris)
    tp = np.concatenate(tri_poly)
    TA, TB = A[first][tp], B[first][tp]
    outside = TA == 0  # (0, piece): B, facing the piece; turn it to face the outside
    T[outside] = T[outside][:, ::-1]
    fracture = ~outside
    return LabelContour(X, T[fracture], np.stack([TA, TB], 1)[fracture] - 1, T[outside], TB[outside] - 1)
