"""The refinement finds weak material: synthetic weak sheets (flat, tilted, curved) with cuts 2, 4 and 8
voxels off end on the sheet; a cut already on one stays there; no step raises the functional."""

from __future__ import annotations

import numpy as np
import pytest

from fields.pyramid import StrengthPyramid
from fracture.coarse.scenes.weak_sheets import SHEETS, weak_sheet_case
from fracture.fidelity import area_samples
from fracture.mesh.intersect import self_intersections
from fracture.refine.engine import RefineParams, Refiner
from fracture.mesh.fracture_surface import FractureSurface
from fracture.tolerances import tol


def refine_case(case, levels=5, **params):
    pyramid = StrengthPyramid(case.grid, case.zeta, levels=levels, sigma=1.0)
    mesh = FractureSurface.from_coarse(case.cut_V, case.cut_F, np.tile([0, 1], (len(case.cut_F), 1)))
    r = Refiner(mesh, pyramid, case.BV, case.BF, RefineParams(max_triangles=12000, **params),
                np.random.default_rng(0))
    return r, r.run()


@pytest.mark.parametrize("kind", SHEETS)
@pytest.mark.parametrize("offset", [2.0, 4.0, 8.0])
def test_the_refined_surface_ends_on_the_weak_sheet(kind, offset):
    case = weak_sheet_case(kind, offset)
    start = case.distance_to_sheet(area_samples(case.cut_V, case.cut_F))
    r, log = refine_case(case)
    d = case.distance_to_sheet(area_samples(r.mesh.V, r.mesh.F))
    assert start.mean() > 0.8 * offset  # the cut started off the sheet
    assert d.mean() < 1.0 and np.mean(d < 1.0) >= 0.7
    E, before = np.array(log.functional), np.array(log.functional_before)
    assert (E <= before + tol.functional_rise * np.abs(before)).all()  # up to rounding
    assert self_intersections(r.mesh.V, r.mesh.F) == 0
    assert log.boundary_error[-1] < 1e-9


def test_a_cut_on_the_weak_sheet_stays_there():
    case = weak_sheet_case("flat", 0.0)
    r, log = refine_case(case, search="none")
    d = case.distance_to_sheet(area_samples(r.mesh.V, r.mesh.F))
    assert d.max() < 0.05
    assert len(r.mesh.F) == len(case.cut_F)  # a flat field along a flat cut: nothing to refine


def test_coarse_levels_reach_a_sheet_that_the_finest_level_alone_does_not_see():
    """Eight voxels off, the sheet is beyond level 0's reach; the schedule's coarse stages find it, and so
    does the paper's field (the mean of every level) given the iterations."""
    case = weak_sheet_case("flat", 8.0)
    r, _ = refine_case(case, search="none")
    assert case.distance_to_sheet(area_samples(r.mesh.V, r.mesh.F)).mean() < 0.5
    r, _ = refine_case(case, levels=1, coarse_levels=1, search="none")  # level 0 alone
    assert case.distance_to_sheet(area_samples(r.mesh.V, r.mesh.F)).mean() > 7.5
    r, _ = refine_case(case, coarse_levels=5, stage_iterations=60, search="none")  # one stage on every level
    assert case.distance_to_sheet(area_samples(r.mesh.V, r.mesh.F)).mean() < 0.5
