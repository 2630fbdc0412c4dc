"""No crossing pair leaves the refinement (fracture/refine/untangle.py): a crumpled sheet is relaxed apart
where it crosses itself, and left alone elsewhere; a surface that cannot be parted is refused."""

import numpy as np
import pytest

from fracture.errors import ResultError
from fracture.mesh.exterior import Exterior
from fracture.mesh.intersect import self_intersections
from fracture.mesh.primitives import box, sheet
from fracture.mesh.topology import boundary_edges
from fracture.refine.untangle import require_uncrossed, untangle


def crumpled(seed=3):
    """A sheet across the unit box (its rim on the box) whose middle is crumpled until it crosses itself."""
    V, F = sheet(lambda u, v: np.stack([u, v, np.full_like(u, 0.5)], 1), (0, 1), (0, 1), 13, 13)
    rng = np.random.default_rng(seed)
    middle = np.flatnonzero((np.abs(V[:, :2] - 0.5) < 0.2).all(axis=1))
    V[middle] += rng.normal(0.0, 0.06, (len(middle), 3))
    return V, F, middle


def test_a_crumpled_sheet_is_relaxed_apart_and_only_around_its_crossings():
    V, F, middle = crumpled()
    B = Exterior(*box([0, 0, 0], [1, 1, 1], (4, 4, 4)))
    assert self_intersections(V, F) > 0
    X, before, left = untangle(V, F, B)
    assert before > 0 and left == 0 and self_intersections(X, F) == 0
    rim = np.unique(boundary_edges(F))
    assert B.distance(X[rim]).max() < 1e-9  # the rim stays on B
    corners = np.flatnonzero((np.abs(V[:, :2] - 0.5) > 0.45).all(axis=1))
    assert len(corners) == 4 and np.array_equal(X[corners], V[corners])  # far from the crumple: unmoved
    assert np.abs(X - V).max() > 0.01
    assert untangle(X, F, B)[1] == 0  # nothing crosses: nothing to do


def test_a_surface_that_cannot_be_parted_is_refused_naming_where():
    V, F, _ = crumpled()
    B = Exterior(*box([0, 0, 0], [1, 1, 1], (4, 4, 4)))
    with pytest.raises(ResultError, match=r"refine: \d+ pairs of refined fracture triangles cross each other "
                                          r"\(the first near \["):
        require_uncrossed(V, F, B, rounds=0)
    X, before, _ = require_uncrossed(V, F, B)
    assert before > 0 and self_intersections(X, F) == 0

