"""Quadric decimation (fracture/mesh/decimate.py): a call's result depends on its arguments only."""

from __future__ import annotations

import numpy as np
import pytest

from fracture.coarse.scenes import bunny_mesh
from fracture.mesh.decimate import quadric_decimation
from fracture.mesh.primitives import sheet


def test_a_decimation_does_not_take_the_last_calls_options():
    """MeshLab's filter keeps its last call's parameters: a flat sheet's collapse with a planar quadric and
    its boundary held changed the marble bunny's decimation after it (and so its scene, and the search's cut)."""
    BV, BF = bunny_mesh()
    first = quadric_decimation(BV, BF, 700, preservetopology=True)
    V, F = sheet(lambda u, v: np.stack([u, v, 0.0 * u], 1), (0, 1), (0, 1), 20, 20)
    quadric_decimation(V, F, 50, preserveboundary=True, boundaryweight=1000.0, preservenormal=True,
                       preservetopology=True, planarquadric=True, autoclean=False)
    again = quadric_decimation(BV, BF, 700, preservetopology=True)
    assert np.array_equal(first[0], again[0]) and np.array_equal(first[1], again[1])
    assert abs(len(first[1]) - 700) <= 10 and first[1].dtype == np.int64


def test_an_unknown_option_is_refused():
    V, F = sheet(lambda u, v: np.stack([u, v, 0.0 * u], 1), (0, 1), (0, 1), 4, 4)
    with pytest.raises(ValueError, match="unknown options \\['planar'\\]"):
        quadric_decimation(V, F, 8, planar=True)
