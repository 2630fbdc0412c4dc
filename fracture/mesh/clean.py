"""Flat triangles out of a closed exterior, its shape unchanged.

A closed surface made by CAD booleans (CGAL's union of boxes, a modeller's
merge) often keeps triangles without area: corners at one position under
different vertex numbers where coplanar faces merged, or three corners on a
line (a T-junction closed by a sliver). They bound nothing, but the refined
cracks are traced across B triangle by triangle (:mod:`fracture.pieces.imprint`),
and a trace cannot cross a triangle without a plane: it fell back to a path
along B's edges through a far corner, which then fenced other cracks off.

:func:`remove_flat_triangles` merges coincident corners and removes the
triangles left without three distinct corners (pymeshlab: merge close
vertices, remove duplicate and null faces), then flips the slivers away
(pymeshlab's T-vertex removal by edge flips). The result is taken only if it
is still closed and encloses the same volume; otherwise the surface is kept as
it was.

:func:`collapse_short_edges` joins the corners of edges far shorter than the
surface's own (the slivers and bumps of a few hundredths of a cell that the
contour's bisection leaves where B's creases meet the cracks); the imprint
asks for it when a crack cannot be traced across such a bump. Written here
because pymeshlab merges vertices by proximity, also across a thin part of
the object, and libigl's decimation stops at a face count, not a length.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from fracture.mesh.intersect import self_intersections
from fracture.mesh.topology import (across_edges, corner_groups, diagonal, face_frames, manifold_vertices,
                                    signed_volume, unique_edges)
from fracture.tolerances import tol


def flat_triangles(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Which triangles have no area (doubled area at most ``tol.degenerate`` times the squared diagonal)."""
    return 2 * face_frames(V, F)[0] <= tol.degenerate * diagonal(V) ** 2


def remove_flat_triangles(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """The closed surface ``(V, F)`` without flat triangles (module notes), and how many it had (0: the input
    returned as it was; also when cleaning would open the surface or change its volume)."""
    flat = int(flat_triangles(V, F).sum())
    if not flat:
        return V, F, 0
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.asarray(V, np.float64), np.asarray(F, np.int32)))
    ms.meshing_merge_close_vertices(threshold=pymeshlab.PureValue(tol.same_position * diagonal(V)))
    ms.meshing_remove_duplicate_faces()
    ms.meshing_remove_null_faces()
    m = ms.current_mesh()
    W, G = m.vertex_matrix(), m.face_matrix().astype(np.int64)
    if len(G) and flat_triangles(W, G).any():  # slivers with three distinct corners on a line
        ms.meshing_remove_t_vertices(method=1, threshold=40, repeat=True)  # 1: by edge flips
        m = ms.current_mesh()
        W, G = m.vertex_matrix(), m.face_matrix().astype(np.int64)
    ms.meshing_remove_unreferenced_vertices()
    m = ms.current_mesh()
    W, G = np.ascontiguousarray(m.vertex_matrix(), np.float64), np.ascontiguousarray(m.face_matrix(), np.int64)
    _, counts = unique_edges(G) if len(G) else (None, np.zeros(1))
    volume = signed_volume(V, F)
    if (not len(G) or np.any(counts != 2) or flat_triangles(W, G).any()
            or abs(signed_volume(W, G) - volume) > tol.closure * max(abs(volume), diagonal(V) ** 3)):
        return V, F, 0
    return W, G, flat


def collapse_short_edges(V: np.ndarray, F: np.ndarray, length: float) -> tuple[np.ndarray, np.ndarray, int]:
    """The closed surface ``(V, F)`` with the corners of every edge shorter than ``length`` joined (each
    group of corners so connected at their mean), the triangles left without three corners and pairs of
    opposite triangles on the same corners removed; and how many vertices went. The input comes back (and
    0) when there is no such edge or the result would not be closed, vertex-manifold and free of crossings
    with the same volume (within ``tol.closure``)."""
    e, _ = unique_edges(F)
    short = e[np.linalg.norm(V[e[:, 1]] - V[e[:, 0]], axis=1) < length]
    if not len(short):
        return V, F, 0
    n = len(V)
    graph = sp.coo_matrix((np.ones(len(short)), (short[:, 0], short[:, 1])), shape=(n, n))
    k, group = csgraph.connected_components(graph, directed=False)
    W = np.zeros((k, 3))
    np.add.at(W, group, V)
    W /= np.bincount(group, minlength=k)[:, None]
    G = group[F]
    G = G[(G[:, 0] != G[:, 1]) & (G[:, 1] != G[:, 2]) & (G[:, 2] != G[:, 0])]
    group, size = corner_groups(G)
    G = G[size[group] == 1]  # a flattened bump leaves its two sides on the same corners
    used, inverse = np.unique(G, return_inverse=True)
    W, G = W[used], inverse.reshape(-1, 3).astype(np.int64)
    volume = signed_volume(V, F)
    across = across_edges(G) if len(G) else None
    if (across is None or not manifold_vertices(G, across).all()
            or abs(signed_volume(W, G) - volume) > tol.closure * max(abs(volume), diagonal(V) ** 3)
            or self_intersections(W, G)):
        return V, F, 0
    return W, G, n - len(W)

