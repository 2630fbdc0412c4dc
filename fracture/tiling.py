"""From a set of closed pieces that tile an object to one shared fracture surface.

Real exports (Blender's Cell Fracture) give every piece its own closed surface.
Two neighbouring pieces cover their common region with faces of opposite
orientation, but split differently (T-junctions, other n-gons, coordinates
rounded to 6 decimals, and faces that are only nearly planar), so they cannot
be matched vertex for vertex. :func:`shared_surface` matches them
geometrically instead:

1. all corners are welded across pieces, and every corner that lies on an
   edge of another face is inserted into that edge (T-junctions removed);
2. a face is shared with another piece when points sampled on it lie on that
   piece's surface (libigl point-mesh distance, within a gap tolerance) and
   the surfaces face each other; a face shared with nobody is exterior;
3. the region between pieces A and B is taken from the faces of one of them
   (the lower index) and triangulated once, in the plane of each face, by a
   constrained Delaunay triangulation of its boundary (Triangle, no new
   points). Since every edge carries every corner on it, the triangulated
   regions and the exterior surface B meet vertex to vertex: the fracture
   surface is stored once with the two component ids of every triangle, and B
   is closed and shares the fracture surface's boundary vertices.

Written here because neither libigl nor pymeshlab matches overlapping faces of
polygon soups into a conforming, non-manifold surface with side labels.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import igl
import numpy as np
import triangle
from scipy.spatial import cKDTree

from fracture.errors import InputError
from fracture.tolerances import tol
from fracture.topology import directed_edge_face, fan, plane_basis, scatter_add, signed_volume, unique_edges, weld


@dataclass
class SharedSurface:
    """The result of :func:`shared_surface`.

    Attributes
    ----------
    V : (n, 3) float
        Welded points of both surfaces.
    fracture_F : (m, 3) int
        Fracture triangles; the normal points from ``sides[:, 0]`` into ``sides[:, 1]``.
    sides : (m, 2) int
        Piece behind and in front of each fracture triangle.
    exterior_F : (k, 3) int
        Triangles of the exterior surface B, outward.
    exterior_piece : (k,) int
        The piece each exterior triangle belongs to.
    piece_fracture_area : (pieces,) float
        Area of each piece's own faces that were found shared (for checks).
    notes : list of str
        Repairs that were made (closed tiny gaps).
    """

    V: np.ndarray
    fracture_F: np.ndarray
    sides: np.ndarray
    exterior_F: np.ndarray
    exterior_piece: np.ndarray
    piece_fracture_area: np.ndarray
    notes: list[str] = field(default_factory=list)


def polygon_normal_area(P: np.ndarray) -> tuple[np.ndarray, float]:
    """Newell normal (unit) and area of a (nearly) planar polygon ``(k, 3)``."""
    n = np.cross(P, np.roll(P, -1, axis=0)).sum(axis=0) * 0.5
    area = float(np.linalg.norm(n))
    return (n / area if area > 0 else n), area


def _insert_edge_points(polygons: list[np.ndarray], G: np.ndarray, tree: cKDTree, radius: float
                        ) -> list[np.ndarray]:
    """Every polygon with the points of ``G`` that lie on its edges inserted (in order along each edge).

    Zero-length edges (corners welded together) are dropped. One batched
    neighbour query for all edges of all polygons.
    """
    sizes = np.array([len(f) for f in polygons])
    a = np.concatenate(polygons).astype(np.int64)
    nxt = np.arange(len(a)) + 1
    ends = np.cumsum(sizes)
    nxt[ends - 1] = ends - sizes  # the last edge closes the polygon
    b = a[nxt]
    poly = np.repeat(np.arange(len(polygons)), sizes)
    edge = np.flatnonzero(a != b)
    A, B = G[a[edge]], G[b[edge]]
    length = np.linalg.norm(B - A, axis=1)
    cands = tree.query_ball_point((A + B) / 2, length / 2 + radius)
    counts = np.array([len(c) for c in cands])
    which = np.repeat(np.arange(len(edge)), counts)  # index into `edge`
    cand = np.concatenate([np.asarray(c, np.int64) for c in cands]) if len(which) else np.zeros(0, np.int64)
    AB = B[which] - A[which]
    t = np.einsum("ij,ij->i", G[cand] - A[which], AB) / length[which] ** 2
    dist = np.linalg.norm(G[cand] - (A[which] + t[:, None] * AB), axis=1)
    on = (dist <= radius) & (t > 0) & (t < 1) & (cand != a[edge][which]) & (cand != b[edge][which])
    # each polygon: per edge its start corner (t = -1) then its inserted points by t
    item_edge = np.concatenate([edge, edge[which[on]]])
    item_t = np.concatenate([np.full(len(edge), -1.0), t[on]])
    item_id = np.concatenate([a[edge], cand[on]])
    order = np.lexsort((item_t, item_edge))
    ids = item_id[order]
    per_poly = np.bincount(poly[item_edge], minlength=len(polygons))
    return np.split(ids, np.cumsum(per_poly)[:-1])


def _area_vectors(V: np.ndarray, polygons: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Area vectors of polygons (Newell: the sum over a fan), with the fan triangles and their polygon."""
    tris, owner = fan(polygons)
    A = V[tris[:, 0]]
    vec = scatter_add(owner, 0.5 * np.cross(V[tris[:, 1]] - A, V[tris[:, 2]] - A), len(polygons))
    return vec, tris, owner


def _triangulate_polygon(loop: np.ndarray, G: np.ndarray, where: str) -> np.ndarray:
    """Constrained Delaunay triangulation of a (nearly planar) polygon, oriented like it."""
    if len(loop) == 3:
        return loop[None, :]
    P = G[loop]
    n, _ = polygon_normal_area(P)
    u, v = plane_basis(n)
    XY = np.stack([(P - P[0]) @ u, (P - P[0]) @ v], 1)
    k = len(loop)
    segments = np.stack([np.arange(k), (np.arange(k) + 1) % k], 1)
    tri = triangle.triangulate({"vertices": XY, "segments": segments}, "pQ")
    if "triangles" not in tri or len(tri["vertices"]) != k:
        raise InputError(f"{where}cannot triangulate a face with corners {loop.tolist()} (it crosses itself)")
    T = loop[tri["triangles"]]
    nrm = np.cross(G[T[:, 1]] - G[T[:, 0]], G[T[:, 2]] - G[T[:, 0]])
    flip = nrm @ n < 0
    T[flip] = T[flip][:, ::-1]
    return T


def shared_surface(V: np.ndarray, polygons: list[list[np.ndarray]], names: list[str], source: str = "") -> SharedSurface:
    """Match the pieces' touching faces and build the conforming surfaces.

    Parameters
    ----------
    V : (n, 3) float
        Rest-pose vertices.
    polygons : list (per piece) of list of (k,) int
        Each piece's faces, n-gons allowed; each piece must be closed.
    names : list of str
        Piece names, for messages.
    source : str
        File the rest pose came from, for messages.

    Raises
    ------
    InputError
        A piece is not closed or inside out, two pieces overlap, or there is
        a gap between pieces wider than the repair tolerance.
    """
    where = f"{source}: " if source else ""
    V = np.asarray(V, np.float64)
    diag = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    n_pieces = len(polygons)

    # every piece closed (its area vectors cancel) and outward (positive volume)
    poly_piece = np.repeat(np.arange(n_pieces), [len(polys) for polys in polygons])
    vec, tris, owner = _area_vectors(V, [f for polys in polygons for f in polys])
    total = np.bincount(poly_piece, np.linalg.norm(vec, axis=1), minlength=n_pieces)
    hole = np.linalg.norm(scatter_add(poly_piece, vec, n_pieces), axis=1)
    A, B, C = V[tris[:, 0]], V[tris[:, 1]], V[tris[:, 2]]
    volumes = np.bincount(poly_piece[owner], np.einsum("ij,ij->i", A, np.cross(B, C)) / 6.0, minlength=n_pieces)
    for p in range(n_pieces):
        if total[p] <= tol.area * diag**2 or hole[p] > tol.closure * total[p]:
            raise InputError(f"{where}piece {names[p]!r} is not a closed surface (its faces leave a hole of "
                             f"about {hole[p]:.3g} square units)")
        if volumes[p] <= 0:
            raise InputError(f"{where}piece {names[p]!r} is inside out or flat (volume {volumes[p]:.3g})")

    # 1. weld corners across pieces, insert T-junction points into every edge
    G, label = weld(V, tol.weld * diag)
    moved = float(np.linalg.norm(V - G[label], axis=1).max())
    tree = cKDTree(G)
    loops = _insert_edge_points([label[f] for polys in polygons for f in polys], G, tree, tol.on_edge * diag)
    keep = np.array([len(loop) >= 3 for loop in loops], bool)
    vec = np.zeros((len(loops), 3))
    vec[keep] = _area_vectors(G, [loop for loop, k in zip(loops, keep) if k])[0]
    face_area = np.linalg.norm(vec, axis=1)
    keep &= face_area > tol.area * diag**2
    faces = [(p, loop) for p, loop, k in zip(poly_piece, loops, keep) if k]  # (piece, loop of welded ids)
    face_piece, face_area = poly_piece[keep], face_area[keep]

    # 2. which piece (if any) each face is shared with
    tris, tri_face = fan([loop for _, loop in faces])
    tri_piece = face_piece[tri_face]
    A, B, C = G[tris[:, 0]], G[tris[:, 1]], G[tris[:, 2]]
    tri_n = np.cross(B - A, C - A)
    tri_area = 0.5 * np.linalg.norm(tri_n, axis=1)
    tri_n /= np.maximum(2 * tri_area, tol.zero)[:, None]
    # samples: the centroid and points toward each corner of every fan triangle
    centroid = (A + B + C) / 3
    samples = np.concatenate([centroid] + [centroid + 0.6 * (X - centroid) for X in (A, B, C)])
    sample_tri = np.tile(np.arange(len(tris)), 4)
    partner = np.full(len(faces), -1)
    gap = np.zeros(len(faces))
    notes = []
    for p in range(n_pieces):
        mine = tri_piece[sample_tri] == p
        other = tri_piece != p
        if not mine.any():
            continue
        d2, hit, _ = igl.point_mesh_squared_distance(samples[mine], G, tris[other])
        hit_tri = np.flatnonzero(other)[hit]
        facing = np.einsum("ij,ij->i", tri_n[sample_tri[mine]], tri_n[hit_tri]) < -tol.facing
        d = np.sqrt(d2)
        face = tri_face[sample_tri[mine]]
        hit_piece = tri_piece[hit_tri]
        close = facing & (d <= tol.gap_repair * diag)
        near = facing & (d < tol.gap_detect * diag)
        # per face: shared when most samples are close to a facing face of another piece
        count = np.bincount(face, minlength=len(faces))
        shared = (np.bincount(face, close, minlength=len(faces)) >= 0.5 * count) & (count > 0)
        gapped = ~shared & (np.bincount(face, near, minlength=len(faces)) >= 0.5 * count) & (count > 0)
        if gapped.any():
            fi = int(np.flatnonzero(gapped)[0])
            sel = (face == fi) & near
            raise InputError(f"{where}gap of {d[sel].min():.3g} between pieces {names[p]!r} and "
                             f"{names[hit_piece[sel][0]]!r} (more than the {tol.gap_repair * diag:.3g} that is "
                             f"repaired); the pieces must tile the object in the rest pose")
        # its partner: the piece most of its close samples hit; its gap: the farthest of them
        c = close & shared[face]
        if c.any():
            votes, n_votes = np.unique(face[c] * n_pieces + hit_piece[c], return_counts=True)
            order = np.lexsort((-n_votes, votes // n_pieces))
            first = order[np.r_[True, np.diff(votes[order] // n_pieces) != 0]]
            partner[votes[first] // n_pieces] = votes[first] % n_pieces
            np.maximum.at(gap, face[c], d[c])
    if moved > tol.report * diag:
        notes.append(f"welded corners of neighbouring pieces that were up to {2 * moved:.2g} apart")
    big_gap = gap > tol.weld * diag
    if big_gap.any():
        notes.append(f"matched facing faces of neighbouring pieces up to {gap.max():.2g} apart "
                     f"({int(big_gap.sum())} faces; the lower-numbered piece's faces are kept)")

    # 3. triangulate: exterior faces, and the shared faces of the lower-numbered piece of each pair
    fracture, sides, exterior, owner = [], [], [], []
    piece_fracture_area = np.bincount(face_piece[partner >= 0], face_area[partner >= 0], minlength=n_pieces)
    for fi, (p, loop) in enumerate(faces):
        q = partner[fi]
        if q >= 0 and p > q:
            continue
        T = _triangulate_polygon(loop, G, where)
        if q >= 0:
            fracture.append(T)
            sides.append(np.tile([p, q], (len(T), 1)))
        else:
            exterior.append(T)
            owner.append(np.full(len(T), p))
    if not fracture:
        raise InputError(f"{where}no two pieces share a face: nothing to refine (is this a fractured object?)")
    out = SharedSurface(G, np.concatenate(fracture), np.concatenate(sides).astype(np.int64),
                        np.concatenate(exterior) if exterior else np.zeros((0, 3), np.int64),
                        np.concatenate(owner) if owner else np.zeros(0, np.int64), piece_fracture_area, notes)
    _fill_slivers(out, names, diag, where)
    _check_tiling(out, volumes, names, diag, where)
    return out


def _fill_slivers(s: SharedSurface, names: list[str], diag: float, where: str) -> None:
    """Close thin holes in B left where neighbouring pieces disagree on a corner.

    Cell Fracture's pieces can disagree on where a cut meets the surface by a
    few thousandths of the diagonal, leaving a sliver of the exterior that no
    piece covers. For a hole of B whose mean width (2 area / perimeter) is
    below the gap tolerance, the hole's short edges are collapsed (in both
    surfaces, so the cut's boundary stays on B); what remains of it, if
    anything, is triangulated and given to the piece that borders it most.
    Wider holes are left for :func:`_check_tiling` to report.
    """
    if len(s.exterior_F) == 0:
        return
    merged, filled, largest = 0, [], 0.0
    for _ in range(100):  # each pass closes at least one hole or stops
        loops = [np.asarray(l, np.int64) for l in igl.boundary_loop_all(np.ascontiguousarray(s.exterior_F, np.int64))]
        thin = []
        for loop in loops:
            P = s.V[loop]
            _, area = polygon_normal_area(P)
            perimeter = float(np.linalg.norm(P - np.roll(P, -1, axis=0), axis=1).sum())
            if len(loop) >= 3 and 2 * area / perimeter <= tol.gap_repair * diag:
                thin.append((loop, area))
        if not thin:
            break
        loop, area = thin[0]
        largest = max(largest, area)
        P = s.V[loop]
        lengths = np.linalg.norm(P - np.roll(P, -1, axis=0), axis=1)
        k = int(np.argmin(lengths))
        if lengths[k] <= tol.gap_repair * diag and len(loop) >= 3:
            a, b = int(loop[k]), int(loop[(k + 1) % len(loop)])
            s.V[a] = 0.5 * (s.V[a] + s.V[b])
            for name in ("exterior_F", "fracture_F"):
                F = getattr(s, name)
                F[F == b] = a
                keep = (F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])
                setattr(s, name, F[keep])
                if name == "exterior_F":
                    s.exterior_piece = s.exterior_piece[keep]
                else:
                    s.sides = s.sides[keep]
            merged += 1
            continue
        if directed_edge_face(s.exterior_F, loop[:2])[0] >= 0:
            loop = loop[::-1]  # the fill runs against the existing boundary edges
        T = _triangulate_polygon(loop, s.V, where)
        # the triangles across the hole's edges, weighted by edge length, vote for its piece
        across = directed_edge_face(s.exterior_F, np.stack([np.roll(loop, -1), loop], 1))
        lengths = np.linalg.norm(s.V[loop] - np.roll(s.V[loop], -1, axis=0), axis=1)
        known = across >= 0
        piece = int(np.bincount(s.exterior_piece[across[known]], weights=lengths[known]).argmax()) if known.any() else 0
        s.exterior_F = np.concatenate([s.exterior_F, T])
        s.exterior_piece = np.concatenate([s.exterior_piece, np.full(len(T), piece)])
        filled.append(names[piece])
    if merged or filled:
        s.notes.append(f"closed {merged + len(filled)} sliver holes of the exterior where neighbouring pieces "
                       f"disagree on a corner (largest area {largest:.2g}; {merged} short edges collapsed, "
                       f"{len(filled)} holes filled)")


def _check_tiling(s: SharedSurface, volumes: list[float], names: list[str], diag: float, where: str) -> None:
    _, counts = unique_edges(s.exterior_F)
    if np.any(counts != 2):
        raise InputError(f"{where}the pieces' outer faces do not form a closed surface "
                         f"({int((counts == 1).sum())} open edges, {int((counts > 2).sum())} edges shared by more "
                         f"than 2 faces): the pieces leave gaps or overlap")
    outer = signed_volume(s.V, s.exterior_F)
    total = float(sum(volumes))
    if abs(total - outer) > tol.volume * outer:
        kind = "overlap" if total > outer else "leave gaps"
        raise InputError(f"{where}the pieces {kind}: their volumes add up to {total:.6g}, "
                         f"the object they form has volume {outer:.6g}")
