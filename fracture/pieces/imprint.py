"""Cut the exterior B along the refined fracture surface's boundary (Section 5, Figure 7).

The boundary vertices of the refined surface S lie on B (the refinement
projects them there), but not on B's vertices, and S's boundary edges cut
through B's triangles. To merge B and S into closed pieces, both are
remeshed so that they share that curve exactly:

1. every boundary vertex of S is inserted into B (a 1-to-3 split of the
   triangle it lies on, an edge split when it lies on an edge, or it snaps
   to a vertex of B it sits on);
2. every boundary edge ``(p, q)`` of S is traced on B, from ``p`` to ``q``,
   in the plane through them that contains B's normal (a surface traversal
   that approximates the geodesic, as in the paper): each B edge the trace
   crosses is split at the crossing, so the trace becomes a chain of B edges;
3. the same crossing points are inserted into S's boundary edge (its triangle
   becomes a fan), recorded in S's barycentric tree by their arc-length
   position between ``p`` and ``q``.

Afterwards every boundary edge of S is a cut edge of B, and the two share
the vertices along it. libigl and pymeshlab have no operation that embeds a
polyline lying on a mesh into it (booleans need closed operands, and S is
open and non-manifold), so the insertion is written here on a half-edge map
of B. It touches only the triangles along the cut.
"""

from __future__ import annotations

import copy
import heapq
from dataclasses import dataclass, fields, replace

import numpy as np

from fracture.errors import InputError, JoinError
from fracture.mesh.clean import collapse_short_edges
from fracture.mesh.exterior import Exterior
from fracture.refine.crossings_on_b import edges_would_cross, splits_would_cross
from fracture.mesh.edges import edge_table, row_edges
from fracture.mesh.fracture_surface import FractureSurface
from fracture.tolerances import tol

# A point within this barycentric distance of an edge of a B triangle is put on it (tol.snap says why).
SNAP = tol.snap

# Boundary edges of S are split until their midpoints are this close to B,
# relative to B's median edge length.
CHORD = 0.05
# An ear of S (two boundary edges) whose centroid is closer to B than this
# fraction of its longest edge lies along B (see clip_tangent_triangles).
TANGENT = 0.1
# An ear of S whose two boundary edges meet at less than this angle (degrees) is clipped (_hairpins).
HAIRPIN = 10.0
# An interior edge of S between two boundary vertices is split, and the new
# vertex put this fraction of the edge's length inside B.
BRIDGE_DEPTH = 0.2

# A boundary vertex of S farther from B than this fraction of B's median edge is off B (a collision of the
# refinement kept it there); a trace that cannot be embedded is repaired at most _REPAIRS times (_merge_off_b
# from such a vertex, else _simplify_rim_near).
OFF_B = 1e-3
_REPAIRS = 4

# B's edges shorter than this fraction of its median edge are collapsed when S cannot be imprinted as B is.
SHORT_EDGE = 0.1

# Where the trace of a boundary edge of S cannot be embedded and neither end is off B, S's boundary edges
# shorter than RIM_EDGE of B's median edge within RIM_REACH of it are collapsed (_simplify_rim_near).
RIM_EDGE = 0.2
RIM_REACH = 2.0

# What a user can change when S cannot be imprinted (said after each such refusal).
_RETRY = "; another refine.max_triangles or refine.draw gives other refined cracks there"


@dataclass
class Imprint:
    """B remeshed along S's boundary.

    Attributes
    ----------
    V, F : B's vertices and triangles after the insertions (B's own vertices first).
    to_fracture : (len(V),) int
        The refined-surface vertex that each B vertex on the cut is, or -1.
    cut_edges : (k, 2) int
        B edges along S's boundary (pairs of B vertex ids).
    cut_faces : (k,) int
        The triangle of S on each cut edge.
    origin : (len(F),) int
        The original B triangle each triangle lies in.
    merged_off_b : int
        Boundary vertices of S off B whose traces could not be embedded, merged into a neighbour on the
        boundary (:func:`_merge_off_b`).
    joined_b : int
        B's vertices that went where its short edges were collapsed before S could be imprinted (0: B as
        it was given).
    rim_collapsed : int
        Short boundary edges of S collapsed beside traces that could not be embedded
        (:func:`_simplify_rim_near`).
    """

    V: np.ndarray
    F: np.ndarray
    to_fracture: np.ndarray
    cut_edges: np.ndarray
    cut_faces: np.ndarray
    origin: np.ndarray
    merged_off_b: int = 0
    joined_b: int = 0
    rim_collapsed: int = 0


class _Surface:
    """A closed, oriented triangle mesh under vertex insertion, as a half-edge map.

    ``he[(a, b)]`` is the triangle holding the directed edge ``a -> b``; the
    triangle across it holds ``b -> a``. Splits rewrite one triangle in place
    and append the others, so triangle ids stay valid.
    """

    def __init__(self, V: np.ndarray, F: np.ndarray):
        self.V = [tuple(v) for v in np.asarray(V, np.float64).tolist()]
        self.F = [list(f) for f in np.asarray(F, np.int64).tolist()]
        self.origin = list(range(len(self.F)))
        self.cover: dict[int, list[int]] = {}
        a, b, c = np.asarray(F, np.int64).T.tolist()
        faces = list(range(len(self.F)))
        self.he = dict(zip(zip(a + b + c, b + c + a), faces * 3))
        if len(self.he) != 3 * len(self.F):
            raise InputError("exterior: B has a directed edge twice (it is not an oriented 2-manifold)")
        vface = np.zeros(len(self.V), np.int64)
        vface[np.asarray(F, np.int64).ravel()] = np.repeat(np.arange(len(self.F)), 3)
        self.vface = vface.tolist()

    # -- elementary operations ------------------------------------------------------------

    def _new_face(self, tri, parent):
        f = len(self.F)
        self.F.append(tri)
        o = self.origin[parent]
        self.origin.append(o)
        self.cover.setdefault(o, [o]).append(f)
        return f

    def _set(self, f, tri):
        self.F[f] = tri
        a, b, c = tri
        self.he[(a, b)] = self.he[(b, c)] = self.he[(c, a)] = f
        self.vface[a] = self.vface[b] = self.vface[c] = f

    def _vertex(self, p):
        self.V.append(tuple(p))
        self.vface.append(-1)
        return len(self.V) - 1

    def split_face(self, f, p):
        """Insert point ``p`` inside triangle ``f`` (1-to-3); returns the new vertex."""
        a, b, c = self.F[f]
        x = self._vertex(p)
        self._set(f, [a, b, x])
        self._set(self._new_face([b, c, x], f), [b, c, x])
        self._set(self._new_face([c, a, x], f), [c, a, x])
        return x

    def split_edge(self, a, b, p):
        """Insert point ``p`` on edge ``a - b``, splitting both its triangles; returns the new vertex."""
        f, g = self.he.pop((a, b)), self.he.pop((b, a))
        c = self._third(f, a, b)
        d = self._third(g, b, a)
        x = self._vertex(p)
        self._set(f, [a, x, c])
        self._set(self._new_face([x, b, c], f), [x, b, c])
        self._set(g, [b, x, d])
        self._set(self._new_face([x, a, d], g), [x, a, d])
        return x

    def _third(self, f, a, b):
        for v in self.F[f]:
            if v != a and v != b:
                return v
        raise AssertionError("degenerate triangle")

    def fan(self, v):
        """Triangles around vertex ``v``, each rotated to start at ``v``: ``(v, a, b)``."""
        start = f = self.vface[v]
        out = []
        while True:
            tri = self.F[f]
            k = tri.index(v)
            a, b = tri[(k + 1) % 3], tri[(k + 2) % 3]
            out.append((f, a, b))
            f = self.he[(v, b)]
            if f == start:
                return out
            if len(out) > len(self.F):  # a closed, oriented B always comes back round
                raise AssertionError(f"the triangles around vertex {v} of B do not close")

    # -- queries --------------------------------------------------------------------------

    def locate(self, p, f0):
        """The triangle covering the original triangle ``f0`` that holds ``p``, with ``p``'s barycentrics."""
        faces = self.cover.get(f0, [f0])
        T = np.array([[self.V[v] for v in self.F[f]] for f in faces])
        bary = _barycentric(np.asarray(p)[None], T)
        best = int(np.argmax(bary.min(axis=1)))
        return faces[best], bary[best]


def _barycentric(p, T):
    """Barycentric coordinates ``(k, 3)`` of points ``p`` in triangles ``T (k, 3, 3)`` (projected to their planes)."""
    a, b, c = T[:, 0], T[:, 1], T[:, 2]
    e1, e2, x = b - a, c - a, p - a
    d00, d01, d11 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    d20, d21 = (x * e1).sum(1), (x * e2).sum(1)
    den = np.maximum(d00 * d11 - d01 * d01, tol.tiny)
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return np.stack([1.0 - v - w, v, w], 1)


def _insert(surf: _Surface, p, f0, claimed: set, where: str) -> int:
    """Insert the point ``p`` (on B's original triangle ``f0``) as a vertex of B; returns its id."""
    f, bary = surf.locate(p, f0)
    tri = surf.F[f]
    small = bary < SNAP
    if small.sum() >= 2:  # on a vertex
        v = tri[int(np.argmax(bary))]
        if v not in claimed:
            return v
        if np.linalg.norm(np.asarray(surf.V[v]) - p) <= tol.coincide * max(1.0, np.abs(p).max()):
            raise _not_joined(where, f"at {np.round(p, 6).tolist()}: two points where its cracks reach the surface "
                                     "coincide there")
        # another boundary vertex is there already: insert beside it
        bary = np.maximum(bary, 2 * SNAP)
        bary /= bary.sum()
        small = bary < SNAP
    bary = np.clip(bary, 0.0, None)
    if small.any():  # on an edge: the one opposite the small coordinate
        k = int(np.argmax(small))
        a, b = tri[(k + 1) % 3], tri[(k + 2) % 3]
        s = bary[(k + 2) % 3] / (bary[(k + 1) % 3] + bary[(k + 2) % 3])
        return surf.split_edge(a, b, (1 - s) * np.asarray(surf.V[a]) + s * np.asarray(surf.V[b]))
    P = np.array([surf.V[v] for v in tri])
    return surf.split_face(f, bary @ P)


def _fan_normal(surf: _Surface, u: int) -> np.ndarray:
    U = np.asarray(surf.V[u])
    fan = surf.fan(u)
    A = np.array([surf.V[a] for _, a, _ in fan]) - U
    B = np.array([surf.V[b] for _, _, b in fan]) - U
    n = _cross(A, B).sum(axis=0)
    return n / max(np.linalg.norm(n), tol.tiny)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of 3-vectors (rows), the same products: NumPy's moves axes first, which on the walks' fans
    of a few triangles cost more than the products (0.9 s of the rotated Cell Fracture cube's animate stage
    at the full budget)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _trace(surf: _Surface, p: int, q: int, claimed: set, cut: set, where: str) -> list[int]:
    """Embed a path from vertex ``p`` to vertex ``q`` of B as a chain of B edges; returns its vertices.

    The path is B's section by the plane through ``p`` and ``q`` that holds
    their mean normal, walked vertex to vertex: from each vertex, the plane
    leaves through one edge of the fan ahead (farther along ``q - p``),
    which is split there (or the walk steps onto a vertex of B it meets).
    Where the section cannot be walked (B folds between ``p`` and ``q``, or
    the section meets another curve), the path is the shortest chain of B's
    edges from ``p`` to ``q`` that touches no other curve
    (:func:`_edge_path`); the splits the walk made stay (they only refine B).
    """
    added: list[int] = []
    try:
        return _walk_section(surf, p, q, claimed, cut, where, added)
    except InputError:
        claimed.difference_update(added)
        path = _edge_path(surf, p, q, claimed, cut)
        if path is None:
            raise
        claimed.update(path[1:-1])
        return path


def _edge_path(surf: _Surface, p: int, q: int, claimed: set, cut: set) -> list[int] | None:
    """The shortest chain of B edges from ``p`` to ``q`` through no claimed vertex and along no cut edge
    (Dijkstra over B's half-edges, searched near ``p`` and ``q`` first), or None."""
    P, Q = np.asarray(surf.V[p]), np.asarray(surf.V[q])
    mid, span = 0.5 * (P + Q), float(np.linalg.norm(Q - P))
    for reach in (2.0 * span, 8.0 * span, np.inf):
        dist, prev, heap = {p: 0.0}, {}, [(0.0, p)]
        while heap:
            d, u = heapq.heappop(heap)
            if u == q:
                path = [q]
                while path[-1] != p:
                    path.append(prev[path[-1]])
                return path[::-1]
            if d > dist.get(u, np.inf):
                continue
            U = np.asarray(surf.V[u])
            for _, a, _ in surf.fan(u):
                if (a in claimed and a != q) or (min(u, a), max(u, a)) in cut:
                    continue
                A = np.asarray(surf.V[a])
                if np.linalg.norm(A - mid) > reach:
                    continue
                nd = d + float(np.linalg.norm(A - U))
                if nd < dist.get(a, np.inf):
                    dist[a], prev[a] = nd, u
                    heapq.heappush(heap, (nd, a))
    return None


def _walk_section(surf: _Surface, p: int, q: int, claimed: set, cut: set, where: str, added: list) -> list[int]:
    """The plane section walk of :func:`_trace`; the vertices it claims are appended to ``added``."""
    P, Q = np.asarray(surf.V[p]), np.asarray(surf.V[q])
    d = Q - P
    m = _cross(d, _fan_normal(surf, p) + _fan_normal(surf, q))  # the plane's normal
    dd = d @ d
    chain = [p]
    u, progress = p, 0.0
    for _ in range(20000):
        if (u, q) in surf.he or (q, u) in surf.he:
            chain.append(q)
            return chain
        U = np.asarray(surf.V[u])
        fan = surf.fan(u)
        A = np.array([surf.V[a] for _, a, _ in fan])
        B = np.array([surf.V[b] for _, _, b in fan])
        sa, sb = (A - U) @ m, (B - U) @ m
        lam = np.clip(sa / np.where(sa == sb, 1.0, sa - sb), 0.0, 1.0)
        Y = A + lam[:, None] * (B - A)
        ahead = ((Y - P) @ d) / dd
        score = np.where((sa * sb <= 0) & (sa != sb) & (ahead > progress), ahead, -np.inf)
        k = int(np.argmax(score))
        if not np.isfinite(score[k]):
            raise _not_joined(where, f"between {np.round(U, 6).tolist()} and {np.round(Q, 6).tolist()}: the surface "
                                     "folds between them")
        _, a, b = fan[k]
        t = lam[k]
        if t < SNAP and a not in claimed:
            u = a
        elif t > 1 - SNAP and b not in claimed:
            u = b
        else:
            if (min(a, b), max(a, b)) in cut:
                raise _not_joined(where, f"near {np.round(Y[k], 6).tolist()}: two of its cracks cross each other "
                                         "on the surface there")
            # (a claimed end is another curve's vertex: pass beside it, not through it)
            t = min(max(t, 2 * SNAP), 1 - 2 * SNAP)
            u = surf.split_edge(a, b, A[k] + t * (B[k] - A[k]))
        progress = max(progress, float(score[k]))
        chain.append(u)
        if u not in claimed:
            added.append(u)
        claimed.add(u)
    raise _not_joined(where, f"between {np.round(P, 6).tolist()} and {np.round(Q, 6).tolist()}: the path along it "
                             "does not end")


def _not_joined(where: str, detail: str) -> JoinError:
    return JoinError(where, f"the refined fracture surface cannot be joined to the object's surface {detail}", _RETRY)


def _hairpins(T: np.ndarray, boundary: np.ndarray) -> np.ndarray:
    """Which ears (corners ``T (k, 3, 3)``; ``boundary (k, 3)``: edge ``i``, from corner ``i`` to ``i + 1``, is
    on S's boundary) have two boundary edges that meet at an angle under :data:`HAIRPIN` degrees at their
    common corner: the boundary turns back on itself there, and the traces of the two edges on B would run
    side by side closer than B's triangles resolve."""
    two = boundary.sum(axis=1) == 2
    tip = (np.argmin(boundary, axis=1) + 2) % 3  # the corner opposite the edge that is not on the boundary
    rows = np.arange(len(T))
    P = T[rows, tip]
    a = T[rows, (tip + 1) % 3] - P
    b = T[rows, (tip + 2) % 3] - P
    lengths = np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1)
    cos = np.einsum("ij,ij->i", a, b) / np.maximum(lengths, tol.tiny)
    return two & (cos > np.cos(np.radians(HAIRPIN)))


def clip_tangent_triangles(mesh: FractureSurface, exterior: Exterior, ratio: float = TANGENT, max_rounds: int = 20) -> int:
    """Remove ears of S that lie along B (two boundary edges, centroid within ``ratio`` of their size from B)
    or turn its boundary back on itself (:func:`_hairpins`).

    Such a triangle separates nothing (B is on one of its sides); kept, it
    would double a patch of B (a flat B) or cut through it (a curved B).
    Removing one can expose another, so this repeats. Returns the removals.
    """
    total = 0
    for _ in range(max_rounds):
        # ears only (two boundary edges or three, so every corner on the boundary): removing a
        # triangle with fewer would split the fan of its corner opposite them, cutting off a cap of S
        # whose rim, imprinted on B, is oriented against the rest of the cut; the bridges such a
        # triangle has are split instead (split_bridge_edges)
        count = edge_table(mesh.F, len(mesh.V)).row_count.reshape(-1, 3)
        boundary = count == 1
        cand = np.flatnonzero(boundary.sum(axis=1) >= 2)
        if not len(cand):
            break
        T = mesh.V[mesh.F[cand]]
        size = np.linalg.norm(T - np.roll(T, 1, axis=1), axis=2).max(axis=1)
        d2, _, _ = exterior.closest(T.mean(axis=1))
        flat = cand[(d2 < (ratio * size) ** 2) | _hairpins(T, boundary[cand])]
        flat = flat[~_chords_would_cross(mesh, count, flat, exterior)]
        if not len(flat):
            break
        keep = np.ones(len(mesh.F), bool)
        keep[flat] = False
        mesh.F, mesh.sides = mesh.F[keep], mesh.sides[keep]
        total += len(flat)
    return total


def _chords_would_cross(mesh: FractureSurface, count: np.ndarray, ears: np.ndarray, exterior: Exterior
                        ) -> np.ndarray:
    """Which of the ``ears`` (triangles; ``count (m, 3)``: each triangle's edges' triangle counts, 1 on the
    boundary) would, removed, leave their third side as a boundary edge that crosses another on B: an ear
    whose two boundary edges go around the end of another crack's rim (over a crease of B and back) has its
    chord across that rim, and the two could not both be cut into B. Tested against the boundary that the
    removal of the others leaves, until the ears kept change no more."""
    F = mesh.F
    rows = np.flatnonzero(count.ravel() == 1)
    E = row_edges(F, rows)
    bad = np.zeros(len(ears), bool)
    while True:
        going = ears[~bad]
        # the third side becomes a boundary edge if it had two triangles and the other one stays
        third = count[going] == 2
        f = going[third.any(axis=1)]
        k = np.argmax(third[third.any(axis=1)], axis=1)
        chords = np.stack([F[f, k], F[f, (k + 1) % 3]], 1)
        key = np.sort(chords, axis=1)
        _, inverse, twice = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        once = twice[inverse.ravel()] == 1  # a chord two removed ears share goes with them
        crossing = np.zeros(len(f), bool)
        crossing[once] = edges_would_cross(mesh.V, E, np.isin(rows // 3, going), chords[once], exterior.normal_at)
        if not crossing.any():
            return bad
        bad[np.searchsorted(ears, f[crossing])] = True


def collapse_short_boundary(mesh: FractureSurface, length: float, near: tuple[np.ndarray, float] | None = None
                            ) -> int:
    """Merge the ends of boundary edges shorter than ``length`` (the triangle on the edge goes away); with
    ``near = (point, reach)`` only those whose midpoints lie within ``reach`` of ``point``, shortest first.

    Two boundary vertices a hair apart cannot both be inserted into B without
    slivers that cross each other. An edge is collapsed only when its ends
    have no common neighbour but the third corner of its triangle (the link
    condition), which keeps the surface's topology. Returns the collapses.
    """
    E = row_edges(mesh.F, edge_table(mesh.F, len(mesh.V)).boundary_rows)
    length_of = np.linalg.norm(mesh.V[E[:, 1]] - mesh.V[E[:, 0]], axis=1)
    short = np.flatnonzero(length_of < length)
    if near is not None:
        point, reach = near
        mid = 0.5 * (mesh.V[E[short, 0]] + mesh.V[E[short, 1]])
        short = short[np.linalg.norm(mid - point, axis=1) <= reach]
        short = short[np.argsort(length_of[short], kind="stable")]
    merged = np.arange(len(mesh.V))  # where each vertex went
    done = 0
    for i in short.tolist():
        a, b = merged[E[i, 0]], merged[E[i, 1]]
        if a != b and _collapse(mesh, a, b):
            merged[merged == b] = a
            done += 1
    return done


def subdivide_boundary(mesh: FractureSurface, exterior: Exterior, tolerance: float, max_rounds: int = 12) -> int:
    """Split boundary edges of ``mesh`` whose midpoint is farther than ``tolerance`` from B.

    The new vertex goes onto B (the closest point to the midpoint), so the
    boundary polyline follows B within ``tolerance`` and every boundary
    edge spans a few B triangles at most: the traces between its ends stay
    short and close to the straight chord. Returns the number of splits.
    """
    total = 0
    for _ in range(max_rounds):
        rows = edge_table(mesh.F, len(mesh.V)).boundary_rows
        face, E = rows // 3, row_edges(mesh.F, rows)
        d2, _, closest = exterior.closest(0.5 * (mesh.V[E[:, 0]] + mesh.V[E[:, 1]]))
        far = np.flatnonzero(d2 > tolerance ** 2)
        # a midpoint whose closest point of B is where an end's is adds nothing: beside a vertex that stays
        # off B (a collision kept it there) at a crease of B, every split took the same point of B
        ends = exterior.closest(mesh.V[E[far].ravel()])[2].reshape(-1, 2, 3)
        far = far[np.linalg.norm(closest[far, None] - ends, axis=2).min(axis=1) > tolerance]
        # one split edge per triangle per round
        far = far[np.unique(face[far], return_index=True)[1]]
        far = far[~splits_would_cross(mesh.V, E, far, closest[far], exterior.normal_at)]
        if not len(far):
            break
        new = mesh.split_edges(E[far], np.full(len(far), 0.5), rows=rows[far], which=np.arange(len(far)))
        mesh.V[new] = closest[far]
        total += len(far)
    return total


def split_bridge_edges(mesh: FractureSurface, exterior: Exterior, depth: float = BRIDGE_DEPTH,
                       max_rounds: int = 20) -> int:
    """Split the interior edges of S that join two boundary vertices; the new vertex goes inside B.

    Such a bridge edge runs along B when B is flat between its ends and
    outside B where B is concave, so the triangles on it touch or cross B's
    triangles beside the cut. Its midpoint goes at least ``depth`` times the
    edge's length below B (to B's closest point, pushed in along the normal
    of B's closest triangle), which leaves every triangle of S with a corner
    strictly inside the material: the fans of the imprint then meet B only
    along the cut. A triangle may carry two bridges; a round splits those
    that are the first (lowest id) bridge of every triangle on them.
    Returns the number of splits.
    """
    total = 0
    for _ in range(max_rounds):
        table = edge_table(mesh.F, len(mesh.V))
        on_b = np.zeros(len(mesh.V), bool)
        on_b[row_edges(mesh.F, table.boundary_rows)] = True
        rows = np.flatnonzero(on_b[row_edges(mesh.F, np.arange(3 * len(mesh.F)))].all(axis=1)
                              & (table.row_count > 1))
        if not len(rows):
            break
        bridges = np.unique(table.eid[rows])
        chosen = bridges[table.independent(bridges)]
        on, which = table.rows_of(chosen)
        ends = row_edges(mesh.F, on[np.unique(which, return_index=True)[1]])
        mid = 0.5 * (mesh.V[ends[:, 0]] + mesh.V[ends[:, 1]])
        target = depth * np.linalg.norm(mesh.V[ends[:, 1]] - mesh.V[ends[:, 0]], axis=1)
        d2, f, closest = exterior.closest(mid)
        n = exterior.normals[f]
        shallow = ~exterior.inside(mid) | (d2 < target ** 2)
        new = mesh.split_edges(ends, np.full(len(chosen), 0.5), rows=on, which=which)
        mesh.V[new] = np.where(shallow[:, None], closest - target[:, None] * n, mid)
        total += len(chosen)
    return total


def imprint_boundary(BV: np.ndarray, BF: np.ndarray, mesh: FractureSurface, where: str = "animate") -> Imprint:
    """Remesh B and the refined surface ``mesh`` (edited in place) so that S's boundary is a chain of B edges.

    Boundary vertices of ``mesh`` move onto B exactly (by at most their
    distance to it plus :data:`SNAP` of a B triangle). New vertices of
    ``mesh`` are recorded in its barycentric tree. Where a trace cannot be
    embedded from a boundary vertex off B, that vertex is merged into its
    neighbour and the boundary embedded again (:func:`_merge_off_b`); where
    both ends are on B, S's short boundary edges near it are collapsed
    (:func:`_simplify_rim_near`); at most :data:`_REPAIRS` repairs, the
    result says how many of each. If S still cannot be
    imprinted, B's edges shorter than :data:`SHORT_EDGE` of its median edge
    (bumps of a few hundredths of a cell that the contour leaves at B's
    creases, over which two cracks' traces crossed on random Blender
    exports) are collapsed (:func:`fracture.mesh.clean.collapse_short_edges`)
    and S imprinted on that B from where it was; the result says how many of
    B's vertices went, and the first refusal stands if this fails too.
    """
    before = copy.deepcopy(mesh)
    try:
        return _imprint(BV, BF, mesh, where)
    except InputError as refused:
        BV, BF = np.asarray(BV, np.float64), np.asarray(BF, np.int64)
        W, G, joined = collapse_short_edges(BV, BF, SHORT_EDGE * median_edge(BV, BF))
        if not joined:
            raise
        for f in fields(mesh):
            setattr(mesh, f.name, getattr(before, f.name))
        try:
            return replace(_imprint(W, G, mesh, where), joined_b=joined)
        except InputError:
            raise refused from None


def _imprint(BV: np.ndarray, BF: np.ndarray, mesh: FractureSurface, where: str) -> Imprint:
    """:func:`imprint_boundary` on B as it is."""
    BV = np.asarray(BV, np.float64)
    BF = np.asarray(BF, np.int64)
    exterior = Exterior(BV, BF)
    h = median_edge(BV, BF)
    clip_tangent_triangles(mesh, exterior)
    collapse_short_boundary(mesh, 10 * SNAP * h)
    subdivide_boundary(mesh, exterior, CHORD * h)
    split_bridge_edges(mesh, exterior)
    merged = collapsed = repairs = 0
    while True:
        rows = edge_table(mesh.F, len(mesh.V)).boundary_rows
        sface, E = rows // 3, row_edges(mesh.F, rows)  # edges as directed in their triangle
        verts = np.unique(E)
        d2, f0, closest = exterior.closest(mesh.V[verts])
        try:
            length = np.linalg.norm(mesh.V[E[:, 1]] - mesh.V[E[:, 0]], axis=1)
            surf, to_b, chains = _embed_in_some_order(BV, BF, E, verts, f0, closest, length, where)
            break
        except _TraceFailed as failed:
            if repairs == _REPAIRS:
                raise failed.error from None
            off = np.zeros(len(mesh.V))
            off[verts] = np.sqrt(d2)
            if _merge_off_b(mesh, failed.edge, off, OFF_B * h):
                merged += 1
            else:
                done = _simplify_rim_near(mesh, failed.edge, h)
                if not done:
                    raise failed.error from None
                collapsed += done
            repairs += 1
    # S's boundary vertices take their positions on B
    mesh.V[verts] = np.array([surf.V[to_b[v]] for v in verts.tolist()])

    BV_cut = np.array(surf.V)
    cut_edges, cut_faces, to_fracture = _split_fracture_edges(mesh, E, sface, chains, BV_cut, to_b)
    return Imprint(V=BV_cut, F=np.array(surf.F, np.int64), to_fracture=to_fracture,
                   cut_edges=cut_edges, cut_faces=cut_faces, origin=np.array(surf.origin, np.int64),
                   merged_off_b=merged, rim_collapsed=collapsed)


def median_edge(BV: np.ndarray, BF: np.ndarray) -> float:
    """B's median edge length (each triangle's first edge): the scale of the imprint's tolerances."""
    return float(np.median(np.linalg.norm(BV[BF[:, 1]] - BV[BF[:, 0]], axis=1)))


def _embed_in_some_order(BV, BF, E, verts, f0, closest, length, where):
    """:func:`_embed` with S's boundary edges (of ``length``) traced shortest first, then in other orders
    until one embeds them all (a long edge traced early can fence a short one's ends apart); raises the
    first order's :class:`_TraceFailed` if none does."""
    failed = None
    for order in (np.argsort(length, kind="stable"), np.arange(len(E)), np.argsort(-length, kind="stable")):
        try:
            return _embed(BV, BF, E, verts, f0, closest, order, where)
        except _TraceFailed as e:
            failed = failed or e
    raise failed


def _embed(BV, BF, E, verts, f0, closest, order, where):
    """Insert S's boundary vertices into B and trace its boundary edges in ``order``."""
    surf = _Surface(BV, BF)
    claimed: set[int] = set()
    to_b = {}
    for v, f, p in zip(verts.tolist(), f0.tolist(), closest):
        b = _insert(surf, p, f, claimed, where)
        claimed.add(b)
        to_b[v] = b
    cut: set[tuple[int, int]] = set()
    chains = [None] * len(E)
    for i in order.tolist():
        a, b = E[i].tolist()
        try:
            chain = _trace(surf, to_b[a], to_b[b], claimed, cut, where)
        except InputError as e:
            raise _TraceFailed(e, (a, b)) from None
        cut.update((min(x, y), max(x, y)) for x, y in zip(chain[:-1], chain[1:]))
        chains[i] = chain
    return surf, to_b, chains


class _TraceFailed(Exception):
    """The trace of S's boundary edge ``edge`` (its two vertices) could not be embedded: ``error`` says why."""

    def __init__(self, error: InputError, edge: tuple[int, int]):
        super().__init__(str(error))
        self.error, self.edge = error, edge


def _merge_off_b(mesh: FractureSurface, edge: tuple[int, int], off: np.ndarray, limit: float) -> bool:
    """Merge the end of S's boundary ``edge`` that lies off B (``off``: each vertex's distance to B, more
    than ``limit``; the farther end if both do) into the other end; whether it was merged.

    A boundary vertex a collision of the refinement kept off B has its closest point of B where it may not
    belong: beside a crease of B, on the face across it from its neighbours (on a Blender cube two cracks
    then crossed there). Merged into its neighbour along the boundary, its triangle on the edge goes and
    the boundary runs from the neighbour on (:func:`_collapse`)."""
    a, b = edge
    if max(off[a], off[b]) <= limit:
        return False
    gone, kept = (a, b) if off[a] >= off[b] else (b, a)
    return _collapse(mesh, kept, gone)


def _simplify_rim_near(mesh: FractureSurface, edge: tuple[int, int], h: float) -> int:
    """Collapse S's boundary edges shorter than :data:`RIM_EDGE` of ``h`` (B's median edge) within
    :data:`RIM_REACH` of ``h`` of the boundary ``edge`` whose trace could not be embedded; how many.

    Where the refined rim doubles back on itself on B (a zigzag a few thousandths of a cell long, or two
    stretches of one rim running side by side a hundredth of a cell apart, left by collisions at a crease
    of B), the traces of its edges are walked into each other. Coarser there, the rim is a single curve
    again: on Blender Cell Fracture exports with a margin of 0.02 and on a plank-shaped torus the pieces
    then closed, and the rest of the rim keeps its resolution."""
    point = mesh.V[list(edge)].mean(axis=0)
    return collapse_short_boundary(mesh, RIM_EDGE * h, near=(point, RIM_REACH * h))


def _collapse(mesh: FractureSurface, kept: int, gone: int) -> bool:
    """Merge vertex ``gone`` of S into ``kept`` (its neighbour on one triangle: the triangle goes) if their
    only common neighbour is that triangle's third corner (the link condition for an edge on the boundary);
    whether it was merged."""
    F = mesh.F
    around_kept = np.flatnonzero((F == kept).any(axis=1))
    around_gone = np.flatnonzero((F == gone).any(axis=1))
    both = np.intersect1d(around_kept, around_gone)
    if len(both) != 1 or len(np.intersect1d(F[around_kept], F[around_gone])) != 3:
        return False
    F = F.copy()
    F[around_gone] = np.where(F[around_gone] == gone, kept, F[around_gone])
    keep = np.ones(len(F), bool)
    keep[both] = False
    mesh.F, mesh.sides = F[keep], mesh.sides[keep]
    return True


def _split_fracture_edges(mesh: FractureSurface, E, sface, chains, BV_cut: np.ndarray, to_b: dict):
    """Insert the chains' inner vertices into S's boundary edges (each triangle becomes a fan)."""
    to_fracture = np.full(len(BV_cut), -1, np.int64)
    for s, b in to_b.items():
        to_fracture[b] = s
    parents, weights = [], []
    inner = []
    for (a, b), chain in zip(E.tolist(), chains):
        if len(chain) == 2:
            continue
        P = BV_cut[chain]
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))])
        t = arc[1:-1] / arc[-1]
        parents.append(np.tile([a, b, a], (len(t), 1)))
        weights.append(np.stack([1 - t, t, np.zeros_like(t)], 1))
        inner.append(chain[1:-1])
    if parents:
        ids = mesh._add_vertices(np.concatenate(parents), np.concatenate(weights))
        chain_inner = np.concatenate([np.asarray(c, np.int64) for c in inner])
        mesh.V[ids] = BV_cut[chain_inner]
        to_fracture[chain_inner] = ids

    # S's triangles: each boundary edge u -> v of triangle (u, v, w) becomes a
    # fan (u, x1, w), (x1, x2, w), ..., (xk, v, w); a triangle with several
    # boundary edges is handled edge by edge (its other edges stay in the fan).
    # Only the boundary triangles are touched: rewrites by id, new ones appended.
    m = len(mesh.F)
    rewritten: dict[int, list[int]] = {}
    added, parent = [], []

    def triangle(f):
        return added[f - m] if f >= m else rewritten.get(f) or mesh.F[f].tolist()

    owner = {(a, b): f for (a, b), f in zip(E.tolist(), sface.tolist())}
    cut_edges, cut_faces = [], []
    for (a, b), chain in zip(E.tolist(), chains):
        f = owner[(a, b)]
        S = [a] + [int(to_fracture[x]) for x in chain[1:-1]] + [b]
        tri = triangle(f)
        w = tri[(tri.index(a) + 2) % 3]
        first = [S[0], S[1], w]
        if f >= m:
            added[f - m] = first
        else:
            rewritten[f] = first
        fan_faces = [f] + list(range(m + len(added), m + len(added) + len(S) - 2))
        added.extend([S[i], S[i + 1], w] for i in range(1, len(S) - 1))
        parent.extend([f] * (len(S) - 2))
        # the triangle's other edges now live in the first (w -> a) and last (b -> w) fan triangles
        if (w, a) in owner:
            owner[(w, a)] = fan_faces[0]
        if (b, w) in owner:
            owner[(b, w)] = fan_faces[-1]
        cut_edges.extend(zip(chain[:-1], chain[1:]))
        cut_faces.extend(fan_faces)
    if rewritten:
        mesh.F[list(rewritten)] = np.array(list(rewritten.values()), np.int64)
    if added:
        parent = np.array(parent, np.int64)
        while (parent >= m).any():  # a fan triangle split again: its side ids are its parent's
            parent = np.where(parent >= m, np.r_[np.arange(m), parent][parent], parent)
        mesh.F = np.concatenate([mesh.F, np.array(added, np.int64)])
        mesh.sides = np.concatenate([mesh.sides, mesh.sides[parent]])
    return np.array(cut_edges, np.int64).reshape(-1, 2), np.array(cut_faces, np.int64), to_fracture
