"""Coarsening of the sheets of a conforming non-manifold fracture surface (each sheet: the triangles
between one pair of pieces) by quadric edge collapse, each sheet's boundary (its
junctions with other sheets and its curve on B) kept vertex for vertex, so the sheets still meet each
other and B exactly. Contoured sheets (a label grid's marching tetrahedra) have triangles of a
fraction of a cell: Cell Fracture's flat sheets (bisector planes of its cells) need only a few
triangles per boundary vertex, the global search's curved ones about one per two cells of area (the
flow refines them where psi varies).

Curved sheets are collapsed by pyfqmr (Fast Quadric Mesh Simplification: on the collapsing wall's
searched sheets 0.06 s against pymeshlab's 0.64 s, the same triangle counts, every rim vertex kept
bit for bit; `docs/design-measurements.md`). Flat sheets go to pymeshlab, whose planar quadric keeps
the triangles of a plane well shaped (on a plane every collapse costs nothing to a plain quadric).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from fracture.mesh.edges import edge_table, row_edges
from fracture.mesh.decimate import quadric_decimation
from fracture.mesh.intersect import self_intersections
from fracture.mesh.topology import corner_groups
from fracture.tolerances import tol

# A coarsened curved sheet keeps about one triangle per this many cells of its area.
_CELLS_PER_TRIANGLE = 2.0
# How many times a curved sheet whose coarsening folds or crosses is coarsened again with twice the triangles
# before it keeps its own: a sheet turned 80 degrees from the cut kept 66,224 triangles (three times a
# preview's budget) where the first collapse gave 3,916 with one fold, and the second 7,834 without. With
# three tries some of the collapsing wall's sheets that fold were coarsened too, and its crack lost 0.6 point
# of its area in the weakest fifth; with one, the wall's and the clay's fold again and keep their triangles.
_FINER = 1


def _simplify_sheet(X: np.ndarray, FF: np.ndarray, cell: float | None) -> tuple[np.ndarray, np.ndarray] | None:
    """One sheet (triangles ``FF`` of points ``X``) coarsened (module notes): its new inner points and its
    triangles, whose entries are ids of ``X`` for the kept vertices and ``-1 - j`` for new point ``j``; None
    when the sheet is already as coarse as asked."""
    # the sheet's vertices in ascending order and its triangles on them: what np.unique(FF, return_inverse=True)
    # gives, by marking instead of sorting (a sheet's vertices are a part of X's: 26 sheets of the collapsing
    # wall's 89,000 contour triangles took 0.03 s of sorts)
    mark = np.zeros(len(X), bool)
    mark[FF] = True
    used = np.flatnonzero(mark)
    local = (np.cumsum(mark) - 1)[FF]
    table = edge_table(local, len(used))
    rim = np.unique(row_edges(local, table.first)[table.count == 1])
    target = max(2 * len(rim), 4)
    if cell is not None:  # triangles of about two cells' area
        T = X[used][local]
        area = 0.5 * np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1).sum()
        target = max(target, int(area / (_CELLS_PER_TRIANGLE * cell * cell)))
    if target >= len(local):
        return None
    # the collapse on the sheet scaled to about unit size by a power of two (exact both ways: the kept points
    # come back bit for bit): the libraries' tolerances are absolute, and a cut a ten-thousandth of a unit
    # across kept twice the triangles of the same cut a unit across
    scale = 2.0 ** -np.round(np.log2(max(float(np.ptp(X[used], axis=0).max()), tol.zero)))
    VD, FD = (_collapse_curved if cell is not None else _collapse_flat)(X[used] * scale, local, target)
    VD = np.asarray(VD, np.float64) / scale
    # kept vertices sit exactly where they were: back to their ids (a point at distance 0), the others are new
    # (a unique of the rows of both, axis=0, took five times as long on the collapsing wall's sheets)
    distance, nearest = cKDTree(X[used]).query(VD)
    ids = np.where(distance == 0.0, used[nearest], -1)
    new = ids < 0
    ids[new] = -1 - np.arange(int(new.sum()))
    fresh = VD[new]
    if not np.isin(used[rim], ids).all():  # the collapse moved a rim vertex (pymeshlab on a sheet a few cells
        return None  # wide: a thin plank's cut): the sheet keeps its triangles, which meet B and the others
    return np.asarray(fresh, np.float64).reshape(-1, 3), ids[FD]


def _collapse_curved(V: np.ndarray, F: np.ndarray, target: int) -> tuple[np.ndarray, np.ndarray]:
    """Quadric edge collapse of a curved sheet to ``target`` triangles, its boundary vertices kept."""
    import pyfqmr

    simplifier = pyfqmr.Simplify()
    simplifier.setMesh(V, F)
    simplifier.simplify_mesh(target_count=target, aggressiveness=7, preserve_border=True, verbose=False)
    VD, FD, _ = simplifier.getMesh()
    return np.asarray(VD, np.float64), np.asarray(FD, np.int64)


def _collapse_flat(V: np.ndarray, F: np.ndarray, target: int) -> tuple[np.ndarray, np.ndarray]:
    """Quadric edge collapse of a flat sheet to ``target`` triangles (a planar quadric keeps them well
    shaped), its boundary vertices kept."""
    return quadric_decimation(V, F, target, preserveboundary=True, boundaryweight=1000.0, preservenormal=True,
                              preservetopology=True, planarquadric=True, qualitythr=0.3, autoclean=False)


def _simplify_sheets(X: np.ndarray, FF: np.ndarray, sides: np.ndarray, cell: float | None, done: dict,
                     finer: dict | None = None):
    """Coarsen every sheet (module notes); returns the new points (``X`` followed by the sheets' new inner
    vertices) and triangles. ``done`` keeps each sheet's result by its pair of pieces, for the next call;
    ``finer`` (optional) how many times a sheet's cell is to be divided by the square root of two (twice the
    triangles each time)."""
    finer = {} if finer is None else finer
    n = len(X)
    out_X, out_F, out_S = [X], [np.zeros((0, 3), np.int64)], [np.zeros((0, 2), np.int64)]
    pair = sides[:, 0] * (sides.max(initial=0) + 1) + sides[:, 1]
    for k in np.unique(pair):
        sel = np.flatnonzero(pair == k)
        key = tuple(sides[sel[0]].tolist())
        if key not in done:
            done[key] = _simplify_sheet(X, FF[sel], None if cell is None else cell * 0.5 ** (finer.get(key, 0) / 2))
        if done[key] is None:
            out_F.append(FF[sel])
            out_S.append(sides[sel])
            continue
        fresh, F = done[key]
        out_X.append(fresh)
        out_F.append(np.where(F < 0, n - 1 - F, F))
        out_S.append(np.repeat(sides[sel[:1]], len(F), axis=0))
        n += len(fresh)
    return np.concatenate(out_X), np.concatenate(out_F), np.concatenate(out_S)


def _same_corners(F: np.ndarray) -> np.ndarray:
    """The triangles that share their three vertices with another."""
    group, size = corner_groups(F)
    return np.flatnonzero(size[group] > 1)


def _sheet_pinches(F: np.ndarray, sides: np.ndarray) -> np.ndarray:
    """The triangles on an edge that three or more triangles of their own sheet share (a collapse that
    joined two parts of a sheet along an edge: the pieces on either side would pinch there)."""
    if not len(F):
        return np.zeros(0, np.int64)
    _, sheet = np.unique(sides[:, 0] * (int(sides.max()) + 1) + sides[:, 1], return_inverse=True)
    key = edge_table(F, int(F.max()) + 1).eid * (int(sheet.max()) + 1) + np.repeat(sheet.ravel(), 3)
    _, inverse, count = np.unique(key, return_inverse=True, return_counts=True)
    return np.unique(np.flatnonzero(count[inverse.ravel()] > 2) // 3)


def coarsen_sheets(X: np.ndarray, FF: np.ndarray, sides: np.ndarray, cell: float | None = None,
                   crossings: int = 0):
    """Coarsened sheets (module notes), except for sheets whose coarsened triangles would cross another
    sheet (or themselves), fold two triangles onto the same three vertices or join two parts of the sheet
    along an edge: those are coarsened again less (with ``cell``, :data:`_FINER` times, each with twice
    the triangles: another collapse may not fold in the same place), then keep their triangles.
    Without ``cell``, a few triangles per rim vertex (flat sheets); with it, triangles of about two cells'
    area (curved ones). ``crossings``: the crossing pairs of triangles the sheets have already (none, for a
    contour), which the result may keep. Returns the points (``X`` followed by the new inner vertices),
    triangles and sides."""
    keep = np.zeros(len(FF), bool)
    base = sides.max(initial=0) + 1
    pair = sides[:, 0] * base + sides[:, 1]
    done: dict = {}  # a sheet coarsened once is the same the next round
    finer: dict = {}  # the sheets coarsened again less, and how many times
    for _ in range(4 + _FINER):
        XS, FS, SS = _simplify_sheets(X, FF[~keep], sides[~keep], cell, done, finer)
        XS_all = XS
        F_all = np.concatenate([FS, FF[keep]])
        S_all = np.concatenate([SS, sides[keep]])
        count, pairs = self_intersections(XS_all, F_all, report=100000)
        # two triangles on the same three vertices (a fold the collapse can leave) cross nowhere but
        # enclose no volume: the pieces on either side would be one
        folded = np.concatenate([_same_corners(F_all), _sheet_pinches(F_all, S_all)])
        if count <= crossings and not len(folded):
            return XS_all, F_all, S_all
        bad = np.concatenate([pairs.ravel() if count > crossings else np.zeros(0, np.int64), folded])
        hit = np.unique(S_all[bad][:, 0] * base + S_all[bad][:, 1])
        for k in hit:
            key = (int(k // base), int(k % base))
            if cell is not None and done.get(key) is not None and finer.get(key, 0) < _FINER:
                finer[key] = finer.get(key, 0) + 1
                del done[key]
            else:
                keep |= pair == k
    return X, FF, sides
