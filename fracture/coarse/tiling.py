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
   Nodes of slits between two pieces take the nearer piece: slits up to half
   again as wide as the pieces' usual slit (Cell Fracture's margin leaves one
   width between every two neighbours), at least a quarter cell and at most a
   cell; B spans their mouths and the cracks run in their middles (their
   edges' crossings are found with the slits closed). Two pieces overlapping by more than a fifth
   of a cell on average are refused (a moved piece); a piece with no node is
   left out, with a note.
2. **Multi-material marching tetrahedra** (:mod:`fracture.mesh.multilabel`):
   the interfaces between the labels, the fracture sheets between pieces and
   B between a piece and the outside. An edge's crossing lies on the surfaces
   (bisection of the winding numbers along the edge).
3. **Coarsening.** Each sheet (all triangles between one pair of pieces) is
   flat for Cell Fracture and is coarsened by pymeshlab's quadric edge
   collapse with its rim kept vertex for vertex; a sheet whose coarsened
   triangles would cross another keeps its contoured ones.
4. **Pinholes** (:mod:`fracture.coarse.pinholes`): a sheet's closed boundary
   curve on B smaller than a tenth of a cell is collapsed to a point, just
   inside B, with B's island inside it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import igl
import numpy as np
from scipy import ndimage

from fields.grid import thinnest_extent
from fracture.coarse.pinholes import PINHOLE, close_pinholes
from fracture.mesh.multilabel import contour_labels
from fracture.mesh.sheets import coarsen_sheets
from fracture.errors import InputError
from fracture.mesh.exterior import Exterior, fast_winding
from fracture.tolerances import tol
from fracture.mesh.edges import edge_table
from fracture.mesh.topology import closed_oriented, fan, signed_volume, weld

# Cells along the object's largest extent, at least ...
DEFAULT_CELLS = 32
# ... and enough for this many across its thinnest extent (along its principal axes: a plank's thickness; at 32
# along its length a plank 40 times longer than thick had less than a cell across, and lost pieces), ...
_ACROSS = 8
# ... up to this many along the largest extent.
_MOST_CELLS = 256
# Two pieces may overlap by this much on average (grid cells): Cell Fracture's pieces overlap by about
# 1e-4 of the size (up to 0.08 cells measured), a piece moved by 1/40 of the size by 0.4 cells.
_OVERLAP = 0.2
# ... over at least this many grid nodes (a node or two inside two small pieces is noise).
_OVERLAP_NODES = 10
# A piece overlapping others over more than this share of the object's nodes holds them: the object itself.
_HOLDING = 0.5
# A box holds another when it does within this fraction of its diagonal (a piece reaching out of the others'
# box, a box holding the others').
_BOX_SLACK = 0.05
# An object thinner than this fraction of its size lies in a plane: no solid pieces (rounding leaves 1e-16).
_PLANE = 1e-9
# A piece or part is inside out when six times the volume it encloses is below minus this fraction of twice its
# area to the power 3/2 (a ball's ratio is 0.2, a plank a hundredth as thick as wide 0.007; two flat quads that
# Cell Fracture left of a Suzanne as one piece, rounding, 4e-6).
_TURNED = 1e-4
# Corners of a piece closer than this fraction of its size are one vertex.
_WELD = 1e-9
# A piece whose box holds the others' and whose volume is theirs together (within this fraction of its own:
# Cell Fracture's margin takes up to a tenth) is the unfractured object (holding_the_rest).
_HOLDS_VOLUME = 0.15
# A point lies in a slit between two pieces when its distances to its closest points on them add up to at most
# this many times their distance apart (within a tenth of the slit's width of the segment between them).
_BRIDGE = 1.02
# Bisection steps for an edge's crossing (its place to 2^-this of a cell).
_BISECTIONS = 12
# A piece farther from every other piece than this fraction of the pieces' median box diagonal, and than
# _APART_SLITS times the pieces' median distance to their nearest, is not part of the fractured object (a
# ground, a projectile or a collider exported with it): it is left out, with a note.
_APART = 0.25
_APART_SLITS = 10.0
# A piece thinner than this fraction of its largest extent along its least principal axis is flat (a ground
# plane): not a solid, and left out before the grid is laid over the pieces.
_FLAT = 1e-3


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
        The input pieces that take part (all but those thinner than a cell and those not of the object:
        :func:`not_of_the_object`); pieces are numbered in this order.
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


def not_of_the_object(pieces: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which pieces ``(V, F)`` are not of the fractured object, three ``(len(pieces),)`` bool: flat
    (:data:`_FLAT`) and reaching out of the others' box (a ground plane); of the others, the whole of the
    rest (:func:`holding_the_rest`: the unfractured object); of the others, apart from all the rest
    (:func:`apart_from_the_rest`: a ground, a projectile)."""
    n = len(pieces)
    thin = np.array([thinnest_extent(V) <= _FLAT * float(np.ptp(V, axis=0).max()) for V, _ in pieces])
    flat = np.zeros(n, bool)
    if not thin.all():
        # a flat piece within the solids' box (a sliver Cell Fracture left) is left out as thinner than a cell
        # later, on the same grid as before; one that reaches out of it (a ground plane) would widen the grid
        X = np.concatenate([V for (V, _), t in zip(pieces, thin) if not t])
        lo, hi = X.min(axis=0), X.max(axis=0)
        slack = _BOX_SLACK * float(np.linalg.norm(hi - lo))
        flat = thin & np.array([(V.min(axis=0) < lo - slack).any() or (V.max(axis=0) > hi + slack).any()
                                for V, _ in pieces])
    holds, apart = np.zeros(n, bool), np.zeros(n, bool)
    solid = np.flatnonzero(~flat)
    holds[solid] = holding_the_rest([pieces[p] for p in solid])
    rest = np.flatnonzero(~flat & ~holds)
    apart[rest] = apart_from_the_rest([pieces[p] for p in rest])
    return flat, holds, apart


def holding_the_rest(pieces: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Which pieces ``(V, F)`` are the whole of the others, ``(len(pieces),)`` bool: the unfractured object
    exported with its pieces (Cell Fracture hides it; an export of the whole scene writes it). Such a piece,
    among four or more, has a box that holds every other's (within :data:`_BOX_SLACK` of its diagonal) and the
    volume of all the others together (within :data:`_HOLDS_VOLUME` of its own); a piece of a tiling holds
    no other's box, or has the volume of some of them only."""
    holds = np.zeros(len(pieces), bool)
    if len(pieces) < 4:
        return holds
    lo = np.array([V.min(axis=0) for V, _ in pieces])
    hi = np.array([V.max(axis=0) for V, _ in pieces])
    volume = np.array([abs(signed_volume(V, F)) for V, F in pieces])
    for q in range(len(pieces)):
        others = np.delete(np.arange(len(pieces)), q)
        slack = _BOX_SLACK * float(np.linalg.norm(hi[q] - lo[q]))
        boxed = (lo[others] >= lo[q] - slack).all() and (hi[others] <= hi[q] + slack).all()
        holds[q] = boxed and abs(volume[others].sum() - volume[q]) <= _HOLDS_VOLUME * volume[q]
    return holds if (~holds).sum() >= 2 else np.zeros(len(pieces), bool)


def apart_from_the_rest(pieces: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Which pieces ``(V, F)`` lie apart from all the others (:data:`_APART`), ``(len(pieces),)`` bool; none
    when fewer than two would be left (the pieces then tile nothing, which the tiling says).

    Pieces of one fractured object touch their neighbours (Cell Fracture's margin leaves a slit of a
    hundredth of a piece or less); a ground below the object, or a ball thrown at it, is a piece a quarter
    of a piece's size or more from every other (a piece of the object moved a twentieth of its size out of
    place is still one of its pieces). Two pieces' distance is the least distance of
    either's vertices to the other's triangles (each piece's libigl tree built once: :class:`Exterior`), asked
    only of pieces whose boxes come that close."""
    n = len(pieces)
    lo = np.array([V.min(axis=0) for V, _ in pieces])
    hi = np.array([V.max(axis=0) for V, _ in pieces])
    reach = _APART * float(np.median(np.linalg.norm(hi - lo, axis=1)))
    trees = [Exterior(V, F) for V, F in pieces]
    nearest = np.full(n, np.inf)
    for i in range(n):
        near = np.flatnonzero((lo <= hi[i] + reach).all(axis=1) & (hi >= lo[i] - reach).all(axis=1))
        for j in near[near > i].tolist():
            d2 = min(trees[j].closest(pieces[i][0])[0].min(), trees[i].closest(pieces[j][0])[0].min())
            nearest[i] = min(nearest[i], np.sqrt(d2))
            nearest[j] = min(nearest[j], np.sqrt(d2))
    touching = np.isfinite(nearest)
    if touching.sum() < 2:
        return np.zeros(n, bool)
    apart = nearest > max(reach, _APART_SLITS * float(np.median(nearest[touching])))
    return apart if (~apart).sum() >= 2 else np.zeros(n, bool)


def _piece_triangles(V: np.ndarray, polygons: list[list[np.ndarray]]) -> list[tuple[np.ndarray, np.ndarray]]:
    out = []
    for polys in polygons:
        T, _ = fan([np.asarray(f) for f in polys], V)
        used, inv = np.unique(T, return_inverse=True)
        out.append((np.ascontiguousarray(V[used], np.float64), np.ascontiguousarray(inv.reshape(-1, 3), np.int64)))
    return out


def _refuse_twins(pieces, names, where: str) -> None:
    """Refuse two pieces with the same vertices (a piece exported twice), before the grid is labelled: the
    overlap of the labels says it too (:func:`_check_tiling`, for twins that differ in a vertex), after
    the winding numbers of every node (8 s for the 40-frame test object against a few milliseconds)."""
    seen: dict[bytes, int] = {}
    for p, (PV, _) in enumerate(pieces):
        points = np.unique(PV, axis=0)
        key = points.tobytes()
        if key in seen:
            q = seen[key]
            raise InputError(f"{where}pieces {names[q]!r} and {names[p]!r} have the same {len(points)} vertices: "
                             "the pieces must tile the object in the rest pose (is a piece exported twice?)")
        seen[key] = p


def outward(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, bool]:
    """The triangles ``F`` of a piece facing out, and whether any had to turn.

    The pieces' insides are their winding numbers (module notes, 1), which a piece exported inside out
    (its faces facing in: -1 inside) or with some faces turned (about 0 inside) would lose. The faces of
    each closed part (every edge shared by two of its faces) are oriented alike (libigl's ``bfs_orient``);
    a piece whose closed parts enclose a negative volume in all is turned whole, and a closed part that then
    encloses a negative volume is turned, unless it lies wholly inside the larger parts (a cavity's wall
    faces into the cavity; the larger parts are settled first). Parts that overlap, as Suzanne's eyes
    overlap her head, keep their orientation when it is outward; an open part (Suzanne's pieces may hold
    one) has no inside to tell its orientation by and is kept as it was exported."""
    # corners at one place are one vertex here (Cell Fracture writes each piece's faces with corners of their
    # own along some edges): the parts are then closed where the piece is
    size = max(float(np.ptp(V, axis=0).max()), tol.zero)
    _, at = weld(V, _WELD * size)
    W = at[F]
    Wo, part = igl.bfs_orient(W)
    part = np.asarray(part, np.int64)
    G = np.where((np.asarray(Wo) != W).any(axis=1)[:, None], F[:, ::-1], F)  # bfs_orient reverses a row it turns
    open_face = (edge_table(W, len(V)).row_count != 2).reshape(-1, 3).any(axis=1)
    closed = np.bincount(part, open_face.astype(np.int64), minlength=part.max() + 1) == 0
    G[~closed[part]] = F[~closed[part]]
    centre = V.mean(axis=0)  # volumes about a point of the piece
    A, B, C = (V[G[:, i]] - centre for i in range(3))
    volume = np.bincount(part, np.einsum("ij,ij->i", A, np.cross(B, C)))  # six times each part's
    area = np.bincount(part, np.linalg.norm(np.cross(B - A, C - A), axis=1))  # twice each part's
    volume[~closed], area[~closed] = 0.0, 0.0
    if volume.sum() < -_TURNED * area.sum() ** 1.5:  # the piece inside out, a cavity's wall with it
        G[closed[part]] = G[closed[part]][:, ::-1]
        volume = -volume
    for c in np.argsort(-np.abs(volume)):
        if not closed[c] or volume[c] >= -_TURNED * area[c] ** 1.5:
            continue  # open, outward, or a sliver with no inside to lose (Cell Fracture leaves some)
        mine = part == c
        corners = V[np.unique(G[mine])]
        settled = closed & (np.abs(volume) > abs(volume[c])) & (np.arange(len(volume)) != c)  # larger parts
        around = G[settled[part]]
        if len(around) and fast_winding(V, around, corners).min() > 0.5:
            continue  # a cavity's wall: wholly inside the larger parts
        G[mine] = G[mine][:, ::-1]
    return G, bool((G != F).any())


class _Labels(NamedTuple):
    """What :func:`_labels` finds on the grid."""

    label: np.ndarray  # every node's: 0 outside, p + 1 in piece p
    filled: np.ndarray  # the nodes of slits that were filled (module notes)
    overlap: np.ndarray  # the nodes inside two pieces or more, as pairs (k, 2) of the two most inside pieces
    gaps: np.ndarray  # the filled nodes as pairs of the two pieces nearest them
    by_slit: np.ndarray  # the nodes whose edges are bisected with the slits closed (:func:`_winding_crossing`)
    widest: float  # the widest slit that is closed


def _labels(pieces, nodes: np.ndarray, shape, h: float) -> _Labels:
    """The label of every node, and the slits between the pieces that are closed (module notes).

    A slit is closed where it is narrower than the pieces' slits are for the most part (Cell Fracture's
    margin leaves one width between every two neighbours) by half again, between a quarter cell and a cell:
    a slit node within that of two different pieces is filled (it takes the nearer) if a closing by one cell
    fills it (left open, one beside a wall was a bubble of B inside the object) or if it lies between the
    two (at a slit's mouth the closing leaves the node whose neighbour above is outside, and B dipped into
    every crack there). Where the pieces keep apart (their usual slit is wider than a sixth of a cell), the
    nodes by a slit (filled, or within a cell of two pieces, inside or out) have their edges bisected with
    the slits closed; pieces that touch (a margin of 0) are contoured as they are."""
    W = np.zeros((len(pieces), len(nodes)))
    for p, (PV, PF) in enumerate(pieces):
        lo, hi = PV.min(axis=0), PV.max(axis=0)
        pad = 0.5 * (hi - lo).max()  # winding numbers fall off outside the box: only nearby nodes matter
        near = np.all((nodes >= lo - pad) & (nodes <= hi + pad), axis=1)
        W[p, near] = fast_winding(PV, PF, nodes[near])
    in_two = np.flatnonzero((W > 0.5).sum(axis=0) >= 2)
    top2 = np.sort(np.argsort(-W[:, in_two], axis=0)[:2].T, axis=1)
    inside = (W.sum(axis=0) > 0.5).reshape(shape)
    label = np.where(inside.ravel(), W.argmax(axis=0) + 1, 0).reshape(shape)
    closed = ndimage.binary_closing(inside, structure=ndimage.generate_binary_structure(3, 1), border_value=0)
    # the nodes of the cubes that the contour cuts (another label among their 26 neighbours): their edges
    # are the contour's
    mixed = ndimage.maximum_filter(label, size=3) != ndimage.minimum_filter(label, size=3)
    filled = np.zeros_like(inside)
    by_slit = np.zeros_like(inside)
    gaps = np.zeros((0, 2), np.int64)
    widest = 0.25 * h
    if mixed.any() and len(pieces) > 1:
        at = np.flatnonzero(mixed.ravel())
        two, d, apart, _ = _two_nearest(pieces, nodes[at], h)
        # an outside node in a slit, a tenth of its width or more from either wall (a node on a piece's outer
        # face beside a seam where two pieces touch lies on the segment to the other piece too)
        out = ~inside.ravel()[at]
        between = out & (d[1] < h) & _between(d, apart) & (d[0] >= 0.1 * apart)
        if between.any():  # the pieces' usual slit, half again
            widest = float(np.clip(1.5 * np.median(apart[between]), 0.25 * h, h))
        slit = out & (d[1] < widest) & (closed.ravel()[at] | (between & (apart < widest)))
        filled.ravel()[at[slit]] = True
        if widest > 0.25 * h:  # the pieces keep apart (a margin): their slits are closed in the contour too
            by_slit.ravel()[at[slit | (d[1] < h)]] = True
        label.ravel()[at[slit]] = two[0, slit] + 1
        gaps = np.sort(two[:, slit].T, axis=1)
    return _Labels(label, filled, top2, gaps, by_slit, widest)


def _winding_crossing(pieces, h: float, by_slit: np.ndarray | None = None, origin: np.ndarray | None = None,
                      widest: float = 0.0):
    """The crossing of a grid edge for :func:`~fracture.mesh.multilabel.contour_labels`: where the edge
    leaves the piece at its inside end, i.e. where that piece's winding number stops exceeding the
    other end's piece's (or the pieces' sum stops exceeding 1/2, toward the outside), by bisection.

    An edge with an end by a slit (``by_slit``, on the grid at ``origin``: :func:`_labels`) is bisected
    with the slits narrower than ``widest`` closed: a point in no piece lies in a slit when it lies between
    its closest points on its two nearest pieces, and in a piece rather than another where it is nearer to
    it (:func:`_in_closed_slit`). So B spans a slit's mouth at the level of the pieces' outer faces and the
    crack runs in the slit's middle: winding numbers are 0 across a slit, and an edge from outside through
    a slit's mouth to the piece beyond put B on the slit's far wall, a groove along every crack whose
    creases crossed the refined cracks' traces when Cell Fracture's margin left slits a fifth of a cell wide.
    """
    boxes = [(PV.min(axis=0) - 2 * h, PV.max(axis=0) + 2 * h) for PV, _ in pieces]
    solids = [Exterior(PV, PF) for PV, PF in pieces]  # each piece's hierarchy built once for every bisection

    def crossing(U, W, la, lb):
        inner_u = la > 0  # bisect from the end inside a piece
        P0, P1 = np.where(inner_u[:, None], U, W), np.where(inner_u[:, None], W, U)
        owner = np.where(inner_u, la, lb) - 1
        other = np.where(inner_u, lb, la) - 1  # -1: outside
        n = len(P0)
        slit = np.zeros(n, bool)
        if by_slit is not None and by_slit.any():
            for P in (U, W):
                ijk = np.rint((P - origin) / h).astype(np.int64)
                slit |= by_slit[tuple(ijk.T)]
        # an edge between two pieces, by no slit, is decided by their two winding numbers alone; the others'
        # (their sum) are asked only toward the outside and by a slit
        pair = (other >= 0) & ~slit
        asked = [~pair | (owner == p) | (other == p) for p in range(len(pieces))]
        lo, hi = np.zeros(n), np.ones(n)
        for _ in range(_BISECTIONS):
            mid = 0.5 * (lo + hi)
            X = P0 + mid[:, None] * (P1 - P0)
            w_in, w_out, total = np.zeros(n), np.zeros(n), np.zeros(n)
            for p in range(len(pieces)):
                near = np.flatnonzero(asked[p] & np.all((X >= boxes[p][0]) & (X <= boxes[p][1]), axis=1))
                if not len(near):
                    continue
                w = solids[p].winding(X[near])
                total[near] += w
                w_in[near[owner[near] == p]] = w[owner[near] == p]
                w_out[near[other[near] == p]] = w[other[near] == p]
            inside = np.where(other >= 0, w_in > w_out, total > 0.5)
            at = np.flatnonzero(slit & (np.maximum(w_in, w_out) < 0.5) & (total < 0.5))  # in no piece
            if len(at):
                inside[at] = _in_closed_slit(pieces, X[at], owner[at], other[at], widest, h)
            lo, hi = np.where(inside, mid, lo), np.where(inside, hi, mid)
        t = 0.5 * (lo + hi)
        return np.where(inner_u, t, 1.0 - t)

    return crossing


def _two_nearest(pieces, X: np.ndarray, reach: float):
    """Per point of ``X``, its two nearest pieces (``(2, k)``), its distances to them, how far apart its
    closest points on them are, and its squared distance to every piece (inf beyond ``reach`` of its box)."""
    D = np.full((len(pieces), len(X)), np.inf)
    C = np.zeros((len(pieces), len(X), 3))
    for p, (PV, PF) in enumerate(pieces):
        near = np.flatnonzero(np.all((X >= PV.min(axis=0) - reach) & (X <= PV.max(axis=0) + reach), axis=1))
        if len(near):
            D[p, near], _, C[p, near] = igl.point_mesh_squared_distance(X[near], PV, PF)
    rows = np.arange(len(X))
    two = np.argsort(D, axis=0)[:2]
    d = np.sqrt(np.maximum(D[two, rows], 0.0))
    return two, d, np.linalg.norm(C[two[0], rows] - C[two[1], rows], axis=1), D


def _between(d: np.ndarray, apart: np.ndarray) -> np.ndarray:
    """Points on the segment between their closest points on two pieces (:data:`_BRIDGE`)."""
    return d.sum(axis=0) <= _BRIDGE * apart


def _in_closed_slit(pieces, X: np.ndarray, owner: np.ndarray, other: np.ndarray, widest: float, h: float
                    ) -> np.ndarray:
    """For points ``X`` in no piece on edges by a slit, whether they lie on ``owner``'s side with the slits
    closed: toward the outside (``other`` -1), within a slit (:func:`_between`) narrower than ``widest``;
    toward another piece, nearer to the owner than to it (the pieces within two cells ``h`` of a point are
    asked: an end of its edge, a diagonal of a cell at most, lies in the owner)."""
    _, d, apart, D = _two_nearest(pieces, X, 2.0 * h)
    rows = np.arange(len(X))
    bridged = _between(d, apart) & (apart < widest)
    nearer = D[owner, rows] < np.where(other >= 0, D[np.maximum(other, 0), rows], np.inf)
    return np.where(other >= 0, nearer, bridged)


# the share of the smaller piece's volume above which an overlap is the same piece twice
_TWIN = 0.9


def _check_tiling(label, overlap, gaps, names, h, where) -> str | None:
    """Refuse pieces that overlap by more than :data:`_OVERLAP` cells on average (the overlap's volume
    over the smaller piece's volume to the power 2/3, an area); returns a note on the widest slit that
    was filled, or None."""
    count = np.bincount(label.ravel(), minlength=len(names) + 1)[1:].astype(np.float64)
    if len(overlap):  # one piece over most of the others: the object itself, exported with its pieces
        holds = np.bincount(overlap.ravel(), minlength=len(names))
        q = int(np.argmax(holds))
        partners = np.unique(overlap[(overlap == q).any(axis=1)])
        if holds[q] > _HOLDING * count.sum() and len(partners) > 2:
            raise InputError(f"{where}piece {names[q]!r} holds the other pieces (it overlaps {len(partners) - 1} of "
                             f"them, over {holds[q] / count.sum():.0%} of the object): is the unfractured object "
                             "exported with its pieces? Export the pieces alone (Blender: select them, Selection "
                             "Only)")
    # a piece's own volume: the nodes it was labelled with and those it lost to a piece it overlaps (a piece
    # exported twice loses every node to its twin)
    inside = count + (np.bincount(overlap.ravel(), minlength=len(names)) if len(overlap) else 0)
    note = None
    for what, pairs in (("overlap", overlap), ("slit", gaps)):
        if not len(pairs):
            continue
        pairs, n = np.unique(pairs, axis=0, return_counts=True)
        smaller = np.maximum(np.minimum(inside[pairs[:, 0]], inside[pairs[:, 1]]), 1.0)
        thick = n / smaller ** (2 / 3)
        worst = int(np.argmax(thick))
        a, b = pairs[worst]
        if what == "overlap" and thick[worst] > _OVERLAP and n[worst] >= _OVERLAP_NODES:
            twice = n[worst] >= _TWIN * smaller[worst]
            raise InputError(
                f"{where}pieces {names[a]!r} and {names[b]!r} overlap by {thick[worst] * h:.3g} on average "
                f"({n[worst] * h ** 3:.3g} cubic units, {n[worst] / smaller[worst]:.0%} of the smaller piece); "
                "the pieces must tile the object in the rest pose " + (
                    "(is a piece exported twice?)" if twice else "(is a piece moved?)"))
        if what == "slit":
            note = (f"between pieces {names[a]!r} and {names[b]!r}, {thick[worst] * h:.3g} wide on average "
                    f"({n[worst] * h ** 3:.3g} cubic units)")
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
        Grid cells along the object's largest extent, at least (more for a thin object: :data:`_ACROSS`;
        doubled once if a piece holds no node).
    """
    where = f"{source}: " if source else ""
    V = np.asarray(V, np.float64)
    used = np.unique(np.concatenate([np.concatenate(p) for p in polygons]))
    span = np.ptp(V[used], axis=0)
    if not span.max() > tol.zero * max(float(np.abs(V[used]).max()), 1.0):
        raise InputError(f"{where}the pieces' vertices all lie at one point, {V[used[0]].tolist()} (an object "
                         "smaller than the file's decimals, rounded?); expected pieces of some size")
    if not thinnest_extent(V[used]) > _PLANE * span.max():
        raise InputError(f"{where}the pieces' vertices all lie in one plane: the object is flat; expected the "
                         "closed pieces of a solid")
    pieces = _piece_triangles(V, polygons)
    notes: list[str] = []
    turned = []
    for p, (PV, PF) in enumerate(pieces):
        PF, changed = outward(PV, PF)
        if changed:
            pieces[p] = (PV, PF)
            turned.append(p)
    if turned:
        notes.append("turned the faces of pieces exported inside out or with faces facing in (their insides are "
                     "taken from their faces' orientation): " + ", ".join(repr(names[p]) for p in turned))
    flat, holds, apart = not_of_the_object(pieces)
    take = np.flatnonzero(~flat & ~holds & ~apart)  # the pieces of the object: numbered in this order below
    if not len(take):
        why = "flat (no volume)" if flat.all() else "flat, holding the others or apart from them"
        raise InputError(f"{where}every piece is {why}: no solid pieces to refine; expected the closed pieces "
                         "of a fractured object")
    for which, what in ((flat, "flat pieces (a ground plane?): not solids"),
                        (holds, "pieces that hold the others (the unfractured object, exported with its pieces?)"),
                        (apart, "pieces that touch no other piece (a ground, a projectile or a collider exported "
                                "with the object?)")):
        if which.any():
            notes.append(f"left out {what}: " + ", ".join(repr(names[p]) for p in np.flatnonzero(which)))
    if len(take) < len(pieces):
        pieces, names = [pieces[p] for p in take], [names[p] for p in take]
        V_used = np.concatenate([PV for PV, _ in pieces])
        lo, hi = V_used.min(axis=0), V_used.max(axis=0)
    else:
        lo, hi = V.min(axis=0), V.max(axis=0)
        V_used = V[used]
    _refuse_twins(pieces, names, where)  # among the object's pieces (a ground exported twice is left out)
    across = _ACROSS * float((hi - lo).max()) / max(thinnest_extent(V_used), tol.zero)
    cells = max(cells, min(_MOST_CELLS, int(np.ceil(across))))
    for n in (cells, 2 * cells):  # a piece thinner than a cell everywhere: try once at half the cell size
        h = float((hi - lo).max()) / n
        origin = lo - 1.5 * h
        shape = tuple(int(s) for s in np.ceil((hi - lo) / h).astype(int) + 4)
        grid = np.stack(np.meshgrid(*[np.arange(s) for s in shape], indexing="ij"), -1).reshape(-1, 3)
        found = _labels(pieces, origin + grid * h, shape, h)
        label, filled, overlap, gaps = found.label, found.filled, found.overlap, found.gaps
        present = np.bincount(label.ravel(), minlength=len(pieces) + 1)[1:] > 0
        if present.all():
            break
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
    c = contour_labels(label, origin, np.full(3, h), _winding_crossing(pieces, h, found.by_slit, origin,
                                                                      found.widest))
    X, FF, sides, BF, bpiece = c.V, c.fracture_F, c.sides, c.exterior_F, c.exterior_piece
    X, FF, sides = coarsen_sheets(X, FF, sides)
    X, FF, sides, BF, bpiece, pinholes = close_pinholes(X, FF, sides, BF, bpiece, h)
    if pinholes:
        notes.append(f"closed {pinholes} pinhole{'s' if pinholes > 1 else ''}: a piece reached the surface through "
                     f"a hole in a crack smaller than {PINHOLE:g} grid cells ({PINHOLE * h:.3g}); the crack now "
                     "ends just inside")
    if not closed_oriented(BF):
        raise AssertionError(f"{where}marching tetrahedra gave an outer surface that is not a closed 2-manifold")
    if len(kept) == 1:
        raise InputError(f"{where}one piece ({names[kept[0]]!r}): no crack to refine; expected the pieces of a "
                         "fractured object")
    if not len(FF):
        raise InputError(f"{where}no two pieces touch: nothing to refine (is this a fractured object?)")
    renumber = np.full(len(pieces), -1)
    renumber[kept] = np.arange(len(kept))
    return LabelTiling(X, FF, renumber[sides], BF, renumber[bpiece], take[kept], n, notes)
