"""Voronoi fracture of a closed mesh: the coarse pieces of the built-in scenes.

The object is cut into the Voronoi cells of a set of seeds, as Blender's Cell
Fracture does. Each cell is a convex polytope (scipy's halfspace
intersection); its intersection with the object is a boolean of two closed
meshes (pymeshlab, exact arithmetic). Every facet shared by two cells is
triangulated the same way in both cells, so the two booleans cut the object
at exactly the same points and the pieces meet vertex to vertex. The faces of
a piece that lie on a bisector plane are its fracture faces; they are
remeshed to a target edge length (Triangle, constrained, with the same points
on every shared boundary edge) so the coarse surface has well-shaped
triangles of about the size the paper's simulations produced.
"""

from __future__ import annotations

from dataclasses import dataclass

import igl
import numpy as np
import pymeshlab
import triangle
from scipy.spatial import HalfspaceIntersection, cKDTree

from fracture.errors import InputError
from fracture.mesh.exterior import Exterior
from fracture.mesh.topology import directed_edge_face, plane_basis, signed_volume, unique_edges, weld
from fracture.tolerances import tol

# Points this close are one, and a vertex this close to a bisector plane lies on it (relative to the
# diagonal; fracture/tolerances.py says why)
_WELD = tol.same_position
_ON_PLANE = tol.on_plane


@dataclass
class VoronoiFracture:
    """Pieces of an object cut by Voronoi cells, as one shared fracture surface.

    Attributes
    ----------
    V, F : (n, 3) float, (m, 3) int
        Fracture surface; boundary vertices lie on the cut mesh.
    sides : (m, 2) int
        Pieces behind and in front of each triangle (normal points into ``sides[:, 1]``).
    pieces : list of (V, F)
        The closed coarse pieces (for contact and inertia of the animator).
    seeds : (C, 3) float
    """

    V: np.ndarray
    F: np.ndarray
    sides: np.ndarray
    pieces: list[tuple[np.ndarray, np.ndarray]]
    seeds: np.ndarray

    def component_of(self, X: np.ndarray) -> np.ndarray:
        """The piece containing each point: its nearest seed."""
        return cKDTree(self.seeds).query(X)[1]


def _halfspaces(seeds: np.ndarray, i: int, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Rows ``[a, b]`` with ``a . x + b <= 0`` inside cell ``i`` (bisectors, then the box)."""
    s = seeds[i]
    others = np.delete(seeds, i, axis=0)
    A = others - s
    b = -0.5 * (np.einsum("ij,ij->i", others, others) - s @ s)
    eye = np.eye(3)
    box = np.concatenate([np.column_stack([eye, -hi]), np.column_stack([-eye, lo])])
    return np.concatenate([np.column_stack([A, b]), box])


def voronoi_cells(seeds: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Closed, outward meshes of the Voronoi cells of ``seeds`` inside the box ``[lo, hi]``.

    A facet shared by two cells is triangulated identically in both (a fan
    from its lowest-numbered corner after welding all cells' corners).
    """
    seeds = np.asarray(seeds, np.float64)
    diag = float(np.linalg.norm(hi - lo))
    H, corners = [], []
    for i in range(len(seeds)):
        Hi = _halfspaces(seeds, i, lo, hi)
        H.append(Hi)
        corners.append(HalfspaceIntersection(Hi, seeds[i]).intersections)
    G, label = weld(np.concatenate(corners), _WELD * diag)
    offsets = np.cumsum([0] + [len(c) for c in corners])
    cells = []
    for i, Hi in enumerate(H):
        ids = np.unique(label[offsets[i]:offsets[i + 1]])
        X = G[ids]
        norms = np.linalg.norm(Hi[:, :3], axis=1)
        dist = (X @ Hi[:, :3].T + Hi[:, 3]) / norms  # (corners, planes)
        tris = []
        for k in range(len(Hi)):
            on = np.flatnonzero(np.abs(dist[:, k]) <= _ON_PLANE * diag)
            if len(on) < 3:
                continue
            n = Hi[k, :3] / norms[k]
            u, v = plane_basis(n)
            P = X[on] - X[on].mean(axis=0)
            loop = ids[on][np.argsort(np.arctan2(P @ v, P @ u))]  # counter-clockwise around the outward normal
            loop = np.roll(loop, -int(np.argmin(loop)))
            tris.append(np.stack([np.full(len(loop) - 2, loop[0]), loop[1:-1], loop[2:]], 1))
        T = np.concatenate(tris)
        used, local = np.unique(T, return_inverse=True)
        cells.append((G[used], local.reshape(-1, 3)))
    return cells


def _intersect(AV, AF, BV, BF) -> tuple[np.ndarray, np.ndarray]:
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(AV, AF))
    ms.add_mesh(pymeshlab.Mesh(BV, BF))
    ms.generate_boolean_intersection(first_mesh=0, second_mesh=1)
    m = ms.current_mesh()
    return m.vertex_matrix().astype(np.float64), m.face_matrix().astype(np.int64)


def _boundary_chains(E: np.ndarray, junction: np.ndarray) -> list[np.ndarray]:
    """Split the edge graph ``E`` (every vertex of degree 2 except junctions) into vertex chains.

    A chain runs from junction to junction; a loop without junctions is
    returned closed (first vertex repeated at the end).
    """
    n = len(junction)
    adj: list[list[int]] = [[] for _ in range(n)]
    for k, (a, b) in enumerate(E):
        adj[a].append(k)
        adj[b].append(k)
    used = np.zeros(len(E), bool)
    chains = []

    def walk(v, k):
        chain = [v]
        while True:
            used[k] = True
            a, b = E[k]
            v = b if a == v else a
            chain.append(v)
            if junction[v] or len(adj[v]) != 2:
                return chain
            k = next((e for e in adj[v] if not used[e]), None)
            if k is None:
                return chain

    for v in np.flatnonzero(junction | (np.array([len(a) for a in adj]) != 2)):
        for k in adj[v]:
            if not used[k]:
                chains.append(np.array(walk(v, k)))
    for k in range(len(E)):
        if not used[k]:
            chains.append(np.array(walk(E[k][0], k)))
    return chains


def _resample(P: np.ndarray, h: float, closed: bool) -> np.ndarray:
    """Points of the polyline ``P`` (ends kept) at about spacing ``h`` by arc length."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))])
    # a chain through corners keeps at least one of them (its region must not collapse)
    k = max(3 if closed else (2 if len(P) > 2 else 1), int(round(s[-1] / h)))
    t = np.linspace(0.0, s[-1], k + 1)
    return np.stack([np.interp(t, s, P[:, c]) for c in range(3)], 1)


def _triangulate_region(P: np.ndarray, segments: np.ndarray, n: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Quality triangulation of a planar region bounded by ``segments`` between points ``P``.

    No points are added on the segments. Triangle fills holes, so triangles
    outside the segments (even-odd rule) are dropped. Returns the points
    (``P`` first) and triangles oriented like ``n``.
    """
    u, v = plane_basis(n)
    origin = P.mean(axis=0)
    XY = np.stack([(P - origin) @ u, (P - origin) @ v], 1)
    area = np.sqrt(3) / 4 * h * h
    out = triangle.triangulate({"vertices": XY, "segments": segments}, f"pq28Ya{area:.12g}Q")
    W, R = out["vertices"], out["triangles"]
    C = W[R].mean(axis=1)
    A, B = XY[segments[:, 0]], XY[segments[:, 1]]  # rays from the centroids toward +x
    straddle = (A[None, :, 1] > C[:, None, 1]) != (B[None, :, 1] > C[:, None, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        x = A[None, :, 0] + (C[:, None, 1] - A[None, :, 1]) * (B[None, :, 0] - A[None, :, 0]) / (B[None, :, 1] - A[None, :, 1])
    R = R[(straddle & (x > C[:, None, 0])).sum(axis=1) % 2 == 1]
    Q = np.concatenate([P, origin + W[len(P):, :1] * u + W[len(P):, 1:] * v])
    nrm = np.cross(Q[R[:, 1]] - Q[R[:, 0]], Q[R[:, 2]] - Q[R[:, 0]])
    flip = nrm @ n < 0
    R[flip] = R[flip][:, ::-1]
    return Q, R


def _remesh(G: np.ndarray, F: np.ndarray, region: np.ndarray, normals: np.ndarray, h: float):
    """Remesh every planar region of a fracture surface to edge length ``h``.

    Edges inside the object (where three regions meet) are split uniformly,
    with points that depend only on the edge, so the regions still meet
    vertex to vertex. The chains of boundary edges on the object's surface
    (chords of the coarse mesh, one region each) are resampled by arc length
    between their junctions, which removes the tiny edges the booleans leave
    where a bisector passes near a vertex of the object.
    """
    edges, count = unique_edges(F)
    on_surface = edges[count == 1]
    surface_key = on_surface[:, 0].astype(np.int64) * len(G) + on_surface[:, 1]
    junction = np.zeros(len(G), bool)
    junction[edges[count > 2].ravel()] = True
    chains = _boundary_chains(on_surface, junction)
    # which region each chain bounds: the region of the triangle on its first edge
    first = np.array([c[:2] for c in chains])
    face = directed_edge_face(F, first)
    face = np.where(face >= 0, face, directed_edge_face(F, first[:, ::-1]))
    chain_region = region[face]

    Vs, Fs, regs = [], [], []
    for r in range(len(normals)):
        T = F[region == r]
        if not len(T):
            continue
        pts, segs, index = [], [], {}

        def point(key, p):
            if key not in index:
                index[key] = len(pts)
                pts.append(p)
            return index[key]

        re, rc = unique_edges(T)
        inner = re[rc == 1]
        inner = inner[~np.isin(inner[:, 0] * len(G) + inner[:, 1], surface_key)]
        for a, b in inner:  # sorted pairs: the neighbouring regions split them the same way
            k = max(1, int(np.ceil(np.linalg.norm(G[b] - G[a]) / h - 0.25)))
            chain = [point(("v", a), G[a])]
            chain += [point(("e", a, b, j), G[a] + (G[b] - G[a]) * (j / k)) for j in range(1, k)]
            chain.append(point(("v", b), G[b]))
            segs += list(zip(chain[:-1], chain[1:]))
        for ci in np.flatnonzero(chain_region == r):
            c = chains[ci]
            closed = c[0] == c[-1]
            Q = _resample(G[c], h, closed)
            ids = [point(("v", c[0]), G[c[0]])]
            ids += [point(("c", ci, j), Q[j]) for j in range(1, len(Q) - 1)]
            ids.append(point(("v", c[-1]), G[c[-1]]))
            segs += list(zip(ids[:-1], ids[1:]))
        Q, R = _triangulate_region(np.array(pts), np.array(segs), normals[r], h)
        Vs.append(Q)
        Fs.append(R + sum(len(v) for v in Vs[:-1]))
        regs.append(np.full(len(R), r))
    return np.concatenate(Vs), np.concatenate(Fs), np.concatenate(regs)


def voronoi_fracture(BV: np.ndarray, BF: np.ndarray, seeds: np.ndarray, edge_length: float,
                     what: str = "object") -> VoronoiFracture:
    """Cut the closed mesh ``(BV, BF)`` into the Voronoi cells of ``seeds``.

    Parameters
    ----------
    BV, BF : closed, outward mesh (the coarse object; keep it coarse, every
        crossing of it with a bisector becomes a fracture-surface vertex).
    seeds : (C, 3) float
        Points inside the object, one per piece.
    edge_length : float
        Target edge length of the fracture surface.

    Raises
    ------
    InputError
        When a cell cuts the object into more than one part (a piece would
        not be connected) or misses it.
    """
    BV = np.asarray(BV, np.float64)
    BF = np.asarray(BF, np.int64)
    seeds = np.asarray(seeds, np.float64)
    lo, hi = BV.min(axis=0), BV.max(axis=0)
    pad = 0.1 * (hi - lo).max()
    diag = float(np.linalg.norm(hi - lo))
    cells = voronoi_cells(seeds, lo - pad, hi + pad)
    pieces = []
    for i, (CV, CF) in enumerate(cells):
        PV, PF = _intersect(BV, BF, CV, CF)
        if len(PF) == 0 or signed_volume(PV, PF) <= 0:
            raise InputError(f"{what}: Voronoi cell {i} does not meet the object")
        parts, _ = igl.facet_components(PF)
        if parts > 1:
            raise InputError(f"{what}: Voronoi cell {i} cuts the object into {parts} parts")
        pieces.append((PV, PF))

    # fracture faces: those of piece i on its bisector with piece j; keep i < j
    regions = []  # (i, j, vertices, triangles)
    for i, (PV, PF) in enumerate(pieces):
        others = np.delete(np.arange(len(seeds)), i)
        A = seeds[others] - seeds[i]
        A /= np.linalg.norm(A, axis=1, keepdims=True)
        mid = 0.5 * (seeds[others] + seeds[i])
        on = np.abs(np.einsum("vjk,jk->vj", PV[:, None, :] - mid[None], A)) <= _ON_PLANE * diag  # (vertices, neighbours)
        face_on = on[PF].all(axis=1)  # (faces, neighbours)
        for k, j in enumerate(others):
            if j > i and face_on[:, k].any():
                regions.append((i, j, A[k], PV, PF[face_on[:, k]]))
    if not regions:
        raise InputError(f"{what}: the seeds give no fracture surface inside the object")
    # weld the regions into one surface, then remesh it
    offsets = np.cumsum([0] + [len(PV) for _, _, _, PV, _ in regions])
    G, label = weld(np.concatenate([PV for _, _, _, PV, _ in regions]), _WELD * diag)
    F = np.concatenate([label[T + offsets[r]] for r, (_, _, _, _, T) in enumerate(regions)])
    region = np.concatenate([np.full(len(T), r) for r, (_, _, _, _, T) in enumerate(regions)])
    normals = np.array([n for _, _, n, _, _ in regions])
    Q, R, reg = _remesh(G, F, region, normals, float(edge_length))
    G2, label2 = weld(Q, _WELD * diag)
    pairs = np.array([(i, j) for i, j, _, _, _ in regions], np.int64)
    return VoronoiFracture(G2, label2[R].astype(np.int64), pairs[reg], pieces, seeds)


def seeds_inside(BV: np.ndarray, BF: np.ndarray, count: int, rng: np.random.Generator,
                 min_distance: float = 0.0, max_tries: int = 100000) -> np.ndarray:
    """``count`` random points inside a closed mesh, at least ``min_distance`` apart.

    Points are drawn uniformly in the mesh's box and kept when inside
    (winding number) and far enough from the others.
    """
    lo, hi = BV.min(axis=0), BV.max(axis=0)
    B = Exterior(BV, BF)
    out: list[np.ndarray] = []
    batch = 256
    for _ in range(max_tries // batch):
        P = lo + (hi - lo) * rng.random((batch, 3))
        P = P[B.inside(P)]
        for p in P:
            if all(np.linalg.norm(p - q) >= min_distance for q in out):
                out.append(p)
                if len(out) == count:
                    return np.array(out)
    raise InputError(f"cannot place {count} seeds {min_distance:.3g} apart inside the object")
