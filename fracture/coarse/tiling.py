"""From closed pieces that tile an object to its surface B and one shared fracture surface, through a label grid.

Real exports (Blender's Cell Fracture) give every piece its own closed
surface, and the pieces do not tile the object exactly: neighbouring pieces
overlap or leave slits of about 1e-4 of the size, split their common faces
differently, and their outer faces join with T-junctions. Matching faces
geometrically depends on tolerances that such input always exceeds
somewhere. This module does not match faces; it labels space and contours the labels:

1. **Labels.** On a grid of cubic cells every node gets the piece whose
   winding number (libigl's fast winding number of the piece's triangles) is
   largest there, or 0 outside the object: a node is inside when the pieces'
   winding numbers sum to more than 1/2, so a node in a slit between two
   pieces (each about 1/2) is inside and an overlap goes to one of them.
   Nodes of slits a closing by one cell fills, within a quarter cell of two
   pieces, take the nearer piece. Two pieces overlapping by more than a fifth
   of a cell on average are refused (a moved piece); a piece with no node is
   left out, with a note.
2. **Multi-material marching tetrahedra** (Wu and Sullivan 2003). Each cube
   of the grid whose corners carry several labels is split into Kuhn's six
   tetrahedra; between two labels of a tetrahedron the interface is the
   polygon through its edges' crossings, its three-label faces' points and,
   with four labels, its own point. Between two pieces this is a fracture
   polygon (its normal points into the second), between a piece and the
   outside a polygon of B. Tetrahedra have no ambiguous cases: B is a closed,
   oriented 2-manifold and the sheets meet each other and B along shared
   edges. Crossings lie on the surfaces (bisection of the winding numbers
   along the edge); points of faces and tetrahedra are means of their
   crossings (those on B when there are some, so B keeps its plane where a
   sheet meets it).
3. **Coarsening.** Each sheet (all triangles between one pair of pieces) is
   flat for Cell Fracture and is coarsened by pymeshlab's quadric edge
   collapse with its rim kept vertex for vertex; a sheet whose coarsened
   triangles would cross another keeps its contoured ones.
4. **Pinholes** (:mod:`fracture.coarse.pinholes`): a sheet's closed boundary
   curve on B smaller than a tenth of a cell is collapsed to a point, just
   inside B, with B's island inside it.

Written here because no library at hand (libigl, pymeshlab, Open3D,
scikit-image) contours a grid of several labels into one conforming surface.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import igl
import numpy as np
from scipy import ndimage

from fracture.coarse.pinholes import PINHOLE, close_pinholes
from fracture.errors import InputError
from fracture.tolerances import tol
from fracture.mesh.topology import closed_oriented, fan, unique_edges

# Cells along the object's largest extent.
DEFAULT_CELLS = 32
# Two pieces may overlap by this much on average (grid cells): Cell Fracture's pieces overlap by about
# 1e-4 of the size (up to 0.08 cells measured), a piece moved by 1/40 of the size by 0.4 cells.
_OVERLAP = 0.2
# ... over at least this many grid nodes (a node or two inside two small pieces is noise).
_OVERLAP_NODES = 10
# Bisection steps for an edge's crossing (its place to 2^-this of a cell).
_BISECTIONS = 12
# Crossings keep this fraction of the edge from its nodes.
_NODE_GAP = 0.02


@dataclass
class LabelTiling:
    """The result of :func:`label_tiling`.

    Attributes
    ----------
    V : (n, 3) float
        Vertices of both surfaces (the cells' vertices).
    fracture_F : (m, 3) int
        Fracture triangles; the normal points from ``sides[:, 0]`` into ``sides[:, 1]``.
    sides : (m, 2) int
        Piece behind and in front of each fracture triangle.
    exterior_F : (k, 3) int
        Triangles of B, outward.
    exterior_piece : (k,) int
        The piece each B triangle belongs to.
    kept : (pieces,) int
        The input pieces that take part (all but those thinner than a cell); pieces are numbered in this order.
    cells : int
        Cells along the largest extent of the grid that was used.
    notes : list of str
    """

    V: np.ndarray
    fracture_F: np.ndarray
    sides: np.ndarray
    exterior_F: np.ndarray
    exterior_piece: np.ndarray
    kept: np.ndarray
    cells: int
    notes: list = field(default_factory=list)


def _piece_triangles(V: np.ndarray, polygons: list[list[np.ndarray]]) -> list[tuple[np.ndarray, np.ndarray]]:
    out = []
    for polys in polygons:
        T, _ = fan([np.asarray(f) for f in polys])
        used, inv = np.unique(T, return_inverse=True)
        out.append((np.ascontiguousarray(V[used], np.float64), np.ascontiguousarray(inv.reshape(-1, 3), np.int64)))
    return out


def _labels(pieces, nodes: np.ndarray, shape, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Label of every node (0 outside, p + 1 in piece p), the nodes that were filled (module notes), the
    nodes inside two pieces or more as pairs ``(k, 2)`` of the two most inside pieces, and the filled
    nodes as pairs of the two pieces nearest them."""
    W = np.zeros((len(pieces), len(nodes)))
    for p, (PV, PF) in enumerate(pieces):
        lo, hi = PV.min(axis=0), PV.max(axis=0)
        pad = 0.5 * (hi - lo).max()  # winding numbers fall off outside the box: only nearby nodes matter
        near = np.all((nodes >= lo - pad) & (nodes <= hi + pad), axis=1)
        W[p, near] = igl.fast_winding_number(PV, PF, nodes[near])
    in_two = np.flatnonzero((W > 0.5).sum(axis=0) >= 2)
    top2 = np.sort(np.argsort(-W[:, in_two], axis=0)[:2].T, axis=1)
    inside = (W.sum(axis=0) > 0.5).reshape(shape)
    label = np.where(inside.ravel(), W.argmax(axis=0) + 1, 0).reshape(shape)
    # fill slits between pieces: nodes that a closing by one cell fills and that lie within a quarter
    # cell of two different pieces; they take the nearer piece
    closed = ndimage.binary_closing(inside, structure=ndimage.generate_binary_structure(3, 1), border_value=0)
    filled = closed & ~inside
    gaps = np.zeros((0, 2), np.int64)
    if filled.any() and len(pieces) > 1:
        at = np.flatnonzero(filled.ravel())
        D = np.stack([igl.point_mesh_squared_distance(nodes[at], PV, PF)[0] for PV, PF in pieces])
        two = np.argsort(D, axis=0)[:2]
        d2 = np.take_along_axis(D, two, axis=0)
        slit = d2[1] < (0.25 * h) ** 2
        filled.ravel()[at[~slit]] = False
        label.ravel()[at[slit]] = two[0, slit] + 1
        gaps = np.sort(two[:, slit].T, axis=1)
    else:
        filled[:] = False
    return label, filled, top2, gaps


# Kuhn's split of a cube into 6 tetrahedra along its diagonal 000-111: every path from corner 000 to 111
# along the axes, corners as bit offsets (x, y, z). Neighbouring cubes split their common face alike.
_KUHN = np.array([[[0, 0, 0], a, a + b, [1, 1, 1]] for a, b in [
    (np.eye(3, dtype=int)[i], np.eye(3, dtype=int)[j]) for i in range(3) for j in range(3) if i != j]])


def _mixed_tets(label: np.ndarray) -> np.ndarray:
    """Node ids ``(t, 4)`` of the Kuhn tetrahedra of every cube whose corners carry more than one label."""
    shape = label.shape
    corners = [label[i:shape[0] - 1 + i, j:shape[1] - 1 + j, k:shape[2] - 1 + k]
               for i in (0, 1) for j in (0, 1) for k in (0, 1)]
    lo, hi = np.minimum.reduce(corners), np.maximum.reduce(corners)
    cube = np.argwhere(lo != hi)  # (c, 3)
    node = cube[:, None, None, :] + _KUHN[None]  # (c, 6, 4, 3)
    return np.ravel_multi_index(tuple(np.moveaxis(node, -1, 0)), shape).reshape(-1, 4)


def _key(ids: np.ndarray, n: int) -> np.ndarray:
    """One integer per sorted tuple of node ids (pairs or triples)."""
    ids = np.sort(ids, axis=-1)
    out = ids[..., 0].astype(np.int64)
    for c in range(1, ids.shape[-1]):
        out = out * n + ids[..., c]
    return out


_PAIRS = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
_FACES = [(0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)]


def _interfaces(tets: np.ndarray, lab: np.ndarray, n_nodes: int):
    """The points of the interfaces inside every tetrahedron (Wu and Sullivan's multi-material marching
    tetrahedra), each tagged with the interface it lies on.

    Between two labels A < B of a tetrahedron the interface polygon has the points of its edges whose
    ends carry A and B, of its faces that carry A, B and a third label, and its own point when it carries
    four labels (3 or 4 points). Returns, per tagged point: the tetrahedron, A, B, the point's kind
    (0 edge, 1 face, 2 tetrahedron) and key (sorted node ids, or the tetrahedron).
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
        key = _key(tets[sel][:, list(f)], n_nodes)
        for x, y in ((0, 1), (0, 2), (1, 2)):
            rec.append((t_all[sel], ls[sel, x], ls[sel, y], np.ones(sel.sum(), np.int64), key))
    Ls = np.sort(L, axis=1)
    four = (Ls[:, 0] != Ls[:, 1]) & (Ls[:, 1] != Ls[:, 2]) & (Ls[:, 2] != Ls[:, 3])
    for x, y in _PAIRS:
        rec.append((t_all[four], Ls[four, x], Ls[four, y], np.full(four.sum(), 2, np.int64), t_all[four]))
    return [np.concatenate(c) for c in zip(*rec)]


def _positions(pieces, nodes, lab, h, edge_keys, face_keys, tet_ids, tets, n_nodes):
    """Points of the edges (where the edge leaves the piece at its inside end: the piece's winding
    number crosses 1/2, found by bisection), faces and tetrahedra (the mean of their edges' crossings,
    of those on B where they have some: :func:`_mean_preferring`)."""
    u, v = edge_keys // n_nodes, edge_keys % n_nodes
    la, lb = lab[u], lab[v]
    inner = np.where(la > 0, u, v)  # the end inside the piece whose surface the edge crosses
    outer = np.where(la > 0, v, u)
    owner = np.where(la > 0, la, lb) - 1
    P0, P1 = nodes[inner], nodes[outer]
    # the crossing: where the inside end's piece stops winding more than the outside end's (another
    # piece), or where the pieces together stop winding more than 1/2 (the outside), by bisection
    other = np.where(la > 0, lb, la) - 1  # -1: outside
    lo, hi = np.zeros(len(u)), np.ones(len(u))
    boxes = [(PV.min(axis=0) - 2 * h, PV.max(axis=0) + 2 * h) for PV, _ in pieces]
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        X = P0 + mid[:, None] * (P1 - P0)
        w_in, w_out, total = np.zeros(len(u)), np.zeros(len(u)), np.zeros(len(u))
        for p, (PV, PF) in enumerate(pieces):
            near = np.flatnonzero(np.all((X >= boxes[p][0]) & (X <= boxes[p][1]), axis=1))
            if not len(near):
                continue
            w = igl.fast_winding_number(PV, PF, X[near])
            total[near] += w
            w_in[near[owner[near] == p]] = w[owner[near] == p]
            w_out[near[other[near] == p]] = w[other[near] == p]
        inside = np.where(other >= 0, w_in > w_out, total > 0.5)
        lo, hi = np.where(inside, mid, lo), np.where(inside, hi, mid)
    t = 0.5 * (lo + hi)
    # no point on a node: a triangle with two points there would have no area
    t = np.clip(t, _NODE_GAP, 1.0 - _NODE_GAP)
    PE = P0 + t[:, None] * (P1 - P0)

    def edge(x, y):  # the crossing ids of edges x - y (edge_keys is sorted)
        return np.searchsorted(edge_keys, np.minimum(x, y) * n_nodes + np.maximum(x, y))

    a, b, c = face_keys // (n_nodes * n_nodes), (face_keys // n_nodes) % n_nodes, face_keys % n_nodes
    Fg = np.stack([edge(a, b), edge(a, c), edge(b, c)], 1)
    # a tetrahedron with four labels: its six edges all cross
    T = tets[tet_ids]
    Tg = np.stack([edge(T[:, i], T[:, j]) for i, j in _PAIRS], 1).reshape(-1, 6)
    outside = (lab[u] == 0) | (lab[v] == 0)
    return PE, _mean_preferring(PE, Fg, outside), _mean_preferring(PE, Tg, outside)


def _mean_preferring(P: np.ndarray, groups: np.ndarray, prefer: np.ndarray) -> np.ndarray:
    """Per row of ``groups`` (crossing ids), the mean of its preferred crossings, or of all when it has
    none."""
    if not len(groups):
        return np.zeros((0, 3))
    w = prefer[groups].astype(np.float64)
    w[w.sum(axis=1) == 0] = 1.0
    return np.einsum("gk,gki->gi", w, P[groups]) / w.sum(axis=1)[:, None]


def _contour(pieces, origin, h, shape, label):
    lab = label.ravel()
    n_nodes = lab.size
    tets = _mixed_tets(label)
    tet, A, B, kind, val = _interfaces(tets, lab, n_nodes)
    edge_keys, face_keys, tet_ids = (np.unique(val[kind == k]) for k in range(3))
    grid = np.stack(np.unravel_index(np.arange(n_nodes), shape), 1)
    nodes = origin + grid * h
    PE, PF, PT = _positions(pieces, nodes, lab, h, edge_keys, face_keys, tet_ids, tets, n_nodes)
    X = np.concatenate([PE, PF, PT])
    index = np.empty(len(val), np.int64)
    start = 0
    for k, table in enumerate((edge_keys, face_keys, tet_ids)):
        sel = kind == k
        index[sel] = start + np.searchsorted(table, val[sel])
        start += len(table)
    # the points' places before they were moved onto the surfaces, for the order around each polygon
    eu, ev = edge_keys // n_nodes, edge_keys % n_nodes
    fa, fb, fc = face_keys // (n_nodes * n_nodes), (face_keys // n_nodes) % n_nodes, face_keys % n_nodes
    X0 = np.concatenate([0.5 * (nodes[eu] + nodes[ev]), (nodes[fa] + nodes[fb] + nodes[fc]) / 3,
                         nodes[tets[tet_ids]].mean(axis=1)])

    # group the tagged points by polygon (tetrahedron, A, B)
    n_lab = int(lab.max()) + 1
    poly = (tet * n_lab + A) * n_lab + B
    order = np.argsort(poly, kind="stable")
    poly, index, tet, A, B = poly[order], index[order], tet[order], A[order], B[order]
    first = np.flatnonzero(np.r_[True, poly[1:] != poly[:-1]])
    size = np.diff(np.r_[first, len(poly)])
    # the axis of each polygon: from its tetrahedron's A corners to its B corners
    corner = nodes[tets[tet[first]]]  # (p, 4, 3)
    cl = lab[tets[tet[first]]]
    isA = (cl == A[first, None])[..., None]
    isB = (cl == B[first, None])[..., None]
    axis = (corner * isB).sum(1) / isB.sum(1) - (corner * isA).sum(1) / isA.sum(1)
    helper = np.where((np.abs(axis[:, 0]) < 0.9 * np.linalg.norm(axis, axis=1))[:, None], [1.0, 0.0, 0.0],
                      [0.0, 1.0, 0.0])
    e1 = np.cross(axis, helper)
    e2 = np.cross(axis, e1)
    owner = np.repeat(np.arange(len(first)), size)
    Q = X0[index] - np.add.reduceat(X0[index], first)[owner] / size[owner, None]
    ang = np.arctan2(np.einsum("ij,ij->i", Q, e2[owner]), np.einsum("ij,ij->i", Q, e1[owner]))
    order = np.lexsort((ang, owner))
    index = index[order]
    tris, tri_poly = [], []
    for m in (3, 4):
        sel = np.flatnonzero(size == m)
        if not len(sel):
            continue
        ids = index[first[sel, None] + np.arange(m)]  # (p, m), counter-clockwise around the axis
        for j in range(1, m - 1):
            tris.append(ids[:, [0, j, j + 1]])
            tri_poly.append(sel)
    if (size < 3).any() or (size > 4).any():
        raise AssertionError("marching tetrahedra: an interface polygon without 3 or 4 points")
    T = np.concatenate(tris)
    tp = np.concatenate(tri_poly)
    TA, TB = A[first][tp], B[first][tp]
    outside = TA == 0  # (0, piece): B, facing the piece; turn it to face the outside
    T[outside] = T[outside][:, ::-1]
    fracture = ~outside
    return X, T[fracture], np.stack([TA, TB], 1)[fracture] - 1, T[outside], TB[outside] - 1


def _simplify_sheets(X: np.ndarray, FF: np.ndarray, sides: np.ndarray):
    """Coarsen every sheet (the triangles between one pair of pieces) with pymeshlab's quadric edge
    collapse, keeping its boundary (its junctions with other sheets and its curve on B) vertex for
    vertex, so the sheets still meet each other and B exactly. Cell Fracture's sheets are flat
    (bisector planes of its cells): a few triangles per boundary vertex describe them.

    Returns the new points (``X`` followed by the sheets' new inner vertices) and triangles.
    """
    import pymeshlab

    n = len(X)
    out_X, out_F, out_S = [X], [np.zeros((0, 3), np.int64)], [np.zeros((0, 2), np.int64)]
    pair = sides[:, 0] * (sides.max(initial=0) + 1) + sides[:, 1]
    for k in np.unique(pair):
        sel = np.flatnonzero(pair == k)
        used, inv = np.unique(FF[sel], return_inverse=True)
        local = inv.reshape(-1, 3)
        e, c = unique_edges(local)
        rim = np.unique(e[c == 1])
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(X[used], local))
        ms.meshing_decimation_quadric_edge_collapse(
            targetfacenum=max(2 * len(rim), 4), preserveboundary=True, boundaryweight=1000.0, preservenormal=True,
            preservetopology=True, planarquadric=True, qualitythr=0.3, autoclean=False)
        m = ms.current_mesh()
        VD, FD = m.vertex_matrix(), m.face_matrix().astype(np.int64)
        # kept vertices sit exactly where they were: back to their global ids, the others are new
        lookup = {tuple(p): g for p, g in zip(X[used].tolist(), used.tolist())}
        ids = np.empty(len(VD), np.int64)
        fresh = []
        for i, p in enumerate(VD.tolist()):
            g = lookup.get(tuple(p))
            if g is None:
                g = n
                n += 1
                fresh.append(p)
            ids[i] = g
        kept_rim = np.isin(used[rim], ids)
        if not kept_rim.all():
            raise AssertionError("sheet simplification moved a boundary vertex")
        out_X.append(np.asarray(fresh, np.float64).reshape(-1, 3))
        out_F.append(ids[FD])
        out_S.append(np.repeat(sides[sel[:1]], len(FD), axis=0))
    return np.concatenate(out_X), np.concatenate(out_F), np.concatenate(out_S)


def _simplified(X: np.ndarray, FF: np.ndarray, sides: np.ndarray):
    """:func:`_simplify_sheets`, except for sheets whose coarsened triangles would cross another sheet:
    those keep their triangles from the contouring (which never cross)."""
    from fracture.mesh.intersect import self_intersections

    keep = np.zeros(len(FF), bool)
    base = sides.max(initial=0) + 1
    pair = sides[:, 0] * base + sides[:, 1]
    for _ in range(4):
        XS, FS, SS = _simplify_sheets(X, FF[~keep], sides[~keep])
        XS_all = XS
        F_all = np.concatenate([FS, FF[keep]])
        S_all = np.concatenate([SS, sides[keep]])
        count, pairs = self_intersections(XS_all, F_all, report=100000)
        if not count:
            return XS_all, F_all, S_all
        hit = np.unique(S_all[pairs.ravel()][:, 0] * base + S_all[pairs.ravel()][:, 1])
        keep |= np.isin(pair, hit)
    return X, FF, sides


def _check_tiling(label, overlap, gaps, names, h, where) -> str | None:
    """Refuse pieces that overlap by more than :data:`_OVERLAP` cells on average (the overlap's volume
    over the smaller piece's volume to the power 2/3, an area); returns a note on the widest slit that
    was filled, or None."""
    count = np.bincount(label.ravel(), minlength=len(names) + 1)[1:].astype(np.float64)
    note = None
    for what, pairs in (("overlap by", overlap), ("leave a slit of", gaps)):
        if not len(pairs):
            continue
        pairs, n = np.unique(pairs, axis=0, return_counts=True)
        thick = n / np.maximum(np.minimum(count[pairs[:, 0]], count[pairs[:, 1]]), 1.0) ** (2 / 3)
        worst = int(np.argmax(thick))
        a, b = pairs[worst]
        said = (f"pieces {names[a]!r} and {names[b]!r} {what} about {n[worst] * h ** 3:.3g} cubic units (on "
                f"average {thick[worst] * h:.3g} thick)")
        if what == "overlap by" and thick[worst] > _OVERLAP and n[worst] >= _OVERLAP_NODES:
            raise InputError(f"{where}{said}; the pieces must tile the object in the rest pose (is a piece moved?)")
        if what != "overlap by":
            note = said
    return note


def label_tiling(V: np.ndarray, polygons: list[list[np.ndarray]], names: list[str], source: str = "",
                 cells: int = DEFAULT_CELLS) -> LabelTiling:
    """B and the fracture surface of pieces that tile an object (module notes).

    Parameters
    ----------
    V : (n, 3) float
        Rest-pose vertices.
    polygons : list (per piece) of list of (k,) int
        Each piece's faces, n-gons allowed.
    names : list of str
        Piece names, for messages.
    source : str
        File the rest pose came from, for messages.
    cells : int
        Grid cells along the object's largest extent (doubled while B is not a manifold).
    """
    where = f"{source}: " if source else ""
    V = np.asarray(V, np.float64)
    pieces = _piece_triangles(V, polygons)
    lo, hi = V.min(axis=0), V.max(axis=0)
    for n in (cells, 2 * cells):  # a piece thinner than a cell everywhere: try once at half the cell size
        h = float((hi - lo).max()) / n
        origin = lo - 1.5 * h
        shape = tuple(int(s) for s in np.ceil((hi - lo) / h).astype(int) + 4)
        grid = np.stack(np.meshgrid(*[np.arange(s) for s in shape], indexing="ij"), -1).reshape(-1, 3)
        label, filled, overlap, gaps = _labels(pieces, origin + grid * h, shape, h)
        present = np.bincount(label.ravel(), minlength=len(pieces) + 1)[1:] > 0
        if present.all():
            break
    notes: list[str] = []
    for p, (PV, PF) in enumerate(pieces):  # closed: the area vectors of its triangles cancel
        vec = np.cross(PV[PF[:, 1]] - PV[PF[:, 0]], PV[PF[:, 2]] - PV[PF[:, 0]])
        hole = float(np.linalg.norm(vec.sum(axis=0)))
        if hole > tol.closure * float(np.linalg.norm(vec, axis=1).sum()):
            notes.append(f"piece {names[p]!r} is not a closed surface (its faces leave a hole of about "
                         f"{0.5 * hole:.3g} square units): its inside was taken from its winding number")
    widest = _check_tiling(label, overlap, gaps, names, h, where)
    if filled.any():
        k = int(filled.sum())
        notes.append(f"filled {k} grid nodes ({k * h ** 3:.3g} cubic units) of slits and dents between "
                     f"pieces that do not quite tile the object; the widest: {widest}")
    kept = np.flatnonzero(present)
    if len(kept) < len(pieces):
        notes.append("left out pieces thinner than a grid cell ({:.3g}) everywhere: {}".format(
            h, ", ".join(repr(names[p]) for p in np.flatnonzero(~present))))
    X, FF, sides, BF, bpiece = _contour(pieces, origin, h, shape, label)
    X, FF, sides = _simplified(X, FF, sides)
    X, FF, sides, BF, bpiece, pinholes = close_pinholes(X, FF, sides, BF, bpiece, h)
    if pinholes:
        notes.append(f"closed {pinholes} pinhole{'s' if pinholes > 1 else ''}: a piece reached the surface through "
                     f"a hole in a crack smaller than {PINHOLE:g} grid cells ({PINHOLE * h:.3g}); the crack now "
                     "ends just inside")
    if not closed_oriented(BF):
        raise AssertionError(f"{where}marching tetrahedra gave an outer surface that is not a closed 2-manifold")
    if not len(FF):
        raise InputError(f"{where}no two pieces touch: nothing to refine (is this a fractured object?)")
    renumber = np.full(len(pieces), -1)
    renumber[kept] = np.arange(len(kept))
    return LabelTiling(X, FF, renumber[sides], BF, renumber[bpiece], kept, n, notes)
