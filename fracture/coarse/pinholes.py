"""Pinholes: closed boundary curves of a fracture sheet on B far smaller than the grid, closed at import.

Where a piece pokes a thin spike through its neighbour to the object's
surface, the contoured sheet between the two is a funnel whose mouth is a
closed boundary curve on B, and B inside the mouth is an island of the spike's
piece. At a crease of B the bisected crossings can crowd such a mouth into a
few hundredths of a grid cell (a real Cell Fracture cube: four vertices within
0.018 cells). Nothing in the pipeline resolves a curve that small: the
refinement slides its vertices along B until the mouth turns over, and B's
island then faces the wrong piece, so neither piece closes.

A pinhole is closed by collapsing its mouth and B's island into one point: B
closes over it (a fan around the point, the surrounding patch's piece), and
the funnel becomes a cone whose apex is moved into the object by twice the
mouth's size, so the spike ends just inside its neighbour. Each collapse is
kept only if B stays a closed 2-manifold, the apex is inside B, the cone is a
closed fan of one sheet, the pieces around it still close and no sheet
crosses another; otherwise the pinhole stays as it was.

Written here because the collapse acts on B and the sheets together (they
share their vertices), which no mesh library's edge collapse does.
"""

from __future__ import annotations

import numpy as np

from fracture.coarse.surface import flood_fill_patches
from fracture.mesh.intersect import self_intersections
from fracture.mesh.edges import row_edges
from fracture.mesh.topology import closed_oriented, simple_boundary_loops, unique_edges, winding_numbers

# A closed boundary curve of a sheet smaller than this (grid cells, its box's diagonal) is a pinhole.
PINHOLE = 0.1


def _loops(FF: np.ndarray, n: int) -> list[np.ndarray]:
    """Vertex sets of the closed boundary curves of the sheets (edges of one fracture triangle) that are
    simple cycles."""
    return [np.unique(row_edges(FF, rows)) for rows in simple_boundary_loops(FF, n)]


def _pieces_close(FF, sides, BF, bpiece, pieces) -> bool:
    """Each of ``pieces``, its B triangles and its sides of the sheets, is closed and oriented."""
    return all(closed_oriented(np.concatenate([BF[bpiece == c], FF[sides[:, 0] == c], FF[sides[:, 1] == c][:, ::-1]]))
               for c in pieces)


def _collapse(X, FF, sides, BF, bpiece, loop, extent, size, crossings):
    """The surfaces with the pinhole ``loop`` (``extent`` across) closed (module notes), or None where a
    check fails (``crossings``: the sheets' crossing pairs before)."""
    in_loop = np.zeros(len(X), bool)
    in_loop[loop] = True
    # B's island: the smaller side of the mouth's edges on B
    touches = in_loop[FF]
    rows = np.flatnonzero(touches.any(axis=1))
    e, c = unique_edges(FF[rows])
    mouth = e[(c == 1) & in_loop[e].all(axis=1)]
    if len(mouth) != len(loop):
        return None
    patch = flood_fill_patches(BF, mouth)
    on_mouth = np.flatnonzero(in_loop[BF].sum(axis=1) >= 2)
    ids = np.unique(patch[on_mouth])
    if len(ids) != 2:
        return None
    counts = np.bincount(patch, minlength=int(patch.max()) + 1)[ids]
    island = np.flatnonzero(patch == ids[np.argmin(counts)])
    merged = np.zeros(len(X), bool)
    merged[BF[island]] = True
    if not merged[loop].all() or np.linalg.norm(np.ptp(X[merged], axis=0)) > size or (merged[FF] & ~in_loop[FF]).any():
        return None
    # one new point for B, one for the sheets' apex
    p = X[loop].mean(axis=0)
    spokes = FF[rows][touches[rows].sum(axis=1) == 1]
    ring = np.unique(spokes[~in_loop[spokes]])
    d = X[ring].mean(axis=0) - p
    length = float(np.linalg.norm(d))
    if length == 0.0:
        return None
    q = p + min(1.0, 2.0 * extent / length) * d
    ip, iq = len(X), len(X) + 1
    X2 = np.concatenate([X, [p, q]])
    keep_s = touches.sum(axis=1) < 2
    FF2 = np.where(in_loop[FF], iq, FF)[keep_s]
    sides2 = sides[keep_s]
    keep_b = merged[BF].sum(axis=1) < 2
    BF2 = np.where(merged[BF], ip, BF)[keep_b]
    bpiece2 = bpiece[keep_b]
    # checks: B closed, the apex inside it, the cone a closed fan of one sheet, the pieces closed, no crossings
    if not closed_oriented(BF2):
        return None
    cone = np.flatnonzero((FF2 == iq).any(axis=1))
    if len(np.unique(sides2[cone], axis=0)) != 1:
        return None
    e, c = unique_edges(FF2[cone])
    if (c[(e == iq).any(axis=1)] != 2).any():
        return None
    if not winding_numbers(X2, BF2, q[None, :])[0] > 0.5:
        return None
    if not _pieces_close(FF2, sides2, BF2, bpiece2, np.unique(np.r_[sides[rows].ravel(), bpiece[merged[BF].any(axis=1)]])):
        return None
    if self_intersections(X2, FF2) > crossings:
        return None
    return X2, FF2, sides2, BF2, bpiece2


def close_pinholes(X: np.ndarray, FF: np.ndarray, sides: np.ndarray, BF: np.ndarray, bpiece: np.ndarray, h: float,
                   limit: float = PINHOLE):
    """Close the sheets' pinholes smaller than ``limit`` grid cells of size ``h`` (module notes).

    ``X`` holds the vertices of both surfaces, ``FF`` and ``sides`` the fracture triangles and their
    pieces, ``BF`` and ``bpiece`` B's triangles and theirs. Returns the five arrays (vertices are
    appended, the collapsed ones left unused) and the number of pinholes closed.
    """
    closed = 0
    size = limit * h
    extents = [(loop, float(np.linalg.norm(np.ptp(X[loop], axis=0)))) for loop in _loops(FF, len(X))]
    small = [(loop, extent) for loop, extent in extents if extent < size]
    crossings = self_intersections(X, FF) if small else 0
    for loop, extent in small:
        out = _collapse(X, FF, sides, BF, bpiece, loop, extent, size, crossings)
        if out is not None:
            X, FF, sides, BF, bpiece = out
            closed += 1
    return X, FF, sides, BF, bpiece, closed
