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
and only these holes, with their sides, are closed here. The import closes the coarse surface's far smaller
pinholes in the same place another way (:mod:`fracture.coarse.pinholes`: both read
:func:`~fracture.mesh.topology.simple_boundary_loops`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from fracture.mesh.edges import edge_table, row_edges
from fracture.mesh.exterior import Exterior
from fracture.mesh.fracture_surface import FractureSurface
from fracture.mesh.topology import simple_boundary_loops

# Holes whose rim is at most this many of B's median edges around are closed when their rim cuts B
# inconsistently (a hole of S larger than that is a real opening of a sheet, imprinted as it is).
MOST_AROUND = 3.0
# The closed hole's vertices are set this far inside B (in B's median edges).
INSET = 0.01


def holes_at(mesh: FractureSurface, points: np.ndarray, h: float) -> list[np.ndarray]:
    """The simple boundary loops of ``mesh`` (:func:`~fracture.mesh.topology.simple_boundary_loops`, as
    directed triangle edges) at most :data:`MOST_AROUND` ``h`` around that come within ``h / 2`` of one of
    ``points`` (where disagreeing cut edges end) and are not all of the boundary of their part of the
    surface (the whole rim of a small sheet is no hole)."""
    if not len(points):
        return []
    n = len(mesh.V)
    loops = simple_boundary_loops(mesh.F, n)
    if not loops:
        return []
    edges = np.concatenate([mesh.F[:, [0, 1]], mesh.F[:, [1, 2]]])
    part = connected_components(sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n)),
                                directed=False)[1]
    rim_of_part = np.bincount(part[mesh.F.ravel()[edge_table(mesh.F, n).boundary_rows]], minlength=part.max() + 1)
    found = []
    for rows in loops:
        E = row_edges(mesh.F, rows)
        if rim_of_part[part[E[0, 0]]] == len(rows):
            continue  # the only boundary of its part: a small sheet's rim
        if np.linalg.norm(mesh.V[E[:, 1]] - mesh.V[E[:, 0]], axis=1).sum() > MOST_AROUND * h:
            continue
        if np.linalg.norm(mesh.V[E[:, 0], None, :] - points[None, :, :], axis=2).min() <= 0.5 * h:
            found.append(rows)
    return found


def close_holes(mesh: FractureSurface, loops: list[np.ndarray], B: Exterior, h: float) -> int:
    """Close each hole ``loops`` (directed triangle edges, from :func:`holes_at`) of ``mesh`` in place
    (module notes); returns how many were closed (a loop whose triangles do not all separate the same two
    pieces is left)."""
    closed = 0
    for rows in loops:
        sides = mesh.sides[rows // 3]
        if not (sides == sides[0]).all():
            continue
        E = row_edges(mesh.F, rows)
        ring = E[:, 0]
        k = len(ring)
        parents = ring[[0, k // 3, (2 * k) // 3]][None, :]
        c = mesh._add_vertices(parents, np.full((1, 3), 1.0 / 3.0))[0]
        mesh.V[c] = mesh.V[ring].mean(axis=0)
        moved = np.r_[ring, c]
        mesh.V[moved] = _inside(B, mesh.V[moved], INSET * h)
        # the cap runs each rim edge the other way round, as the triangle across it would
        mesh.F = np.concatenate([mesh.F, np.stack([E[:, 1], E[:, 0], np.full(k, c)], axis=1)])
        mesh.sides = np.concatenate([mesh.sides, np.repeat(sides[:1], k, axis=0)])
        closed += 1
    return closed


def _inside(B: Exterior, P: np.ndarray, depth: float) -> np.ndarray:
    """Points ``P`` at least ``depth`` inside B: those less deep go to their closest point on B, moved in
    along B's normal there by ``depth``."""
    d2, tri, Q = B.closest(P)
    deep = B.inside(P) & (d2 >= depth * depth)
    moved = np.where(deep[:, None], P, Q - depth * B.normals[tri])
    # beside a sharp edge of B one face's normal can lead outside: such a point stays where it was
    return np.where(B.inside(moved)[:, None], moved, P)
