"""Trim a cut to the object: the part of a fracture surface outside the exterior B goes.

A cut drawn by hand (a plane through a box, a sheet from a modelling tool)
often overhangs the object. The pieces are bounded by B and by the part of
the fracture surface inside B, so the rest is cut away along its
intersection with B. libigl's ``remesh_self_intersections`` does this
exactly (CGAL's exact predicates) on the union of both surfaces: it splits
the fracture triangles along B, including where the cut runs through B's
edges and vertices (a plane through a box at half height), which
``trim_with_solid`` refuses; each part is then wholly inside or outside B,
and its centroid's winding number tells which.
"""

from __future__ import annotations

import igl
import igl.copyleft.cgal  # noqa: F401 (igl.copyleft.cgal.remesh_self_intersections)
import numpy as np

from fracture.mesh.exterior import Exterior
from fracture.tolerances import tol
from fracture.mesh.topology import diagonal, weld


def trim_to_object(V: np.ndarray, F: np.ndarray, BV: np.ndarray, BF: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, float]:
    """The part of the surface ``(V, F)`` inside the closed surface ``(BV, BF)``.

    Vertices within ``tol.on_surface`` of B's diagonal outside it count as
    on B (a cut that ends on B as drawn is returned unchanged). The split
    points are rounded to floating point, so corners of the kept triangles
    closer than ``tol.extent`` of the diagonal are merged and the triangles
    this flattens dropped.

    Returns
    -------
    V, F : the trimmed surface (unchanged if nothing lies outside); F may be empty.
    removed : float
        The share of the surface's area that was outside.
    """
    h = diagonal(BV)
    exterior = Exterior(BV, BF)
    outside = ~exterior.inside(V) & (exterior.closest(V)[0] > (tol.on_surface * h) ** 2)
    if not outside.any():
        return V, F, 0.0
    area = igl.doublearea(V, F).sum()
    TV, TF, _, birth, unique = igl.copyleft.cgal.remesh_self_intersections(
        np.r_[V, BV], np.r_[F, BF + len(V)], stitch_all=True, cutoff=np.iinfo(np.int32).max)
    TF = unique[TF[birth < len(F)]]
    TF = TF[exterior.inside(TV[TF].mean(axis=1))]
    if not len(TF):
        return V[:0], F[:0], 1.0
    used, TF = np.unique(TF, return_inverse=True)
    TF = TF.reshape(-1, 3)
    TV, cluster = weld(TV[used], tol.extent * h)
    TF = cluster[TF]
    TF = TF[(TF[:, 0] != TF[:, 1]) & (TF[:, 1] != TF[:, 2]) & (TF[:, 0] != TF[:, 2])]
    used, TF = np.unique(TF, return_inverse=True)
    TF = TF.reshape(-1, 3)
    TV = TV[used]
    kept = igl.doublearea(TV, TF).sum() if len(TF) else 0.0
    return TV, TF, float(1.0 - kept / area)
