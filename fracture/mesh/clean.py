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
"""

from __future__ import annotations

import numpy as np

from fracture.mesh.topology import diagonal, face_frames, signed_volume, unique_edges
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
