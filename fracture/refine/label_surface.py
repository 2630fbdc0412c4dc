"""The surface of a labelling of the field grid by piece (the global search's cut, Section 4 of
:mod:`fracture.refine.search`): the conforming non-manifold fracture surface between the labels, its grid
terraces smoothed away, its sheets on the floors of psi's valleys and coarsened to triangles of about two
cells.

1. **Contour.** Multi-material marching tetrahedra (:mod:`fracture.mesh.multilabel`): an edge between two
   pieces is crossed where psi is least along it (no nearer a node than :data:`NODE_GAP` of the edge), a
   piece's edge to the outside where it leaves B. The sheets' rims on B then move along B, across their
   sheet, to where psi is least within a cell (the contour put them between two nodes, where the labels
   change, which the psi of a thin layer on B does not see).
2. **Fairing.** Taubin's lambda-mu smoothing evens out the grid's terraces, the sheets' rims and junctions
   smoothed along themselves; then each vertex off the feature curves moves along its normal, within
   :data:`_VALLEY_REACH` of a cell, to where psi is least, on the sheets whose integral of psi that lowers
   (on dense samples).
3. **Untangling.** Every move above is taken back where it makes triangles cross that did not, or rims
   cross on B (Section 5: B could not be cut along both), with its neighbours, until nothing new crosses.
4. **Coarsening.** Each sheet is coarsened to triangles of about two cells (:mod:`fracture.mesh.sheets`:
   the flow refines where psi varies; a plane needs no grid-fine triangles), its rims and junctions kept
   vertex for vertex.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from fracture.mesh.exterior import Exterior
from fracture.mesh.intersect import meeting_pairs
from fracture.mesh.multilabel import contour_labels
from fracture.mesh.sampling import area_barycentric
from fracture.mesh.sheets import coarsen_sheets
from fracture.mesh.topology import face_frames, unique_edges
from fracture.refine.crossings_on_b import close_pairs
from fracture.refine.flow import face_terms
from fracture.tolerances import tol

# Taubin smoothing of the contour: passes and the two factors.
_SMOOTH_PASSES = 30
# ... putting the rims back on B after every this many passes.
_RIM_EVERY = 5
_LAMBDA, _MU = 0.5, -0.53
# A sheet crosses a grid edge at least this fraction of the edge from either node (the cut charges an edge
# the least psi within it: fracture/refine/search.py).
NODE_GAP = 0.15
# Moved contour vertices keep this far from every other vertex (cells).
_APART = 1e-3
# The sheets' vertices move along their normals to where psi is least within this much of a cell
# (_to_valley) ...
_VALLEY_REACH = 0.3
# ... where psi there is lower by this fraction of psi's range (in a broad valley psi hardly changes across a
# cell, and the least of a few samples would roughen the sheet)
_VALLEY_DROP = 1e-3
# ... on the sheets whose integral of psi that lowers, measured on this many samples per cell of area
_VALLEY_SAMPLES = 4.0


def label_surface(sub, near, labels: np.ndarray, B: Exterior, psi_at, span: float, offset: float, grain=None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fracture surface between the pieces ``labels`` of the nodes ``near`` (flat indices) of the box
    grid ``sub`` (its ``origin``, ``spacing``, ``shape`` and ``size``; module notes): its points,
    triangles and the pieces on either side of each, ``(m, 2)``; no triangles if the labels make none.
    ``psi_at`` gives psi at points, ``span`` is its range over the grid, ``offset`` the shift the flow adds
    to it, ``grain`` (optional) the fibres of an anisotropic strength."""
    h = float(np.min(sub.spacing))
    V, F, sides = _contour(sub, near, labels, B, psi_at)
    if not len(F):
        return V, F, sides
    crossed = meeting_pairs(V, F)
    edges = unique_edges(F)  # the triangles stay the same until the coarsening: their edges and counts
    V, crossed = _untangled(V, _apart(V, _rim_to_least(V, F, B, psi_at, h, edges), h), F, B, crossed, edges)
    X = _smooth(V, F, B, edges)
    X = _where_lower(X, _to_valley(X, F, psi_at, h, span, edges), F, sides, psi_at, h, offset, grain)
    V, crossed = _untangled(V, _apart(V, X, h), F, B, crossed, edges)
    V, F, sides = coarsen_sheets(V, F, sides, cell=h, crossings=len(crossed))
    used, inv = np.unique(F, return_inverse=True)  # the vertices the coarsening collapsed away go
    return V[used], inv.reshape(-1, 3).astype(np.int64), sides


def sheet_key(sides: np.ndarray) -> np.ndarray:
    """One integer per triangle naming its sheet (its unordered pair of pieces)."""
    return np.sort(sides, axis=1) @ np.array([1 << 20, 1])


def _contour(sub, near, labels, B: Exterior, psi_at):
    """Fracture triangles between the labels (module notes). Only the band's nodes carry their pieces; the
    rest of the box is label 0, like the outside: the sheets lie within the band, and only tetrahedra with
    two pieces are contoured, so no sheet meets such a node (a piece's label given to the nodes beyond the
    band by their nearest band node would be wrong across a gap of the outside, in a concave object, and
    make sheets there)."""
    vol = np.zeros(sub.size, np.int64)
    vol[near] = labels + 1
    vol = vol.reshape(sub.shape)

    def crossing(P0, P1, la, lb):
        out = (la == 0) | (lb == 0)
        t = np.full(len(P0), 0.5)
        t[~out] = _least_along(P0[~out], P1[~out], psi_at)
        if out.any():  # where the edge leaves B: a ray cast from its end inside, or by bisection of B's
            # winding number where the ray meets B nowhere on the edge (a node on B counts as outside)
            A, C = P0[out], P1[out]
            a_in = la[out] > 0
            s = B.crossing(np.where(a_in[:, None], A, C), np.where(a_in[:, None], C, A))
            cast = np.where(a_in, s, 1.0 - s)
            lo, hi = np.zeros(len(A)), np.ones(len(A))
            rest = np.flatnonzero(np.isnan(cast))
            for _ in range(10 if len(rest) else 0):
                mid = 0.5 * (lo[rest] + hi[rest])
                ins = B.inside(A[rest] + mid[:, None] * (C[rest] - A[rest]))
                toward = ins == a_in[rest]  # still on the first end's side
                lo[rest], hi[rest] = np.where(toward, mid, lo[rest]), np.where(toward, hi[rest], mid)
            t[out] = np.where(np.isnan(cast), 0.5 * (lo + hi), cast)
        # no point between two pieces near a node: the polygons of the tetrahedra around it would leave
        # slivers (an edge of a hundredth of a cell) that the flow's collision tests cannot keep apart (a
        # crossing of B stays on B: no node lies on B, _ON_B)
        t[~out] = np.clip(t[~out], NODE_GAP, 1.0 - NODE_GAP)
        return t

    c = contour_labels(vol, sub.origin, sub.spacing, crossing, pieces_only=True, order_by_points=True)
    used, inv = np.unique(c.fracture_F, return_inverse=True)
    return c.V[used], inv.reshape(-1, 3).astype(np.int64), c.sides.astype(np.int64)


def _least_along(P0: np.ndarray, P1: np.ndarray, psi_at, samples: int = 9) -> np.ndarray:
    """Where along each segment ``P0 -> P1`` psi is least (0 at ``P0``; :func:`_least_on_lines`)."""
    if not len(P0):
        return np.zeros(0)
    return np.clip(_least_on_lines(P0, P1 - P0, np.linspace(0.0, 1.0, samples), psi_at)[0], 0.0, 1.0)


def _least_on_lines(X0: np.ndarray, D: np.ndarray, u: np.ndarray, psi_at) -> tuple[np.ndarray, np.ndarray]:
    """Where psi is least on each line ``X0 + t D`` sampled at the even parameters ``u``: the least sample,
    moved to the vertex of the parabola through it and its two neighbours (within a sample of it); and
    the samples ``(len(X0), len(u))``."""
    X = X0[:, None, :] + u[None, :, None] * D[:, None, :]
    f = psi_at(X.reshape(-1, 3)).reshape(len(X0), len(u))
    k = np.clip(np.argmin(f, axis=1), 1, len(u) - 2)
    rows = np.arange(len(X0))
    a, b, c = f[rows, k - 1], f[rows, k], f[rows, k + 1]
    curve = a - 2 * b + c
    shift = np.where(curve > 0, 0.5 * (a - c) / np.where(curve > 0, curve, 1.0), 0.0)
    return u[k] + np.clip(shift, -1.0, 1.0) * (u[1] - u[0]), f


def _rim_to_least(V: np.ndarray, F: np.ndarray, B: Exterior, psi_at, h: float, edges: tuple, samples: int = 9
                  ) -> np.ndarray:
    """The sheets' rim vertices (on boundary edges) moved along B across their sheet, within a cell either
    side, to where psi is least: the contour puts a rim point between two nodes, where the cut's labels
    change, which the psi of a thin layer on B does not see. ``edges``: :func:`unique_edges` of ``F``."""
    e, count = edges
    rim = np.unique(e[count == 1])
    if not len(rim):
        return V
    normal = _vertex_normals(V, F)
    _, tri, _ = B.closest(V[rim])
    nb = B.normals[tri]
    t = normal[rim] - np.einsum("ij,ij->i", normal[rim], nb)[:, None] * nb
    length = np.linalg.norm(t, axis=1)
    ok = length > tol.tiny
    rim, t = rim[ok], t[ok] / length[ok, None]
    u = np.linspace(-h, h, samples)
    X = (V[rim][:, None, :] + u[None, :, None] * t[:, None, :]).reshape(-1, 3)
    X = B.closest(X)[2]
    f = psi_at(X).reshape(len(rim), samples)
    best = np.argmin(f, axis=1)
    out = V.copy()
    out[rim] = X.reshape(len(rim), samples, 3)[np.arange(len(rim)), best]
    return out


def _vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Per vertex the sum of its triangles' unit normals (not normalised; zero where they cancel)."""
    _, n = face_frames(V, F)
    return np.stack([np.bincount(F.ravel(), np.repeat(n[:, c], 3), len(V)) for c in range(3)], 1)


def _to_valley(V: np.ndarray, F: np.ndarray, psi_at, h: float, span: float, edges: tuple, samples: int = 7
               ) -> np.ndarray:
    """The vertices off the sheets' feature curves (rims and junctions) moved along their normals, within
    :data:`_VALLEY_REACH` of a cell, to where psi is least (the least of ``samples`` values, moved to the
    vertex of the parabola through it and its neighbours), where that is lower than where they are by
    :data:`_VALLEY_DROP` of psi's range ``span``.

    The contour crosses each grid edge where psi is least along the edge, but no nearer a node than
    :data:`NODE_GAP` of it, and the smoothing then evens out the terraces: a thin weak layer (mortar) or
    one on a plane of nodes ends a tenth of a cell or more off the sheet's valley, where the integral of
    psi is well above its floor. On the collapsing wall this lowers the search's functional by 13 %.
    ``edges``: :func:`unique_edges` of ``F``."""
    e, count = edges
    held = np.zeros(len(V), bool)
    held[e[count != 2].ravel()] = True
    normal = _vertex_normals(V, F)
    length = np.linalg.norm(normal, axis=1)
    ids = np.flatnonzero(~held & (length > tol.tiny))
    if not len(ids):
        return V
    normal = normal[ids] / length[ids, None]
    t, f = _least_on_lines(V[ids], normal, np.linspace(-_VALLEY_REACH * h, _VALLEY_REACH * h, samples), psi_at)
    go = f[:, samples // 2] - f.min(axis=1) > _VALLEY_DROP * span
    out = V.copy()
    out[ids[go]] += t[go, None] * normal[go]
    return out


def _where_lower(V, X, F, sides, psi_at, h, offset, grain=None) -> np.ndarray:
    """``X`` (moved vertices of ``V``, the same triangles) on the sheets whose integral of psi it lowers,
    ``V`` on the others: both integrals from the same samples (:data:`_VALLEY_SAMPLES` per cell of
    area), spread by area over ``V``'s triangles and weighted on ``X``'s by the change of their areas (the
    difference of the two then has little noise)."""
    AV, GV, _ = face_terms(V, F, grain)
    if not AV.sum() > 0.0:
        return V
    _, GX, _ = face_terms(X, F, grain)
    count = int(np.clip(_VALLEY_SAMPLES * AV.sum() / (h * h), 20000, 1000000))
    f, bary = area_barycentric(AV, count, np.random.default_rng(0))
    per = np.maximum(AV[f], tol.tiny)
    on_v = (psi_at(np.einsum("nk,nkc->nc", bary, V[F[f]])) + offset) * GV[f] / per
    on_x = (psi_at(np.einsum("nk,nkc->nc", bary, X[F[f]])) + offset) * GX[f] / per
    _, sheet = np.unique(sheet_key(sides), return_inverse=True)
    lower = np.bincount(sheet[f], on_x - on_v, sheet.max() + 1) < 0
    out = V.copy()
    moved = lower[sheet]
    ids = np.unique(F[moved])
    out[ids] = X[ids]
    return out


def _apart(V: np.ndarray, X: np.ndarray, h: float) -> np.ndarray:
    """``X`` (moved vertices of ``V``) with the moved vertices that came within :data:`_APART` cells of
    another vertex back where they were: rims put on B can meet at one point of a crease, and two vertices
    in one place leave a piece a hole of no size."""
    X = X.copy()
    for _ in range(4):
        pairs = cKDTree(X).query_pairs(_APART * h, output_type="ndarray")
        if not len(pairs):
            break
        ids = np.unique(pairs.ravel())
        ids = ids[(X[ids] != V[ids]).any(axis=1)]
        if not len(ids):
            break
        X[ids] = V[ids]
    return X


def _uncrossed(V: np.ndarray, X: np.ndarray, F: np.ndarray, crossed: np.ndarray, rounds: int = 8
               ) -> tuple[np.ndarray, np.ndarray]:
    """``X`` (moved vertices of ``V``) with the vertices of triangles that cross where they did not cross in
    ``V`` (whose crossing pairs of triangles are ``crossed``) back where they were, with their neighbours,
    until no more pairs cross than before (at worst ``V`` itself); and the pairs that cross in the result.
    Only the pairs with a triangle that moved are tested (two triangles that kept their corners cross as
    they did in ``V``: after the rims' moves a few hundredths of the triangles), and after each round only
    those of the triangles it moved back."""
    X = X.copy()
    moved = (X != V).any(axis=1)[F].any(axis=1)
    pairs = np.concatenate([crossed[~(moved[crossed[:, 0]] | moved[crossed[:, 1]])], meeting_pairs(X, F, moved)])
    for _ in range(rounds):
        if len(pairs) <= len(crossed):
            return X, pairs
        back = np.unique(F[pairs.ravel()].ravel())
        ring = np.isin(F, back).any(axis=1)
        back = np.unique(F[ring].ravel())
        X[back] = V[back]
        moved = np.isin(F, back).any(axis=1)
        pairs = np.concatenate([pairs[~(moved[pairs[:, 0]] | moved[pairs[:, 1]])], meeting_pairs(X, F, moved)])
    return (X, pairs) if len(pairs) <= len(crossed) else (V, crossed)


def _rims_uncrossed(V: np.ndarray, X: np.ndarray, E: np.ndarray, normal_at, had: np.ndarray | None = None,
                    rounds: int = 8) -> np.ndarray:
    """``X`` (moved vertices of ``V``) with the moved ends of rim edges ``E`` that cross another on B where
    they did not in ``V`` (seen along B's normal: :mod:`fracture.refine.crossings_on_b`) back where they
    were, until none does (at worst ``V`` itself); ``X`` itself when nothing went back. Rim vertices moved
    each on its own across their sheet (:func:`_rim_to_least`) can zigzag so that a curve crosses itself or
    another on B with no triangles meeting in space: B could not be cut along both (Section 5). ``had``:
    :func:`_rim_crossings` of ``V``, if known."""
    had = _rim_crossings(V, E, normal_at) if had is None else had
    out = X
    for _ in range(rounds):
        new = np.setdiff1d(_rim_crossings(out, E, normal_at), had)
        if not len(new):
            return out
        back = np.unique(E[np.concatenate([new // len(E), new % len(E)])].ravel())
        back = back[(out[back] != V[back]).any(axis=1)]
        if not len(back):
            break
        out = out.copy() if out is X else out
        out[back] = V[back]
    return V


def _rim_crossings(P: np.ndarray, E: np.ndarray, normal_at) -> np.ndarray:
    """The pairs ``(i, j)`` of rim edges ``E`` that cross on B at positions ``P``, as ``i * len(E) + j``."""
    pairs, cross = close_pairs(P, E, normal_at)
    return pairs[cross, 0] * len(E) + pairs[cross, 1]


def _untangled(V: np.ndarray, X: np.ndarray, F: np.ndarray, B: Exterior, crossed: np.ndarray, edges: tuple
               ) -> tuple[np.ndarray, np.ndarray]:
    """``X`` (moved vertices of ``V``, whose crossing pairs of triangles are ``crossed``) with what makes
    rims cross on B (:func:`_rims_uncrossed`) or triangles cross in space (:func:`_uncrossed`) taken back,
    the two in turn until the rims' guard takes back nothing after the triangles' (at worst ``V``); and the
    pairs that cross. ``edges``: :func:`unique_edges` of ``F``."""
    e, count = edges
    E = e[count == 1]
    had = _rim_crossings(V, E, B.normal_at)
    X = _rims_uncrossed(V, X, E, B.normal_at, had)
    for _ in range(4):
        Y, pairs = _uncrossed(V, X, F, crossed)
        Z = _rims_uncrossed(V, Y, E, B.normal_at, had)
        if Z is Y:
            return Y, pairs
        X = Z
    return V, crossed


def _smooth(V: np.ndarray, F: np.ndarray, B: Exterior, edges: tuple) -> np.ndarray:
    """Taubin's lambda-mu smoothing of the contour's terraces, the sheets' feature curves (rims on B:
    boundary edges; junctions: edges of three or more triangles) smoothed along themselves (a vertex on one
    curve over its two neighbours on it, a rim vertex then put back on B), the points where curves meet
    held (:func:`_uncrossed` takes back what makes triangles cross).

    Written here because the surface is non-manifold along its junctions, which pymeshlab's and libigl's
    smoothing filters do not take. ``edges``: :func:`unique_edges` of ``F``."""
    e, count = edges
    feature = count != 2
    on_feature = np.zeros(len(V), bool)
    on_feature[e[feature].ravel()] = True
    # a vertex off the curves takes all its neighbours; one on them, only its neighbours along them
    both = np.concatenate([e, e[:, ::-1]])
    keep = ~on_feature[both[:, 0]] | np.concatenate([feature, feature])
    both = both[keep]
    A = sp.csr_matrix((np.ones(len(both)), (both[:, 0], both[:, 1])), shape=(len(V), len(V)))
    # a vertex on the curves with other than two neighbours along them is where curves meet (or end)
    held = on_feature & (np.bincount(e[feature].ravel(), minlength=len(V)) != 2)
    deg = np.asarray(A.sum(axis=1)).ravel()
    move = np.flatnonzero((~held) & (deg > 0))
    # a moving vertex's mean of its neighbours less itself; a held one's rows are empty
    scale = np.zeros(len(V))
    scale[move] = 1.0 / np.maximum(deg[move], 1)
    umbrella = (sp.diags(scale) @ A - sp.diags((scale > 0).astype(np.float64))).tocsr()
    rim = np.zeros(len(V), bool)
    rim[e[count == 1].ravel()] = True
    rim = move[rim[move]]
    X = V.copy()
    for k in range(_SMOOTH_PASSES):
        for f in (_LAMBDA, _MU):
            X += f * (umbrella @ X)
        # the rims back on B every few passes and after the last (a pass moves them along their curve by a
        # fraction of an edge, off B by less)
        if len(rim) and (k % _RIM_EVERY == _RIM_EVERY - 1 or k == _SMOOTH_PASSES - 1):
            X[rim] = B.closest(X[rim])[2]
    return X
