"""The global search: the paper's functional minimised over a band around the coarse fracture surface by
a minimum cut, before the flow polishes the result.

The functional ``E(S) = integral of psi over S`` (psi shifted positive as the
flow's is, Sec. 4.3) is a weighted area, and a surface that separates the
pieces is a labelling of space by piece. On the field grid:

1. **Band.** Nodes inside B within ``band`` cells of the coarse surface are
   free; the others keep the piece they lie in (the side of the coarse
   surface they see: that of the triangle their closest point lies in, or
   near rims and junctions the nearest of points just off both faces of
   every coarse triangle). A piece also keeps its core, the nodes farther from the
   coarse surface than ``core`` (0.4) of its depth (its largest distance to
   it): a minimum cut favours small regions, and a piece that kept only a few
   nodes would be cut down to them. With a quarter, a weak sheet 4 or 8 cells
   off a tilted cut lay in the core and was reached on 96 % and 76 % of the
   area (the flow alone: 100 %); with 0.4 on 100 % and 99 %, and the
   collapsing wall's polished functional fell from 0.599 to 0.567; with a
   half the marble bunny's network lost half its area to shortcuts through
   the strong marble (`docs/design-measurements.md`). A part of the band
   that no kept node reaches (a tip of the object that the band meets only
   across B) keeps its pieces too: no labelling of it could be tied to a
   piece, and every cut would count it an island (step 3). The band reads no psi
   (:func:`search_band`): the refine stage keeps it in the stage cache, and a
   re-run with another material or stress weight takes it from there.
2. **Cut.** Neighbouring nodes of two pieces cost the least ``psi`` along
   the edge where the contour can put the surface, a sixth of the edge from
   either node (it crosses the edge where psi is least: a thin weak layer on
   one node's side is where it goes, and the mean of the two nodes would
   charge it the strong side's psi), times the edge's area weight (:mod:`fracture.refine.cut_weights`: the 26
   neighbours, so that a cut measures area at every orientation, not a
   staircase's); with a grain (anisotropic strength) the weight depends on
   the surface's normal there. Labels minimising the sum are found by
   alpha-expansion (:mod:`fracture.refine.expansion`; a minimum cut, the global
   minimum with two pieces), coarse to fine: every second node first, then
   the full grid within two cells of the coarse cut's boundaries (on the
   collapsing wall a cut 0.5 % dearer than the full grid's, in half the
   time, and the same weak share after the flow). Edges to nodes outside B cost nothing: the
   surface slides along B freely, as the flow's boundary does. A node may
   take only the pieces on either side of the coarse sheets within the band
   of it: a sheet moves, but two pieces that the coarse animation separates
   keep their sheet (a shorter network that merged sheets would have less
   area, and so a lower functional, and would drop cracks the animation has).
3. **Pieces stay whole.** A region of a piece that the cut separates from
   the piece's kept nodes (an island) joins the piece around it; a piece
   that would vanish keeps the coarse surface. A piece whose kept nodes lie
   in several lobes (the marble bunny's two thinnest pieces) may be cut
   through between them with every part anchored: a cut that leaves a piece
   in more 6-connected parts than its coarse labels is made again with that
   piece holding its coarse nodes (each priced above any cut's saving), so
   the searched surface separates as many regions as the coarse one. A cut that leaves a piece
   below its share of volume (``refine.keep_volume``) is made again with a
   price on every node that piece loses (a Lagrange multiplier of its
   volume, raised cut by cut): the piece gives up only the nodes whose
   weak material pays for them, where keeping its coarse nodes whole (as
   before) left the marble bunny's and the clay's cuts above the coarse
   surface. Coarse to fine, the prices are raised on the coarse level's cuts
   alone (each of its nodes for eight cells) until it keeps every piece its
   share, and the full grid is cut once at them: its cut moves the coarse
   boundaries by a cell or two, and a piece it still leaves short is priced
   again. The clay's three full cuts became two and its cut took 1.4 s
   instead of 1.8 s, every figure of the result the same. A piece that the
   coarse level's first cut leaves well below its share (by more than
   :data:`_COARSE_SLACK` of its volume, but not emptied: the full grid may
   find it in lobes and hold it) is priced there before the full grid is
   cut at all: the clay's two full cuts became one (its cut 0.72 s instead
   of 1.06 s; weakest fifth 31.3 % against 30.9 %). A band in which a piece holds
   fewer nodes than a tenth of the cells its fracture surface covers is not
   searched: the piece is thinner than a cell over most of its crack (a
   search from a searched surface that put the crack on a weak layer a cell
   under B's face), and with hardly a node to keep, the cut would take it
   away with its crack. What was done is said.
4. **Surface.** The labels are contoured into the conforming non-manifold
   fracture surface, its grid terraces smoothed away, its sheets put on the
   floors of psi's valleys and coarsened to triangles of about two cells
   (:mod:`fracture.refine.label_surface`). Each new vertex hangs in the
   barycentric tree from the nearest coarse triangle between the same two
   pieces, which carries the coarse animation to it (Section 5).

The result replaces the coarse surface only if it lowers the functional,
both measured on dense samples (the corners' quadrature of the flow
flatters a surface whose corners lie in a thin weak layer and whose
triangles cross the strong material between them); the flow then refines
and polishes it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import NamedTuple

import igl
import numba
import numpy as np
import scipy.sparse as sp
from scipy import ndimage
from scipy.spatial import cKDTree

from fracture.mesh.exterior import Exterior
from fracture.mesh.fracture_surface import FractureSurface
from fracture.mesh.sampling import uniform_barycentric
from fracture.mesh.topology import barycentric_weights, face_frames
from fracture.refine.cut_weights import OFFSETS, GrainWeights, area_weights
from fracture.refine.expansion import PottsGraph, Prices, expand
from fracture.refine.flow import energy, sampled_energy
from fracture.refine.label_surface import NODE_GAP, label_surface, sheet_key
from fracture.refine.reach import near_label, nodes_near_sheets
from fracture.tolerances import tol

# Points just off each face of the coarse surface, per unit area (in cells^-2), that tell a node its side.
_SIDE_DENSITY = 4.0
# ... this far off the face (cells).
_SIDE_OFFSET = 0.1
# ... asked at most this far from the surface (cells; _sides: at half a cell, within a spacing of the samples
# of a sheet's rim, the nearest sample beyond the rim could be another piece's)
_SIDE_ASK = 2.0
# A node whose offset from its closest point on the coarse surface makes a cosine with the triangle's normal
# above sqrt of this lies on the triangle's side of it (_sides).
_NORMAL_COS2 = 0.999 ** 2
# B's points at most that a piece's depth is measured at.
_DEPTH_SAMPLES = 20000
# Nodes closer than this to B (cells) count as outside.
_ON_B = 0.05
# Cycles of expansion moves over the pieces, on either level (the first does most: on the collapsing wall the
# fine level's second cycle lowers the cut by only 0.13 % and takes 0.3 s of 1.4, but the polished surface's
# functional by 0.6 %, 0.5989 against 0.6026, with half a point more of it in the weakest fifth; a third
# cycle lowers the cut by 0.02 % more)
_CYCLES = 2
# The cut is made coarse to fine (_cut) from this many free nodes on ...
_COARSE_MIN = 4000
# ... and the full grid cut again within this many cells of the coarse cut's boundaries (two, a coarse cell:
# against four, the minimum cuts of the clay and the Jell-O take 0.3 s instead of 0.8-1.0 s; the cut is
# dearer by at most 0.3 % (the wall), the polished functional by 0.24 %, the weak shares within 0.4 points)
_FINE_BAND = 2
# A search is made again from its own surface when its cut lies against the nodes its band keeps (beyond the
# band, or in a piece's core) on at least this share of its weight (search_in_rounds), up to _MOST_ROUNDS in
# all: a tilted weak sheet 8 voxels off the cut pressed 52 % of its cut there, a sheet turned 50 degrees with a
# band of 20 cells 30 % and one turned 30 degrees in the unit cube 36 % (their far ends in the pieces' cores: 95 %
# of the area within a voxel after one search, 100 % after two); the scenes 0-27 % (the marble bunny the most,
# whose second search is refused for its thin pieces; the clay 17 %), the other weak sheets 0-18 %
# (docs/design-measurements.md). A round is kept only if it lowers the functional.
_PRESSED = 0.25
_MOST_ROUNDS = 4
# A piece holding fewer band nodes than this share of the cells its fracture surface covers is thinner than a
# cell over most of it: the band is not searched (_thin_pieces). A piece a cell thick between two cracks holds
# about half (a Suzanne export's thinnest piece at 40 cells: 0.50), one a cell under B's face searched again
# from a searched surface 0.0007.
_THIN = 0.1
# Rounds of joining islands to the pieces around them.
_ISLAND_ROUNDS = 3
# A cut that leaves a piece below its share of volume (refine.keep_volume) is made again with a price on every
# grid node the piece loses (a Lagrange multiplier of its volume): first this share of the price at which the
# piece's giving up all its band nodes saves nothing, then this many times the last, up to this many cuts more.
_PRICE_START = 0.25
_PRICE_GROWTH = 2.0
_PRICE_ROUNDS = 6
# Before the full grid's first cut, a piece is priced on the coarse level's cut alone where that leaves it
# below its share by more than this fraction of its coarse volume (the full cut moves the coarse level's
# boundaries by a cell or two: a piece just short on the coarse level may keep its share on the full grid).
_COARSE_SLACK = 0.1


@dataclass
class SearchResult:
    """What :func:`graph_cut_search` found.

    ``surface`` is the new fracture surface, or None when the coarse one is
    kept (``notes`` say why). Energies are the cut's (the grid's quadrature of
    the shifted psi); ``functional`` the flow's integral of the shifted psi
    over the coarse surface and over the new one.
    """

    surface: FractureSurface | None
    travel: np.ndarray = field(default_factory=lambda: np.zeros(0))  # new vertices' distances to the coarse, cells
    free_nodes: int = 0
    labels_changed: int = 0
    cut_energy: tuple[float, float] = (0.0, 0.0)
    functional: tuple[float, float] = (0.0, 0.0)
    sampled: tuple[float, float] = (0.0, 0.0)  # the same on dense samples: what decides
    pressed: float = 0.0  # the share of the cut's weight on edges to nodes the band keeps (its limits)
    # per piece, the volume the cut's labels give it less the coarse labels' (each node a cell's volume)
    volume_change: np.ndarray = field(default_factory=lambda: np.zeros(0))
    seconds: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)


@dataclass
class SearchBand:
    """The band of a search (module notes, 1): its nodes and the pieces they start in and keep.

    It reads the coarse surface, B, the grid, the distances, ``band`` and
    ``core``, not psi: a run whose coarse
    input and grid are those of an earlier one (a re-run with the material or
    the stress changed) reuses it (the refine stage keeps it in the stage
    cache). ``empty`` says why there is nothing to search ("" when there is)."""

    box: tuple  # the slices of the grid's nodes around the coarse surface
    near: np.ndarray  # the band's nodes: flat indices into the box's nodes
    coarse: np.ndarray  # their pieces
    keep: np.ndarray  # which of them keep their piece
    empty: str = ""


def search_band(mesh: FractureSurface, grid, B: Exterior, band: float, core: float = 0.4,
                distance: np.ndarray | None = None, names: list[str] | None = None) -> SearchBand:
    """The band of ``band`` grid cells around ``mesh`` (the coarse surface) and what its nodes keep (module
    notes, 1); ``distance`` (optional) is the distance of every grid node to the coarse surface, ``names``
    the pieces' names for a note."""
    h = float(np.min(grid.spacing))
    V0, F0, S0 = mesh.V, mesh.F, mesh.sides
    n_pieces = int(S0.max()) + 1
    reach = (band + 2.0) * h
    box = _node_box(grid, V0.min(axis=0) - reach, V0.max(axis=0) + reach)
    sub = _BoxGrid(grid, box)
    if distance is not None:
        d = distance[box].ravel()
    else:
        d = np.sqrt(np.maximum(igl.point_mesh_squared_distance(sub.points(), V0, F0)[0], 0.0))
    # a node on B is outside: a sheet's crossing of B then lies inside an edge (its winding number is
    # anything from 0 to 1 there)
    inside, on_b = B.grid_nodes(sub.origin, sub.spacing, sub.shape, _ON_B * h, asked=d <= reach)
    near = np.flatnonzero(inside.ravel() & ~on_b.ravel())
    none = np.zeros(0, np.int64)
    if not len(near):
        return SearchBand(box, none, none, np.zeros(0, bool), empty=(
            f"search: the band of {band:g} cells holds no grid node inside the object; the coarse surface is "
            "kept (refine.band)"))
    side_of = _SideOf(V0, F0, S0, h)
    coarse = _sides(sub.points(near), V0, F0, S0, side_of)
    # every piece keeps the nodes beyond the band and its core (what a node may become: see _reach)
    dn = d[near]
    depth = _depths(B, V0, F0, S0, side_of, n_pieces)
    keep = (dn > band * h) | (dn > core * depth[coarse])
    # a piece a cell or two thick may have no node beyond its core: it keeps its deepest
    deepest = np.zeros(n_pieces)
    np.maximum.at(deepest, coarse, dn)
    keep |= dn >= deepest[coarse]
    # a part of the band that no kept node reaches keeps its pieces as they are (_unanchored)
    keep |= _unanchored(sub, near, keep)
    if keep.all():
        return SearchBand(box, near, coarse, keep, empty=(
            f"search: the band of {band:g} cells holds no free grid node inside the object; the coarse surface "
            "is kept (refine.band)"))
    coarse, _ = _mend(sub, near, coarse, keep)
    missing = np.setdiff1d(np.unique(S0), coarse).tolist()  # pieces of the coarse surface no node holds
    if missing:
        return SearchBand(box, near, coarse, keep, empty=(
            f"search: piece{'s' if len(missing) > 1 else ''} {_named(missing, names)} "
            f"hold{'' if len(missing) > 1 else 's'} no grid node "
            "(thinner than a cell); the coarse surface is kept"))
    thin = _thin_pieces(V0, F0, S0, coarse, n_pieces, grid.spacing)
    if len(thin):
        return SearchBand(box, near, coarse, keep, empty=(
            f"search: piece{'s' if len(thin) > 1 else ''} {_named(thin.tolist(), names)} "
            f"hold{'' if len(thin) > 1 else 's'} fewer grid nodes than a tenth of the cells of "
            f"{'their' if len(thin) > 1 else 'its'} fracture surface (thinner than a cell over most of it); the "
            "coarse surface is kept"))
    return SearchBand(box, near, coarse, keep)


def _unanchored(sub: _BoxGrid, near: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Which of the band's nodes ``near`` lie in a 6-connected part of the band that holds no kept node: a tip
    of the object that the band meets only across B (a Suzanne's ear, a corner between two outside regions).
    No labelling ties such a part to a node that keeps its piece, so every label there would count as an
    island of the cut (:func:`_regions`) and no cut could be kept: these nodes keep their pieces instead, and
    the coarse surface stays as it is there (a Cell Fracture export of a Suzanne: two such parts of 4 nodes
    in all made every cut of its 7 pieces leave a piece in parts)."""
    inside = np.zeros(sub.size, bool)
    inside[near] = True
    parts, n = ndimage.label(inside.reshape(sub.shape))
    part = parts.ravel()[near]
    anchored = np.zeros(n + 1, bool)
    anchored[part[keep]] = True
    return ~anchored[part]


def _thin_pieces(V, F, sides, coarse, n_pieces, spacing) -> np.ndarray:
    """The pieces that hold fewer band nodes (``coarse``: each node's piece) than :data:`_THIN` of the grid
    cells their fracture surface covers: on the grid they are thinner than a cell over most of it, and the
    cut, with hardly a node of theirs to keep, would take them away (a crack on a weak layer a cell under
    B's face, searched again: the piece beyond it holds a node or two and its whole crack went)."""
    area = np.bincount(sides.ravel(), np.repeat(face_frames(V, F)[0], 2), n_pieces)
    cell = float(np.prod(spacing)) ** (2.0 / 3.0)
    held = np.bincount(coarse, minlength=n_pieces)
    return np.flatnonzero((area > 0.0) & (held < _THIN * area / cell))


def graph_cut_search(mesh: FractureSurface, pyramid, B: Exterior, band: float, tension: float,
                     distance: np.ndarray | None = None, grain=None, core: float = 0.4,
                     names: list[str] | None = None, prepared: SearchBand | None = None,
                     origin: FractureSurface | None = None, volumes=None) -> SearchResult:
    """Search the band of ``band`` grid cells around ``mesh`` (the coarse surface) for the labelling of
    least weighted area (module notes).

    ``pyramid`` gives the grid and psi (level 0), shifted so its minimum is ``tension`` of its range;
    ``core`` is the fraction of each piece's depth beyond which its nodes are kept; ``names`` the pieces'
    names, for the notes;
    ``distance`` (optional) is the distance of every grid node to the coarse surface; ``grain``
    (optional, a :class:`fields.grain.Grain`) makes the cost of a surface element depend on its normal
    (per node the edge weights of :class:`~fracture.refine.cut_weights.GrainWeights`); ``prepared``
    (optional) the band :func:`search_band` made of the same surface, grid, B, ``band`` and ``core``;
    ``origin`` (optional, default ``mesh``) the coarse surface the new vertices hang from in the tree
    and their travel is measured from (:func:`search_in_rounds` searches again from a searched surface);
    ``volumes`` (optional, a :class:`~fracture.refine.volumes.PieceVolumes`) the pieces' volumes and the
    shares they keep: a cut that leaves a piece below its share is not kept.
    """
    clock = time.perf_counter()
    seconds: dict[str, float] = {}

    def tick(name):
        nonlocal clock
        now = time.perf_counter()
        seconds[name] = seconds.get(name, 0.0) + now - clock
        clock = now

    grid = pyramid.grid
    h = float(np.min(grid.spacing))
    psi = pyramid.levels[0]
    offset = tension * float(np.ptp(psi)) - float(psi.min())  # as the flow shifts its field (engine notes)
    V0, F0, S0 = mesh.V, mesh.F, mesh.sides
    n_pieces = int(S0.max()) + 1

    # 1. the band: nodes near the coarse surface, their side of it, free or kept
    sb = search_band(mesh, grid, B, band, core, distance, names) if prepared is None else prepared
    tick("band")
    if sb.empty:
        return SearchResult(None, notes=[sb.empty], seconds=seconds)
    sub = _BoxGrid(grid, sb.box)
    near, coarse, keep = sb.near, sb.coarse, sb.keep
    P = sub.points(near)  # the band's nodes' points, in the order of ``near``

    # 2. the cut
    shifted = (psi[sb.box] + offset).ravel()
    node_weights = None if grain is None else GrainWeights(grain)(sub.spacing, P)
    free = ~keep

    def reach_of(ids):
        return _reach(sub, near[ids], V0, F0, S0, band * h + h)

    notes: list[str] = []
    # per piece, what each grid node it loses costs: zero until a cut leaves it below its share of volume
    price = np.zeros(n_pieces)
    first = None  # what the first cut would have left of the pieces it left short, and those pieces
    start = None  # the pieces' first prices, made when a cut first leaves one short
    cut_band = _Cut(sub, near, keep, coarse, shifted, node_weights, reach_of)
    parts = _parts(sub, near, coarse, n_pieces)  # a piece the cut leaves in more parts than these is split
    held = np.zeros(n_pieces, bool)  # pieces split by a cut, holding their coarse nodes since
    cell = float(np.prod(grid.spacing))

    def priced() -> Prices | None:
        return Prices(coarse, price[coarse]) if price.any() else None

    def raise_prices(short: np.ndarray) -> None:
        nonlocal start
        if start is None:
            start = _PRICE_START * _break_even_prices(cut_band.graph, coarse, n_pieces)
        price[short] = np.where(price[short] > 0.0, _PRICE_GROWTH * price[short], start[short])

    attempt = 0  # cuts made again
    cut_before = False  # the full grid was cut: its volumes correct the coarse level's
    bias = np.zeros(n_pieces)  # per piece, the volume the last full-grid cut gave it less what its coarse level did
    while True:
        coarse_cut = cut_band.coarse_labels(priced()) if cut_band.levels == 2 else None
        if coarse_cut is not None:
            # the prices of the volume are found on the coarse level (each node for eight cells, its volumes
            # corrected by the last full cut's difference once there is one), and the full grid is cut once at
            # them (module notes, 3)
            while volumes is not None and attempt < _PRICE_ROUNDS:
                change = cut_band.coarse_change(coarse_cut, n_pieces) * cell + bias
                short = _short(volumes, change, n_pieces) if cut_before else _clearly_short(volumes, change, n_pieces)
                short = short[~held[short]]
                if not len(short):
                    break
                first = first or (_shares(volumes, change, short, names), short,
                                  "the cut" if cut_before else "the cut's coarse level")
                raise_prices(short)
                attempt += 1
                coarse_cut = cut_band.coarse_labels(priced())
        labels, graph, log = cut_band(priced(), coarse_cut)
        cut_before = True
        cut = labels[graph.p] != labels[graph.q]
        pressed = float(graph.w[cut & (keep[graph.p] | keep[graph.q])].sum() / max(graph.w[cut].sum(), tol.tiny))
        tick("cut")

        # 3. islands join the piece around them; every piece keeps enough of its volume
        islands = 0
        for mended in range(_ISLAND_ROUNDS + 1):
            regions = _regions(sub, near, labels, keep)
            if not regions.lost.any():
                break
            if mended == _ISLAND_ROUNDS:
                return SearchResult(None, free_nodes=int(free.sum()), seconds=seconds, notes=[
                    "search: the cut leaves a piece in parts; the coarse surface is kept"])
            labels = _joined(sub, near, labels, regions.lost)
            islands += int(regions.lost.sum())
        # a piece whose kept nodes lie in several parts (a core in two lobes) may be cut through between them,
        # every part anchored: such a piece holds its coarse nodes (their price above any cut's saving)
        over = np.pad(regions.parts, (0, n_pieces))[:n_pieces] > parts
        if over[held].any() or (over.any() and attempt == _PRICE_ROUNDS):
            # (a piece holding its coarse nodes keeps its coarse region whole: not expected, but then no cut helps)
            return SearchResult(None, free_nodes=int(free.sum()), seconds=seconds, notes=[
                f"search: the cut leaves {_piece_s(np.flatnonzero(over))} {_named(np.flatnonzero(over), names)} "
                "in parts; the coarse surface is kept"])
        if over.any():
            held |= over
            price[over] = graph.w.sum() + 1.0
            attempt += 1
            continue
        change = (np.bincount(labels, minlength=n_pieces) - np.bincount(coarse, minlength=n_pieces))[:n_pieces]
        change = change * cell
        if coarse_cut is not None:
            bias = change - cut_band.coarse_change(coarse_cut, n_pieces) * cell
        short = _short(volumes, change, n_pieces)
        short = short[~held[short]]  # a held piece loses no node
        if not len(short):
            break
        said = _shares(volumes, change, short, names)
        first = first or (said, short, "the cut")
        if attempt == _PRICE_ROUNDS:
            return SearchResult(None, free_nodes=int(free.sum()), seconds=seconds, notes=[
                f"search: {first[2]} would leave {first[0]} of {_their(first[1])} coarse volume "
                f"(refine.keep_volume: at least {100 * volumes.keep:.0f} %), and cut again {attempt} times with a "
                f"rising price on the volume lost, still {said}; the coarse surface is kept"])
        raise_prices(short)
        attempt += 1
    if held.any():
        split = np.flatnonzero(held)
        notes.append(f"search: the cut would split {_piece_s(split)} {_named(split, names)} in parts; cut again with "
                     f"{_them(split)} holding {_their(split)} coarse nodes")
    if first:
        priced = np.flatnonzero((price > 0.0) & ~held)
        again = {1: "once", 2: "twice"}.get(attempt, f"{attempt} times")
        notes.append(f"search: {first[2]} would leave {first[0]} of {_their(first[1])} coarse volume "
                     f"(refine.keep_volume: at least {100 * volumes.keep:.0f} %); with a price on the volume "
                     f"{_named(priced, names)} lost it was cut again {again}, and every piece keeps its share")
    present = np.bincount(labels, minlength=n_pieces) > 0
    lost = [c for c in range(n_pieces) if (coarse == c).any() and not present[c]]
    if lost:
        return SearchResult(None, free_nodes=int(free.sum()), seconds=seconds, notes=[
            f"search: piece{'s' if len(lost) > 1 else ''} {_named(lost, names)} would vanish; the coarse "
            "surface is kept"])
    if islands:
        notes.append(f"search: {islands} grid nodes the cut had cut off from their piece joined the piece around "
                     "them")
    tick("pieces")

    # 4. the surface
    V, F, sides = label_surface(sub, near, labels, B, pyramid.value, float(np.ptp(psi)), offset, grain)
    if not len(F):
        return SearchResult(None, seconds=seconds, notes=["search: the cut left no fracture surface; the coarse "
                                                          "surface is kept"])
    tick("contour")
    tree = mesh if origin is None else origin
    base, travel = _tree_base(V, F, sides, tree.V, tree.F, tree.sides)
    surface = FractureSurface(V, F, sides, n_coarse=len(V), base=base)
    before = energy(V0, F0, pyramid.value(V0) + offset, grain)
    after = energy(V, F, pyramid.value(V) + offset, grain)
    # the surfaces' own quadratures (psi at the corners) flatter a surface whose corners lie in a thin weak
    # layer and whose triangles cross strong material between them: both are compared on dense samples
    sampled = (sampled_energy(V0, F0, pyramid.value, h, offset, grain),
               sampled_energy(V, F, pyramid.value, h, offset, grain))
    tick("tree")
    result = SearchResult(surface, travel=travel / h, free_nodes=int(free.sum()),
                          labels_changed=int((labels != coarse).sum()),
                          cut_energy=(log.energy[0], graph.energy(labels)), functional=(before, after),
                          sampled=sampled, pressed=pressed, volume_change=change, seconds=seconds, notes=notes)
    if sampled[1] >= sampled[0]:
        result.surface = None
        result.notes.append(f"search: the cut's surface does not lower the functional ({sampled[1]:.6g} against the "
                            f"coarse {sampled[0]:.6g}); the coarse surface is kept")
    return result


def search_in_rounds(mesh: FractureSurface, pyramid, B: Exterior, band: float, tension: float, rounds: int = 1,
                     distance: np.ndarray | None = None, prepared: SearchBand | None = None, volumes=None,
                     **options) -> SearchResult:
    """:func:`graph_cut_search` of ``mesh`` (the coarse surface), then again from its own surface, up to
    ``rounds`` searches in all, and one more (up to :data:`_MOST_ROUNDS`) whenever the last one's cut lay
    against the nodes its band keeps on at least :data:`_PRESSED` of its weight (the least surface lies
    beyond the band's limits), while each lowers the functional (on dense samples) further.

    A round's band and cores are measured from the last round's surface, so a crack may travel up to
    ``rounds`` bands from the coarse one, and the cores shrink with the pieces (a minimum cut favours small
    pieces: module notes, 1). A weak sheet 8 voxels off a tilted cut, beyond the first round's cores, is
    reached by the second (`docs/design-measurements.md`). ``options`` go to every round; ``distance`` and
    ``prepared`` (of the coarse surface) to the first; ``volumes`` (the pieces' volumes and shares) to every
    round, with the volumes the kept rounds left. The result's energies run from the coarse surface to
    the last kept round's, its seconds are summed and its notes say how many rounds were kept."""
    result = graph_cut_search(mesh, pyramid, B, band, tension, distance=distance, prepared=prepared,
                              volumes=volumes, **options)
    kept, why = 1, []
    while result.surface is not None and (kept < rounds or (result.pressed >= _PRESSED and kept < _MOST_ROUNDS)):
        if kept >= rounds:
            why.append(f"round {kept}'s cut lay against its band's limits on {100 * result.pressed:.0f} % of its "
                       "weight")
        after = None if volumes is None else replace(volumes, volume=volumes.volume + result.volume_change)
        again = graph_cut_search(result.surface, pyramid, B, band, tension, origin=mesh, volumes=after, **options)
        seconds = {k: result.seconds.get(k, 0.0) + again.seconds.get(k, 0.0)
                   for k in result.seconds.keys() | again.seconds.keys()}
        if again.surface is None:
            result.seconds = seconds
            # refused for its functional (the last thing measured), or before: its own note says why, calling
            # the surface it started from the coarse one
            why_not = ("it did not lower the functional further" if again.sampled != (0.0, 0.0) else
                       again.notes[-1].removeprefix("search: ").replace("; the coarse surface is kept", ""))
            result.notes.append(f"search: round {kept + 1} was not kept ({why_not}); round {kept}'s surface is "
                                "kept (refine.search_rounds)")
            break
        result = SearchResult(again.surface, travel=again.travel, free_nodes=result.free_nodes,
                              labels_changed=result.labels_changed + again.labels_changed,
                              cut_energy=(result.cut_energy[0], again.cut_energy[1]),
                              functional=(result.functional[0], again.functional[1]),
                              sampled=(result.sampled[0], again.sampled[1]), pressed=again.pressed,
                              volume_change=result.volume_change + again.volume_change, seconds=seconds,
                              notes=result.notes + again.notes)
        kept += 1
    if kept > 1:
        result.notes.append(f"search: {kept} rounds, each from the last one's surface ("
                            f"{'; '.join(why) if why else 'refine.search_rounds'})")
    return result


def _named(pieces, names) -> str:
    return ", ".join(repr(names[c]) if names is not None and c < len(names) else str(c) for c in pieces)


def _break_even_prices(graph: PottsGraph, coarse: np.ndarray, n_pieces: int) -> np.ndarray:
    """Per piece, the price per band node at which giving up all of its band nodes saves nothing: the cut's
    energy of the coarse labels ``coarse`` on the piece's boundary over its band nodes."""
    cut = coarse[graph.p] != coarse[graph.q]
    w = graph.w[cut]
    boundary = (np.bincount(coarse[graph.p[cut]], w, n_pieces) + np.bincount(coarse[graph.q[cut]], w, n_pieces))
    return boundary[:n_pieces] / np.maximum(np.bincount(coarse, minlength=n_pieces)[:n_pieces], 1)


def _short(volumes, change: np.ndarray, n_pieces: int) -> np.ndarray:
    """The pieces that the volume ``change`` leaves below their share (none without ``volumes``)."""
    if volumes is None:
        return np.zeros(0, np.int64)
    return np.flatnonzero((change < 0.0) & (change < -volumes.room[:n_pieces]))


def _clearly_short(volumes, change: np.ndarray, n_pieces: int) -> np.ndarray:
    """The pieces that the coarse level's volume ``change``, before any cut of the full grid, leaves below
    their share by more than :data:`_COARSE_SLACK` of their coarse volume, but not without any volume (a
    piece the coarse level takes whole is thinner than its nodes see: the full grid's cut may find it in
    lobes and hold its nodes instead; none without ``volumes``)."""
    if volumes is None:
        return np.zeros(0, np.int64)
    left = volumes.volume[:n_pieces] + change
    coarse = volumes.coarse[:n_pieces]
    return np.flatnonzero((change < 0.0) & (left > 0.0) & (left < (volumes.keep - _COARSE_SLACK) * coarse))


def _shares(volumes, change: np.ndarray, pieces: np.ndarray, names) -> str:
    """``piece 'a' 42 %, 'b' 47 %``: what ``change`` leaves of the pieces' coarse volumes."""
    share = (volumes.volume[pieces] + change[pieces]) / np.maximum(volumes.coarse[pieces], tol.tiny)
    return f"piece{'s' if len(pieces) > 1 else ''} " + ", ".join(
        f"{_named([c], names)} {100 * max(v, 0.0):.0f} %" for c, v in zip(pieces, share))


def _their(pieces) -> str:
    return "their" if len(pieces) > 1 else "its"


def _them(pieces) -> str:
    return "them" if len(pieces) > 1 else "it"


def _piece_s(pieces) -> str:
    return "pieces" if len(pieces) > 1 else "piece"


# -- the band ---------------------------------------------------------------------------------------------
def _node_box(grid, lo, hi) -> tuple[slice, slice, slice]:
    """The slices of the grid's nodes inside the box ``[lo, hi]`` (one node of margin)."""
    a = np.floor((np.asarray(lo) - grid.origin) / grid.spacing).astype(int) - 1
    b = np.ceil((np.asarray(hi) - grid.origin) / grid.spacing).astype(int) + 2
    return tuple(slice(max(int(x), 0), min(int(y), n)) for x, y, n in zip(a, b, grid.shape))


class _BoxGrid:
    """A box of the field grid: its shape, nodes and their points."""

    def __init__(self, grid, box):
        self.grid, self.box = grid, box
        self.shape = tuple(max(s.stop - s.start, 0) for s in box)
        self.origin = grid.origin + grid.spacing * np.array([s.start for s in box])
        self.spacing = grid.spacing

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    def points(self, ids: np.ndarray | None = None) -> np.ndarray:
        """The points of the nodes ``ids`` (flat indices; default every node)."""
        idx = np.stack(np.unravel_index(np.arange(self.size) if ids is None else ids, self.shape), 1)
        return self.origin + idx * self.spacing


class _SideOf:
    """The piece points lie in: that of the nearest of points just off both faces of every coarse triangle
    (robust at junctions, where the nearest triangle's side alone is ambiguous)."""

    def __init__(self, V, F, sides, h):
        T = V[F]
        area = 0.5 * np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1)
        count = np.maximum(np.ceil(_SIDE_DENSITY * area / (h * h)).astype(np.int64), 1)
        f = np.repeat(np.arange(len(F)), count)
        rng = np.random.default_rng(0)
        bary = uniform_barycentric(rng.random(len(f)), rng.random(len(f)))
        # the triangles' corners too, so that every point of the surface has a sample near it
        bary = np.concatenate([bary, np.tile(np.eye(3), (len(F), 1))])
        f = np.concatenate([f, np.repeat(np.arange(len(F)), 3)])
        X = np.einsum("nk,nkc->nc", bary, T[f])
        off = _SIDE_OFFSET * h * face_frames(V, F)[1][f]
        self.h = h
        self.tree = cKDTree(np.concatenate([X - off, X + off]))
        self.piece = np.concatenate([sides[f, 0], sides[f, 1]]).astype(np.int64)

    def __call__(self, P: np.ndarray) -> np.ndarray:
        return self.piece[self.tree.query(P, workers=-1)[1]]


def node_pieces(P: np.ndarray, V: np.ndarray, F: np.ndarray, sides: np.ndarray, h: float) -> np.ndarray:
    """The piece of each point ``P`` inside B: the side of the surface ``(V, F, sides)`` it lies on (the
    band's rule, :func:`_sides`); ``h`` is the grid's cell."""
    if not len(P) or not len(F):
        return np.zeros(len(P), np.int64)
    return _sides(P, V, F, sides, _SideOf(V, F, sides, h))


def _sides(near_points: np.ndarray, V0, F0, S0, side_of: _SideOf) -> np.ndarray:
    """The piece of every band node (points ``near_points``).

    A node whose closest point on the coarse surface lies inside a triangle,
    along the triangle's normal, is on that triangle's side of it (no other
    part of the surface crosses the segment to a closest point); only the
    nodes whose closest point lies on an edge or corner (near rims and
    junctions: on the collapsing wall's band a fifth of the nodes) ask
    :class:`_SideOf`, at the point of the segment to their closest point at
    most :data:`_SIDE_ASK` cells from the surface: the segment meets the surface
    only at its end, so that point lies in the node's piece, and the nearest
    of the samples to a point near them is found at once (to a point far from
    the surface, as most of B's are for :func:`_depths`, it took three to four
    times as long; the pieces are the same)."""
    d2, tri, C = igl.point_mesh_squared_distance(near_points, V0, F0)
    _, n = face_frames(V0, F0)
    off = near_points - C
    along = np.einsum("ij,ij->i", off, n[tri])
    clear = along * along > _NORMAL_COS2 * np.maximum(d2, tol.tiny)
    out = np.where(along > 0, S0[tri, 1], S0[tri, 0]).astype(np.int64)
    ask = np.flatnonzero(~clear)
    d = np.sqrt(np.maximum(d2[ask], tol.tiny))
    out[ask] = side_of(C[ask] + (np.minimum(d, _SIDE_ASK * side_of.h) / d)[:, None] * off[ask])
    return out


def _depths(B: Exterior, V0, F0, S0, side_of, n_pieces) -> np.ndarray:
    """Each piece's depth: its largest distance to the coarse surface, taken over B's vertices and
    triangles' middles (a piece is farthest from its cracks on its part of B)."""
    X = np.concatenate([B.V, B.V[B.F].mean(axis=1)])
    if len(X) > _DEPTH_SAMPLES:  # evenly thinned: a piece's far corner has many of B's points near it
        X = X[:: -(-len(X) // _DEPTH_SAMPLES)]
    d = np.sqrt(np.maximum(igl.point_mesh_squared_distance(X, V0, F0)[0], 0.0))
    depth = np.zeros(n_pieces)
    # the side by the closest triangle where it is clear, else asked near the surface (_sides: most of B's
    # points are far from every face, where a nearest-neighbour query is slow)
    np.maximum.at(depth, _sides(X, V0, F0, S0, side_of), d)
    return depth


def _graph(sub: _BoxGrid, near, moving, shifted, node_weights, stride: int = 1) -> PottsGraph:
    """The 26-neighbour edges between nodes ``near`` of the box (flat indices) that are ``stride`` nodes
    apart, with at least one end ``moving``, weighted by the shifted psi (``shifted``: every node of the
    box) where the contour can cross them times the area weight of their offset (or, with a grain, the
    mean of their nodes' ``node_weights`` for it).

    With a stride of 2 an edge passes through the grid node halfway along it, and costs the least of the
    two halves' costs: the thin weak layer a coarse edge jumps over is still seen."""
    index = np.full(sub.size, -1, np.int64)
    index[near] = np.arange(len(near))
    if node_weights is None:  # one area weight per offset, for every node
        weights = area_weights(np.asarray(sub.spacing, np.float64) * stride)[None, :]
    else:
        weights = np.ascontiguousarray(node_weights, np.float64)
    p, q, w = _lattice_edges(index.reshape(sub.shape), np.asarray(moving, np.bool_), shifted.reshape(sub.shape),
                             OFFSETS, int(stride), weights, node_weights is not None, NODE_GAP)
    return PottsGraph(len(near), p, q, w)


@numba.njit(cache=True)
def _lattice_edges(index, moving, vol, offsets, stride, weights, per_node, gap):
    """:func:`_graph`'s edges: per offset, the box's nodes in order, the edge to the node ``stride``
    offsets on when both are band nodes (``index`` >= 0) and one of them moves; two passes, a count and
    the fill (as NumPy, two masked copies of the box per offset, it took 0.15-0.2 s of the collapsing
    wall's cut)."""
    nx, ny, nz = index.shape
    total = 0
    p, q, w = np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0)
    for fill in range(2):
        if fill:
            p = np.empty(total, np.int64)
            q = np.empty(total, np.int64)
            w = np.empty(total)
        e = 0
        for k in range(len(offsets)):
            sx, sy, sz = offsets[k, 0] * stride, offsets[k, 1] * stride, offsets[k, 2] * stride
            for i in range(max(-sx, 0), nx - max(sx, 0)):
                for j in range(max(-sy, 0), ny - max(sy, 0)):
                    for l in range(max(-sz, 0), nz - max(sz, 0)):
                        a = index[i, j, l]
                        if a < 0:
                            continue
                        b = index[i + sx, j + sy, l + sz]
                        if b < 0 or not (moving[a] or moving[b]):
                            continue
                        if fill:
                            if per_node:
                                area = 0.5 * (weights[a, k] + weights[b, k])
                            else:
                                area = weights[0, k]
                            pa, pb = vol[i, j, l], vol[i + sx, j + sy, l + sz]  # (shifted) psi at the ends
                            if stride == 1:
                                c = _crossing_psi(pa, pb, gap)
                            else:  # the cheaper half of the edge, through the node at its middle
                                m = vol[i + sx // 2, j + sy // 2, l + sz // 2]
                                c = min(_crossing_psi(pa, m, gap), _crossing_psi(m, pb, gap))
                            p[e], q[e], w[e] = a, b, c * area
                        e += 1
        total = e
    return p, q, w


@numba.njit(cache=True, inline="always")
def _crossing_psi(pa: float, pb: float, gap: float) -> float:
    """psi where the contour can put the surface on an edge with these psi at its ends: linear between
    the nodes, the least of it within ``gap`` (:data:`~fracture.refine.label_surface.NODE_GAP`) of either
    end."""
    return min((1.0 - gap) * pa + gap * pb, gap * pa + (1.0 - gap) * pb)


class _Cut:
    """The labels of least cut (alpha-expansion), coarse to fine (banded graph cuts: Lombaert, Sun, Grady
    and Xu, "A multilevel banded graph cuts method for fast image segmentation", ICCV 2005).

    With at least :data:`_COARSE_MIN` free nodes, every second node is cut first (edges twice as long,
    the weights of a lattice of twice the spacing: four times the area each); each node of the full grid
    then takes the label its coarse nodes agree on, and only nodes within :data:`_FINE_BAND` cells of
    where they disagree are cut again at full resolution. ``reach_of(ids)`` says per piece which of the
    band's nodes ``ids`` (positions in ``near``) it may take (:func:`_reach`, in positions of ``ids``);
    coarse to fine it is asked of the coarse level's free nodes and of the full grid's moving nodes only
    (a piece it names no node for takes none; on the clay 0.16 s against 0.2 s for every node; a
    full-grid node given the pieces its coarse cell's corners may take would reach up to two cells
    farther, and on a concave Cell Fracture export, Suzanne, one of the pieces assembled from the
    result was not closed).

    Made once per band and called once per set of prices (the search's cuts again with a price on the
    volume a piece loses): the two levels' graphs, their edges grouped by node and the coarse level's
    reach do not read the prices."""

    def __init__(self, sub: _BoxGrid, near, keep, labels, shifted, node_weights, reach_of):
        self.sub, self.near, self.labels, self.reach_of = sub, near, labels, reach_of
        self.free = free = ~keep
        self.graph = _graph(sub, near, free, shifted, node_weights)  # the full resolution's: the cut's energy
        self.start = self.graph.energy(labels)
        self.ijk = np.stack(np.unravel_index(near, sub.shape), 1)
        self.even = even = np.flatnonzero(np.all(self.ijk % 2 == 0, axis=1))
        self.levels = 2 if free.sum() >= _COARSE_MIN and len(even) else 1
        if self.levels == 1:
            self.reach = _free_reach(reach_of, np.arange(len(near)), free)
        else:  # the coarse level: the nodes of even index and their labels' regions
            self.coarse_graph = _graph(sub, near[even], free[even], shifted,
                                       None if node_weights is None else 4.0 * node_weights[even], stride=2)
            self.coarse_reach = _free_reach(reach_of, even, free[even])

    def coarse_labels(self, prices: Prices | None = None) -> np.ndarray:
        """The coarse level's labels (per node of ``near[even]``; two levels only)."""
        even, free = self.even, self.free
        labels, _ = expand(self.coarse_graph, self.labels[even], free[even], self.coarse_reach, cycles=_CYCLES,
                           prices=None if prices is None else prices.of(even, 8.0))
        return labels

    def coarse_change(self, coarse_labels: np.ndarray, n_pieces: int) -> np.ndarray:
        """Per piece, the band nodes it gains (or loses) at the coarse level's ``coarse_labels``, eight for each
        coarse node (the full grid's cells it stands for)."""
        start = self._coarse_start
        now = np.bincount(coarse_labels, minlength=len(start))
        change = 8 * (now - np.pad(start, (0, len(now) - len(start))))
        return np.pad(change, (0, n_pieces))[:n_pieces]

    @cached_property
    def _coarse_start(self) -> np.ndarray:
        """Per label, the coarse level's nodes it holds before any cut."""
        return np.bincount(self.labels[self.even])

    def __call__(self, prices: Prices | None = None, coarse_labels: np.ndarray | None = None
                 ) -> tuple[np.ndarray, PottsGraph, object]:
        """The labels, the full-resolution graph (every edge with a free end: the cut's energy) and the
        expansion's log (its energies on that graph). ``prices`` (optional, per node of ``near``) is the
        unary term of :func:`~fracture.refine.expansion.expand` (the coarse level's nodes, each for eight
        cells, pay eight); ``coarse_labels`` (optional) the coarse level's labels at those prices, when the
        caller has them (:meth:`coarse_labels`)."""
        sub, near, labels, free, graph, ijk, even = (self.sub, self.near, self.labels, self.free, self.graph,
                                                     self.ijk, self.even)
        if self.levels == 1:
            out, log = expand(graph, labels, free, self.reach, cycles=_CYCLES, prices=prices)
            return out, graph, log
        if coarse_labels is None:
            coarse_labels = self.coarse_labels(prices)
        # each node takes the label its coarse nodes (the corners of the coarse cell it lies in) agree on
        cshape = tuple((n + 1) // 2 for n in sub.shape)
        lattice = np.full(cshape, -1, np.int64)
        lattice[tuple((ijk[even] // 2).T)] = coarse_labels
        agreed = _agreed(ijk, lattice)
        unsure = np.zeros(sub.size, bool)
        unsure[near[agreed < 0]] = True
        unsure = _cube_dilation(unsure.reshape(sub.shape), _FINE_BAND).ravel()
        moving = free & unsure[near]
        start_labels = np.where(free & (agreed >= 0), agreed, labels)
        # a label grows only within the fine band of its coarse region: each move a few cells around one
        # piece, not the whole band around every sheet of it (on the clay 1.1 s instead of 2.6 s of
        # minimum cuts, the same cut within 0.01 %)
        fine_reach = {}
        ids = np.flatnonzero(moving)
        start_vol = np.full(sub.size, -1, np.int64)
        start_vol[near] = start_labels
        start_vol = start_vol.reshape(sub.shape)
        for a, r in self.reach_of(ids).items():
            if not len(r):
                continue
            fine_reach[a] = ids[r][near_label(start_vol, near[ids[r]], a, _FINE_BAND)]
        out, log = expand(graph.among(moving), start_labels, moving, fine_reach, cycles=_CYCLES, prices=prices)
        log.energy = [self.start, graph.energy(out)]
        return out, graph, log


@numba.njit(cache=True)
def _agreed(ijk, lattice):
    """Per node ``ijk`` of the full grid, the label the labelled corners of the coarse cell it lies in
    (``lattice``, -1 where unlabelled) agree on: -2 where none is labelled, -1 where they disagree."""
    out = np.empty(len(ijk), np.int64)
    for n in range(len(ijk)):
        agreed = -2
        for di in range(2):
            i = min((ijk[n, 0] + di) // 2, lattice.shape[0] - 1)
            for dj in range(2):
                j = min((ijk[n, 1] + dj) // 2, lattice.shape[1] - 1)
                for dk in range(2):
                    c = lattice[i, j, min((ijk[n, 2] + dk) // 2, lattice.shape[2] - 1)]
                    if c >= 0:
                        if agreed == -2:
                            agreed = c
                        elif agreed >= 0 and agreed != c:
                            agreed = -1
        out[n] = agreed
    return out


def _free_reach(reach_of, ids: np.ndarray, free: np.ndarray) -> dict:
    """``reach_of(ids)`` asked of the free ones of ``ids`` only (a kept node takes no other label: on the
    clay a third of the coarse level's nodes), in positions of ``ids``."""
    mine = np.flatnonzero(free)
    return {a: mine[r] for a, r in reach_of(ids[mine]).items()}


def _cube_dilation(mask: np.ndarray, cells: int) -> np.ndarray:
    """``mask`` grown by ``cells`` nodes in every axis (a cube): a separable maximum filter, three times
    as fast as the binary dilation it equals."""
    return ndimage.maximum_filter(mask, size=2 * cells + 1, mode="constant", cval=False)


def _reach(sub: _BoxGrid, near, V0, F0, S0, radius: float) -> dict:
    """Per piece, the band's nodes ``near`` (flat indices of the box ``sub``) within ``radius`` of a coarse
    sheet of that piece: where it may grow (:mod:`fracture.refine.reach`), in positions of ``near``."""
    where = np.full(sub.size, -1, np.int64)
    where[near] = np.arange(len(near))
    return nodes_near_sheets(where.reshape(sub.shape), sub.origin, sub.spacing, V0, F0, S0, radius, len(near))


class _Regions(NamedTuple):
    """The 6-connected regions of each label among a band's nodes (:func:`_regions`)."""

    lost: np.ndarray  # (len(near),) bool: in a region of its label that holds none of its kept nodes (an island)
    parts: np.ndarray  # (labels.max() + 1,) int: per label, its regions


def _regions(sub: _BoxGrid, near, labels, keep=None) -> _Regions:
    """The regions of each label of the band's nodes ``near`` (flat indices of the box ``sub``), each in the box
    of its label's nodes only; without ``keep`` (which nodes keep their label) no node is lost."""
    vol = np.full(sub.size, -1, np.int64)
    vol[near] = labels
    vol = vol.reshape(sub.shape)
    kept = np.zeros(sub.size, bool)
    if keep is not None:
        kept[near[keep]] = True
    kept = kept.reshape(sub.shape)
    ijk = np.stack(np.unravel_index(near, sub.shape), 1)
    lost = np.zeros(len(near), bool)
    parts = np.zeros(int(labels.max()) + 1 if len(labels) else 0, np.int64)
    for c in np.unique(labels):
        mine = np.flatnonzero(labels == c)
        lo, hi = ijk[mine].min(axis=0), ijk[mine].max(axis=0) + 1
        box = tuple(slice(a, b) for a, b in zip(lo, hi))
        regions, parts[c] = ndimage.label(vol[box] == c)
        if keep is not None:
            anchored = np.unique(regions[kept[box] & (vol[box] == c)])
            lost[mine] = ~np.isin(regions[tuple((ijk[mine] - lo).T)], anchored)
    return _Regions(lost, parts)


def _parts(sub: _BoxGrid, near, labels, n_pieces: int) -> np.ndarray:
    """Per piece, the number of 6-connected regions its band nodes ``near`` (labelled ``labels``) make."""
    parts = _regions(sub, near, labels).parts
    return np.pad(parts, (0, n_pieces - len(parts)))[:n_pieces]


def _joined(sub: _BoxGrid, near, labels, lost) -> np.ndarray:
    """``labels`` with the ``lost`` nodes given the label of the nearest node not lost."""
    mask = np.ones(sub.size, bool)  # True: no label to take
    mask[near[~lost]] = False
    _, nearest = ndimage.distance_transform_edt(mask.reshape(sub.shape), return_indices=True)
    source = np.ravel_multi_index(tuple(n.ravel()[near[lost]] for n in nearest), sub.shape)
    where = np.full(sub.size, -1, np.int64)
    where[near] = np.arange(len(near))
    out = labels.copy()
    out[lost] = labels[where[source]]
    return out


def _mend(sub: _BoxGrid, near, labels, keep) -> tuple[np.ndarray, int]:
    """The coarse labels with their islands (a few nodes a junction's sampling put on the wrong side, the
    tip of a piece the band cuts off) given the label of the nearest node outside them; and how many."""
    lost = _regions(sub, near, labels, keep).lost
    if not lost.any():
        return labels, 0
    return _joined(sub, near, labels, lost), int(lost.sum())


def _tree_base(V, F, sides, V0, F0, S0) -> tuple[sp.csr_matrix, np.ndarray]:
    """Each new vertex as barycentric weights of its closest point on the nearest coarse triangle between
    the same two pieces (on any triangle where those two never met), ``(len(V), len(V0))``, and its
    distance to that point."""
    key0, key = sheet_key(S0), sheet_key(sides)
    tri = np.full(len(V), -1, np.int64)
    C = np.zeros_like(V)
    d2 = np.zeros(len(V))
    for k in np.unique(key):
        ids = np.unique(F[key == k])
        ids = ids[tri[ids] < 0]
        if not len(ids):
            continue
        faces = np.flatnonzero(key0 == k)
        if not len(faces):
            faces = np.arange(len(F0))
        d2[ids], t, C[ids] = igl.point_mesh_squared_distance(V[ids], V0, F0[faces])
        tri[ids] = faces[t]
    W = barycentric_weights(C, V0[F0[tri]])
    rows = np.repeat(np.arange(len(V)), 3)
    return sp.csr_matrix((W.ravel(), (rows, F0[tri].ravel())), shape=(len(V), len(V0))), np.sqrt(d2)
