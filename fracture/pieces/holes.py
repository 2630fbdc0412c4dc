"""Small holes of the refined surface S where it touches the object's surface B, closed before the pieces are
made (Section 5's input, mended).

A sheet that touches B from inside along a short stretch can keep a hole there whose rim lies on B and
encloses almost none of it (on a Blender export of Suzanne: a rim of 6 vertices, 0.96 of B's median edge
around, over an island of B of 1e-7 square units). Imprinted, the rim cuts that island out of B, and its
orientation gives the island to one of the sheet's pieces and the patch around it, locally, to the other:
against what every other cut of that patch says, so the other piece does not close. Such a rim shows
itself as cut edges whose votes disagree with their patch's piece
(:func:`fracture.pieces.assembly.label_patches`); the hole is closed by a fan from a new vertex at its
centroid, and the rim's vertices and the new one are set just inside B (by :data:`INSET` of B's median
edge), so that the sheet passes under B there instead of through it. The new vertex hangs in the barycentric
tree from three of the rim's vertices.

libigl's ``topological_hole_fill`` fills every hole of a manifold mesh; S is not manifold at its junctions,
and only these holes, with their sides, are closed here.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from fracture.mesh.edges import edge_table, row_edges
from fracture.mesh.exterior import Exterior
from fracture.mesh.fracture_surface import FractureSurface

# Holes whose rim is at most this many of B's median edges around are closed when their rim cuts B
# inconsistently (a hole of S larger than that is a real opening of a sheet, imprinted as it is).
MOST_AROUND = 3.0
# The closed hole's vertices are set this far inside B (in B's median edges).
INSET = 0.01


def boundary_loops(F: np.ndarray, n: int) -> list[np.ndarray]:
    """The boundary curves of ``F`` that are simple closed loops, each as its directed edges ``(k, 2)`` in
    order, as they run in their triangles (a curve through a vertex that has more than one boundary edge
    out of it, at a junction of sheets, is left out)."""
    table = edge_table(F, n)
    rows = table.boundary_rows
    E = row_edges(F, rows)
    out_count = np.bincount(E[:, 0], minlength=n)
    in_count = np.bincount(E[:, 1], minlength=n)
    nxt = np.full(n, -1, np.int64)
    nxt[E[:, 0]] = np.arange(len(E))
    seen = np.zeros(len(E), bool)
    loops = []
    for start in range(len(E)):
        if seen[start]:
            continue
        chain, e, simple = [], start, True
        while not seen[e]:
            seen[e] = True
            chain.append(e)
            a, b = E[e]
            simple &= out_count[a] == 1 and in_count[a] == 1
            e = nxt[b]
            if e < 0:
                simple = False
                break
        if simple and e == start:
            loops.append(E[chain])
    return loops


def holes_at(mesh: FractureSurface, points: np.ndarray, h: float) -> list[np.ndarray]:
    """The simple boundary loops of ``mesh`` at most :data:`MOST_AROUND` ``h`` around that come within
    ``h / 2`` of one of ``points`` (where disagreeing cut edges end) and are not all of the boundary of
    their part of the surface (the whole rim of a small sheet is no hole)."""
    if not len(points):
        return []
    n = len(mesh.V)
    edges = np.concatenate([mesh.F[:, [0, 1]], mesh.F[:, [1, 2]]])
    part = connected_components(sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n)),
                                directed=False)[1]
    loops = boundary_loops(mesh.F, n)
    rim_of_part = np.bincount(part[np.concatenate([loop[:, 0] for loop in loops])], minlength=part.max() + 1) \
        if loops else np.zeros(part.max() + 1, np.int64)
    found = []
    for loop in loops:
        if rim_of_part[part[loop[0, 0]]] == len(loop):
            continue  # the only boundary of its part: a small sheet's rim
        P = mesh.V[loop[:, 0]]
        around = np.linalg.norm(mesh.V[loop[:, 1]] - P, axis=1).sum()
        if around > MOST_AROUND * h:
            continue
        d = np.linalg.norm(P[:, None, :] - points[None, :, :], axis=2).min()
        if d <= 0.5 * h:
            found.append(loop)
    return found


def close_holes(mesh: FractureSurface, loops: list[np.ndarray], B: Exterior, h: float) -> int:
    """Close each hole ``loops`` (from :func:`boundary_loops`) of ``mesh`` in place (module notes); returns
    how many were closed (a loop whose triangles do not all separate the same two pieces is left)."""
    closed = 0
    for loop in loops:
        rows = _rows_of(mesh.F, loop)
        sides = mesh.sides[rows // 3]
        if not (sides == sides[0]).all():
            continue
        ring = loop[:, 0]
        k = len(ring)
        parents = ring[[0, k // 3, (2 * k) // 3]][None, :]
        c = mesh._add_vertices(parents, np.full((1, 3), 1.0 / 3.0))[0]
        mesh.V[c] = mesh.V[ring].mean(axis=0)
        moved = np.r_[ring, c]
        mesh.V[moved] = _inside(B, mesh.V[moved], INSET * h)
        # the cap runs each rim edge the other way round, as the triangle across it would
        cap = np.stack([loop[:, 1], loop[:, 0], np.full(k, c)], axis=1)
        mesh.F = np.concatenate([mesh.F, cap])
        mesh.sides = np.concatenate([mesh.sides, np.repeat(sides[:1], k, axis=0)])
        closed += 1
    return closed


def _rows_of(F: np.ndarray, E: np.ndarray) -> np.ndarray:
    """The directed triangle edges (rows ``3 f + k``, edge ``F[f, k] -> F[f, k + 1]``) that run as ``E``."""
    D = np.stack([F, np.roll(F, -1, axis=1)], axis=2).reshape(-1, 2)
    index = {(a, b): r for r, (a, b) in enumerate(D.tolist())}
    return np.array([index[(a, b)] for a, b in E.tolist()], np.int64)


def _inside(B: Exterior, P: np.ndarray, depth: float) -> np.ndarray:
    """Points ``P`` at least ``depth`` inside B: those less deep go to their closest point on B, moved in
    along B's normal there by ``depth``."""
    d2, tri, Q = B.closest(P)
    deep = B.inside(P) & (d2 >= depth * depth)
    moved = np.where(deep[:, None], P, Q - depth * B.normals[tri])
    # beside a sharp edge of B one face's normal can lead outside: such a point stays where it was
    return np.where(B.inside(moved)[:, None], moved, P)
