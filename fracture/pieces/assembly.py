"""Watertight high-resolution pieces from B and the refined fracture surface (Section 5).

After :func:`fracture.pieces.imprint.imprint_boundary`, B's cut edges are the
refined surface S's boundary edges. B splits along them into patches; each
patch belongs to the component on its side of the S triangle at its cut
edges. A piece is its component's patches plus every S triangle with the
component on one side, turned so that the normal points out of it: one
closed, 2-manifold, outward mesh per component.

Where S leaves B between two boundary vertices (a fracture triangle grazing
a concave part of B), the piece on the far side of S would cross itself: its
B patch and its S triangles pass through each other and enclose a thin
inverted pocket. Such a piece is resolved by libigl's exact mesh boolean
(the union of the piece with nothing, Zhou et al. 2016): its triangles are
cut along the crossing curves and what has winding number 1 is kept, so the
pocket goes and the piece is closed, 2-manifold and free of
self-intersections. The piece on the near side of S keeps the sliver of S
outside B; both are a thin shell of S's grazing triangles in volume.

The boolean is exact, but its new vertices are rounded to doubles, and where
S grazes B the crossing curves of nearly coplanar triangles are so close
that the rounding leaves sliver triangles crossing their neighbours. When a
piece cannot be resolved, all pieces are resolved again from positions
moved by a fixed pseudo-random jitter of :data:`JITTERS` of B's diagonal,
the smallest first (the whole shared array, so neighbouring pieces keep meeting exactly): the
degenerate configurations are gone and so are the slivers. This is a
numeric perturbation in place of a symbolic one (which the boolean does not
offer), at a scale far below the mesh's.

All pieces index one vertex array: S's vertices (shared by the pieces that
meet there), vertices made on S triangles by the resolution, then B's
vertices off the cut and vertices made on B triangles.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import igl.copyleft.cgal as igl_cgal
import numpy as np
import scipy.sparse as sp

from fracture.coarse.surface import flood_fill_patches
from fracture.pieces.imprint import Imprint
from fracture.mesh.intersect import self_intersections
from fracture.mesh.exterior import fast_winding
from fracture.mesh.fracture_surface import FractureSurface
from fracture.mesh.topology import (across_edges, barycentric_weights, corner_groups, diagonal,
                                    directed_edge_face, manifold_vertices, signed_volume, weld)

# Jittered attempts after the plain one (seeds 1, 2, ...), each moving the positions by up to this much of B's
# diagonal (see the module doc): the smallest first; a larger one clears slivers that a tiny one leaves where
# S grazes B over many triangles (random cuts through stairs, a Cell Fracture monkey), and is still far below
# the mesh's scale (a grid cell is about 1e-2 of the diagonal).
JITTERS = (1e-9, 1e-8, 1e-7, 1e-6)


@dataclass
class Pieces:
    """One closed mesh per component over a shared vertex array.

    Attributes
    ----------
    V : (n, 3) float
        Material-space positions: the refined fracture surface's vertices
        (the first ``n_surface``), the vertices the resolution of crossings
        made on its triangles (up to ``n_fracture``), then B's vertices that
        are not on S and those the resolution made on B's triangles.
    n_fracture : int
        Vertices that move like the fracture surface (``V[:n_fracture]``).
    faces : list of (m_c, 3) int
        Triangles of each piece (component order), indexing ``V``.
    exterior : list of (m_c,) bool
        Which triangles of a piece come from B.
    patch_agreement : float
        Smallest share, over B's patches, of the cut-edge votes that agree
        with the patch's component (1 when every cut edge agrees).
    derived : csr (n_fracture - n_surface, n_surface)
        Barycentric weights of the vertices made on S triangles, over the
        corners of the triangle each lies on.
    resolved : list of int or None
        Per piece, the crossing triangle pairs the resolution removed.
    crossings : list of int or None
        Per piece, the crossing triangle pairs left: nonzero only where the
        resolution was refused (see :func:`resolve_crossings`). Both are
        ``None`` for pieces built without the resolution.
    jitter_seed : int
        0, or the seed of the jitter ``V`` was moved by so that every piece
        could be resolved: seed ``k`` moves by up to ``JITTERS[k - 1]`` of B's
        diagonal (see the module doc).
    dissent : (d, 3) float or None
        Where the cut edges whose votes disagree with their patch's component
        end (:func:`label_patches`): a rim of S that cuts B's patches
        inconsistently (:mod:`fracture.pieces.holes`).
    """

    V: np.ndarray
    n_fracture: int
    faces: list
    exterior: list
    patch_agreement: float
    derived: sp.csr_matrix | None = None
    resolved: list | None = None
    crossings: list | None = None
    jitter_seed: int = 0
    dissent: np.ndarray | None = None

    def __post_init__(self):
        if self.derived is None:
            self.derived = sp.csr_matrix((0, self.n_fracture))

    @property
    def n_surface(self) -> int:
        return self.n_fracture - self.derived.shape[0]

    @property
    def unresolved(self) -> list[int]:
        """Pieces that still cross themselves (their resolution was refused)."""
        return [c for c, n in enumerate(self.crossings or []) if n]

    def fracture_tree(self, tree: sp.csr_matrix) -> sp.csr_matrix:
        """Extend S's barycentric tree map ``tree`` (``n_surface`` rows) to the first ``n_fracture`` vertices."""
        return sp.vstack([sp.csr_matrix(tree), self.derived @ tree], format="csr")

    @property
    def n_pieces(self) -> int:
        return len(self.faces)

    @cached_property
    def parts(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Per piece: vertex ids (into ``V``, sorted), local vertices and local triangles."""
        out = []
        for F in self.faces:
            ids, local = np.unique(F, return_inverse=True)
            out.append((ids, self.V[ids], local.reshape(-1, 3)))
        return out

    def piece(self, c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vertex ids (into ``V``), local vertices and local triangles of piece ``c``."""
        return self.parts[c]


def label_patches(im: Imprint, mesh: FractureSurface, n_components: int, fallback
                  ) -> tuple[np.ndarray, float, np.ndarray]:
    """Component of each of B's triangles, by patch.

    The rule is the one that makes the pieces closed, so it reads only the
    orientations, never the geometry. In piece ``sides[:, 0]`` an S triangle
    keeps its orientation and in ``sides[:, 1]`` it is reversed; a closed,
    oriented piece passes each of its edges once in each direction. So at a
    cut edge where the S triangle runs ``u -> v``, the B triangle that also
    runs ``u -> v`` belongs to ``sides[:, 1]`` and the one running ``v -> u``
    to ``sides[:, 0]``. (A side test of B's centroids against the S
    triangle's plane, as used before, guesses wrong where S meets B at a
    grazing angle: the thin pieces of a torus or a monkey.) Each patch takes
    the component its cut edges vote for; patches with no cut edge take
    ``fallback(face_ids)``, the components of their triangles by another rule
    (majority). The second value is the smallest share of a patch's votes
    that agree with its label (1 unless S's boundary curves on B cross), the
    third the cut edges (rows of ``im.cut_edges``) whose vote disagrees with
    the label of the patch on either side.
    """
    patch = flood_fill_patches(im.F, im.cut_edges)
    n_patch = int(patch.max()) + 1 if len(patch) else 0
    E = im.cut_edges
    T = mesh.F[im.cut_faces]
    su, sv = im.to_fracture[E[:, 0]], im.to_fracture[E[:, 1]]
    forward = np.zeros(len(E), bool)  # the S triangle runs su -> sv
    backward = np.zeros(len(E), bool)
    for i in range(3):
        forward |= (T[:, i] == su) & (T[:, (i + 1) % 3] == sv)
        backward |= (T[:, i] == sv) & (T[:, (i + 1) % 3] == su)
    counted = (forward | backward).astype(np.float64)  # a cut edge off its triangle has no say
    sides = mesh.sides[im.cut_faces]
    votes = np.zeros((n_patch, n_components))
    along, against = patch[directed_edge_face(im.F, E)], patch[directed_edge_face(im.F, E[:, ::-1])]
    vote_along, vote_against = np.where(forward, sides[:, 1], sides[:, 0]), np.where(forward, sides[:, 0], sides[:, 1])
    np.add.at(votes, (along, vote_along), counted)
    np.add.at(votes, (against, vote_against), counted)
    label = votes.argmax(axis=1)
    dissent = np.flatnonzero((counted > 0) & ((label[along] != vote_along) | (label[against] != vote_against)))
    total = votes.sum(axis=1)
    voted = total > 0
    agreement = float((votes.max(axis=1)[voted] / total[voted]).min()) if voted.any() else 1.0
    for p in np.flatnonzero(~voted):
        faces = np.flatnonzero(patch == p)
        label[p] = np.bincount(fallback(faces), minlength=n_components).argmax()
    return label[patch], agreement, dissent


def build_pieces(im: Imprint, mesh: FractureSurface, n_components: int, fallback, resolve: bool = True) -> Pieces:
    """Assemble the closed pieces from imprinted B ``im`` and the refined surface ``mesh``.

    ``fallback(face_ids)`` labels B triangles of patches that touch no cut
    (see :func:`label_patches`). With ``resolve``, pieces that cross
    themselves are resolved (:func:`resolve_crossings`).
    """
    component, agreement, dissent = label_patches(im, mesh, n_components, fallback)
    n_s = len(mesh.V)
    off = im.to_fracture < 0
    to_u = im.to_fracture.copy()
    to_u[off] = n_s + np.arange(int(off.sum()))
    V = np.concatenate([mesh.V, im.V[off]])
    faces, exterior = [], []
    for c in range(n_components):
        fb = to_u[im.F[component == c]]
        front = mesh.F[mesh.sides[:, 0] == c]  # normal points away from c: outward already
        back = mesh.F[mesh.sides[:, 1] == c][:, ::-1]
        F = np.concatenate([fb, front, back])
        ext = np.r_[np.ones(len(fb), bool), np.zeros(len(front) + len(back), bool)]
        keep = ~_cancelling(F)
        faces.append(F[keep])
        exterior.append(ext[keep])
    pieces = Pieces(V=V, n_fracture=n_s, faces=faces, exterior=exterior, patch_agreement=agreement,
                    dissent=im.V[np.unique(im.cut_edges[dissent])])
    return _resolve_pieces(pieces) if resolve else pieces


def _resolve_pieces(pieces: Pieces) -> Pieces:
    """Resolve every self-crossing piece; if one is refused, retry all from jittered positions (module doc)."""
    out, failed = _resolve_all(pieces)
    if not failed:
        return out
    size = diagonal(pieces.V)
    for seed, relative in enumerate(JITTERS, start=1):
        jitter = np.random.default_rng(seed).uniform(-1.0, 1.0, pieces.V.shape) * (relative * size)
        moved, failed_moved = _resolve_all(replace(pieces, V=pieces.V + jitter, jitter_seed=seed))
        if len(failed_moved) < len(failed):
            out, failed = moved, failed_moved
        if not failed:
            break
    return out


def _resolve_all(pieces: Pieces) -> tuple[Pieces, list[int]]:
    """Resolve every self-crossing or pinched piece, renumber the shared vertices (order: see :class:`Pieces`).

    Also returns the pieces whose resolution was refused.
    """
    n_s, n_v = pieces.n_fracture, len(pieces.V)
    faces, exterior = list(pieces.faces), list(pieces.exterior)
    resolved, left = [0] * pieces.n_pieces, [0] * pieces.n_pieces
    new_pos, new_parents, new_weights, new_on_s = [], [], [], []
    n_new = 0
    failed = []
    for c, (ids, V, F) in enumerate(pieces.parts):
        pairs = crossing_pairs(V, F)
        pinched = not manifold_vertices(F).all()
        if not (pairs or pinched):
            continue
        out = resolve_crossings(V, F, pieces.exterior[c], boolean=bool(pairs))
        if out is None:
            left[c] = int(pairs)
            failed.append(c)
            continue
        FC, ext, source, P, parents, weights, on_s = out
        to_global = np.where(source >= 0, ids[np.maximum(source, 0)], -1)
        new = np.flatnonzero(source < 0)
        to_global[new] = n_v + n_new + np.arange(len(new))
        n_new += len(new)
        faces[c], exterior[c] = to_global[FC], ext
        new_pos.append(P), new_parents.append(ids[parents]), new_weights.append(weights), new_on_s.append(on_s)
        resolved[c] = int(pairs)
    if not n_new:
        return replace(pieces, faces=faces, exterior=exterior, resolved=resolved, crossings=left), failed
    P, parents, weights, on_s = (np.concatenate(a) for a in (new_pos, new_parents, new_weights, new_on_s))
    # order: S's vertices, new ones on S, B's vertices, new ones on B
    old = np.arange(n_v + n_new)
    order = np.concatenate([old[:n_s], n_v + np.flatnonzero(on_s), old[n_s:n_v], n_v + np.flatnonzero(~on_s)])
    renumber = np.empty_like(order)
    renumber[order] = np.arange(len(order))
    V = np.concatenate([pieces.V, P])[order]
    k = int(on_s.sum())
    derived = sp.csr_matrix((weights[on_s].ravel(), (np.repeat(np.arange(k), 3), parents[on_s].ravel())),
                            shape=(k, n_s))
    return replace(pieces, V=V, n_fracture=n_s + k, faces=[renumber[F] for F in faces], exterior=exterior,
                   derived=derived, resolved=resolved, crossings=left), failed


def resolve_crossings(V: np.ndarray, F: np.ndarray, exterior: np.ndarray, volume_tolerance: float = 0.5,
                      boolean: bool = True):
    """Resolve a closed mesh that crosses itself into the boundary of its winding-number-positive region.

    libigl's exact boolean (the union of ``(V, F)`` with nothing) cuts the
    triangles along their crossing curves and keeps the boundary of the
    region of positive winding number. The result is refused (``None``)
    when the boolean fails, and unless it is closed, 2-manifold, outward and free of crossings, with a
    volume within ``volume_tolerance`` of the input's (the pockets it drops
    are thin; a result that far off is not the same piece). Vertices the
    boolean rounded within 1e-9 of each other are welded first
    (:func:`weld_rounded`), and pinched vertices get a copy per extra fan
    (:func:`split_pinches`); with ``boolean=False`` only the pinches are
    split (a piece that touches itself at a vertex but crosses nowhere).

    Returns ``(F, exterior, source, P, parents, weights, on_s)``: the new
    triangles over ``[V[source >= 0]; P]`` ordered as the output vertices
    (``source[i]`` is the input vertex output vertex ``i`` is, ``-1`` for
    the new ones, which are ``P`` in order), each triangle's ``exterior``
    flag, and per new vertex the corners (``parents``, into ``V``) and
    barycentric ``weights`` of the input triangle it lies on, an S triangle
    (``on_s``) where it lies on one.
    """
    if boolean:
        try:
            VC, FC, J = igl_cgal.mesh_boolean(np.ascontiguousarray(V, np.float64), np.ascontiguousarray(F, np.int64),
                                              np.zeros((0, 3)), np.zeros((0, 3), np.int64), "union")
        except RuntimeError:  # CGAL gives up on some inputs (e.g. coincident crossing curves): refused as well
            return None
        J = np.asarray(J).ravel()
        FC, J = weld_rounded(VC, FC, J)
    else:  # a piece that only touches itself at a vertex: its pinches are split below
        VC, FC, J = np.asarray(V, np.float64), np.asarray(F, np.int64), np.arange(len(F))
    used = np.unique(FC)
    if len(used) < len(VC):  # every output vertex must be on a triangle (its birth triangle is read there)
        remap = np.full(len(VC), -1)
        remap[used] = np.arange(len(used))
        VC, FC = VC[used], remap[FC]
    VC, FC = split_pinches(VC, FC)
    ch = mesh_checks(VC, FC)
    if not (ch["closed_oriented"] and ch["vertex_manifold"] and ch["self_intersections"] == 0):
        return None
    before = signed_volume(V, F)
    if abs(ch["volume"] - before) > volume_tolerance * abs(before):
        return None
    # input vertices come out with the same coordinates (the boolean rounds exact points to doubles)
    _, inv = np.unique(np.concatenate([V, VC]), axis=0, return_inverse=True)
    inv = inv.ravel()
    first = np.full(inv.max() + 1, -1)
    first[inv[:len(V)][::-1]] = np.arange(len(V))[::-1]
    source = first[inv[len(V):]]
    ext = np.asarray(exterior, bool)[J]
    new = np.flatnonzero(source < 0)
    if not len(new):
        return FC, ext, source, np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros((0, 3)), np.zeros(0, bool)
    # each new vertex takes one triangle it was born on, an S triangle if it has one
    corner_v = FC.ravel()
    corner_f = np.repeat(np.arange(len(FC)), 3)
    is_new = source[corner_v] < 0
    corner_v, corner_f = corner_v[is_new], corner_f[is_new]
    order = np.lexsort((ext[corner_f], corner_v))
    corner_v, corner_f = corner_v[order], corner_f[order]
    head = np.r_[True, corner_v[1:] != corner_v[:-1]]
    birth = J[corner_f[head]]  # aligned with new (sorted vertex ids)
    parents = np.asarray(F, np.int64)[birth]
    P = VC[new]
    weights = barycentric_weights(P, V[parents])
    return FC, ext, source, P, parents, weights, ~np.asarray(exterior, bool)[birth]


def _cancelling(F: np.ndarray) -> np.ndarray:
    """Triangles that come in pairs on the same corners with opposite orientations (a fin of no volume).

    A fracture triangle lying on B (its corners all on the cut) meets B's
    triangle there face to face; the two bound nothing and both go.
    """
    S = np.sort(F, axis=1)
    inv, count = corner_groups(F)
    twin = np.flatnonzero(count[inv] == 2)
    out = np.zeros(len(F), bool)
    if len(twin):
        # even permutations of the sorted corners have the same orientation
        rot = F[twin] == S[twin, :1]
        k = rot.argmax(axis=1)
        second = F[twin, (k + 1) % 3]
        parity = second == S[twin, 1]
        order = np.argsort(inv[twin], kind="stable")
        a, b = order[0::2], order[1::2]
        opposite = parity[a] != parity[b]
        out[twin[a[opposite]]] = out[twin[b[opposite]]] = True
    return out


def weld_rounded(V: np.ndarray, F: np.ndarray, J: np.ndarray, relative: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Merge the vertices an exact boolean's rounding left within ``relative`` of the diagonal of each other.

    The boolean computes exactly and rounds its new points to doubles; where
    crossing curves nearly meet, that leaves triangles with edges of 1e-16
    that cross their neighbours. Each cluster of such vertices
    (:func:`fracture.mesh.topology.weld`) becomes its lowest-numbered member and
    the triangles that collapse go (with their rows of ``J``, the source
    triangle of every output triangle). Returns the new ``F`` and ``J``;
    unused vertices stay (the caller drops them).
    """
    _, cluster = weld(V, relative * diagonal(V))
    if cluster.max() + 1 == len(V):
        return F, J
    first = np.full(cluster.max() + 1, len(V))
    np.minimum.at(first, cluster, np.arange(len(V)))
    F = first[cluster][F]
    keep = (F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0])
    return F[keep], J[keep]


def split_pinches(V: np.ndarray, F: np.ndarray, nudge: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Give every extra fan of triangles around a non-manifold vertex its own copy of the vertex.

    Where a resolved pocket touched a vertex, the kept region meets itself
    there in two fans (a pinch). Each fan but the largest gets a copy, moved
    ``nudge`` of the way towards the centroid of one of its triangles, so it
    stays in that triangle's plane and the two fans no longer touch.
    (pymeshlab's ``meshing_repair_non_manifold_vertices`` does the same, on
    its own copy of the mesh and without saying which vertex became which.)
    """
    bad = np.flatnonzero(~manifold_vertices(F))
    if not len(bad):
        return V, F
    V, F = list(V), F.copy()
    for v in bad.tolist():  # a handful of vertices
        faces = np.flatnonzero((F == v).any(axis=1))
        # two triangles at v are in one fan when they share an edge (v, w)
        others = [set(F[f].tolist()) - {v} for f in faces]
        fan = list(range(len(faces)))

        def root(i):
            while fan[i] != i:
                fan[i] = fan[fan[i]]
                i = fan[i]
            return i

        for i in range(len(faces)):
            for j in range(i):
                if others[i] & others[j]:
                    fan[root(i)] = root(j)
        label = np.array([root(i) for i in range(len(faces))])
        groups = sorted((faces[label == r] for r in np.unique(label)), key=len, reverse=True)
        for group in groups[1:]:
            centroid = np.mean([V[u] for u in F[group[0]]], axis=0)
            V.append(V[v] + nudge * (centroid - V[v]))
            rows = F[group]
            rows[rows == v] = len(V) - 1
            F[group] = rows
    return np.array(V), F


def crossing_pairs(V: np.ndarray, F: np.ndarray) -> int:
    """Number of pairs of triangles that meet other than at their shared vertex or edge, decided exactly.

    libigl's exact-arithmetic test (CGAL predicates): triangles that come
    within rounding of each other without meeting are not counted, unlike
    the tolerant count the refinement uses for its moving surface
    (:func:`fracture.mesh.intersect.self_intersections`). That count runs
    first: it is faster and misses no crossing (coplanar overlaps aside), so
    where it finds none the exact test is skipped.
    """
    if len(F) < 2 or not self_intersections(V, F):
        return 0
    out = igl_cgal.remesh_self_intersections(np.ascontiguousarray(V, np.float64), np.ascontiguousarray(F, np.int64),
                                             detect_only=True, cutoff=np.iinfo(np.int32).max)
    return int(len(out[2]))


def mesh_checks(V: np.ndarray, F: np.ndarray, intersections: bool = True) -> dict:
    """Closedness, manifoldness, orientation, volume and self-intersections of one mesh.

    ``closed_oriented``: every directed edge appears once and its reverse
    once (closed, edge-manifold and consistently oriented together).
    """
    across = across_edges(F)  # closed and oriented unless None; the one-fan test reads it too
    vertex_manifold = bool(manifold_vertices(F, across).all())
    out = {"closed_oriented": across is not None, "vertex_manifold": vertex_manifold,
           "volume": signed_volume(V, F), "triangles": int(len(F)), "vertices": int(len(V))}
    if intersections:
        out["self_intersections"] = crossing_pairs(V, F)
    return out


def overlap_and_gap(pieces: Pieces, BV: np.ndarray, BF: np.ndarray, samples: int, rng
                    ) -> tuple[float, float, np.ndarray, int]:
    """Where sample points inside B fall: in more than one piece, in none, in each.

    Points are drawn uniformly in B's box; insideness is the winding number.
    Returns the shares of the points inside B that lie in more than one piece
    and in none, each piece's share of them (its volume over B's, estimated
    from its winding number) and how many points fell inside B.
    """
    lo, hi = BV.min(axis=0), BV.max(axis=0)
    P = lo + (hi - lo) * rng.random((samples, 3))
    inside_b = fast_winding(BV, BF, P) > 0.5
    P = P[inside_b]
    count = np.zeros(len(P), np.int64)
    share = np.zeros(pieces.n_pieces)
    n = max(len(P), 1)
    for c in range(pieces.n_pieces):
        _, V, F = pieces.piece(c)
        inside = fast_winding(V, F, P) > 0.5
        count += inside
        share[c] = inside.sum() / n
    return float((count > 1).sum() / n), float((count == 0).sum() / n), share, len(P)
