"""Quadric edge collapse (Garland and Heckbert) through pymeshlab, with every parameter of the filter given.

MeshLab's filter keeps the parameters of its last call in the process: a call that leaves one out gets what
the call before it set, not the default (a flat sheet's collapse with a planar quadric, then the marble
bunny's decimation without one, gave the bunny another shape, and the search another cut, after a Blender
import had run in the same process). :func:`quadric_decimation` passes them all, so its result depends on its
arguments only.
"""

from __future__ import annotations

import numpy as np

# The filter's own defaults (pymeshlab.print_filter_parameter_list('meshing_decimation_quadric_edge_collapse')).
_DEFAULTS = dict(targetperc=0.0, qualitythr=0.3, preserveboundary=False, boundaryweight=1.0, preservenormal=False,
                 preservetopology=False, optimalplacement=True, planarquadric=False, planarweight=0.001,
                 qualityweight=False, autoclean=True, selected=False)


def quadric_decimation(V: np.ndarray, F: np.ndarray, target: int, **options) -> tuple[np.ndarray, np.ndarray]:
    """``(V, F)`` collapsed to about ``target`` triangles: points ``(n, 3)`` float64 and triangles ``(m, 3)``
    int64. ``options`` are the filter's parameters that differ from its defaults (:data:`_DEFAULTS`)."""
    import pymeshlab

    unknown = set(options) - set(_DEFAULTS)
    if unknown:
        raise ValueError(f"quadric_decimation: unknown options {sorted(unknown)}; expected some of {sorted(_DEFAULTS)}")
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.ascontiguousarray(V, np.float64), np.ascontiguousarray(F, np.int32)))
    ms.meshing_decimation_quadric_edge_collapse(targetfacenum=int(target), **{**_DEFAULTS, **options})
    m = ms.current_mesh()
    return np.ascontiguousarray(m.vertex_matrix(), np.float64), m.face_matrix().astype(np.int64)
