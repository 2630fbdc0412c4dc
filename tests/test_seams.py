"""The refinement composes its flow and its split rule through seams (fracture/refine/engine.py): a second
flow (mean curvature flow) and a second split rule (halve long edges) are swapped in through the
constructor alone, and the defaults are the paper's."""

from __future__ import annotations

import numpy as np

from fields.grid import Grid
from fields.pyramid import StrengthPyramid
from fracture.mesh.fracture_surface import FractureSurface
from fracture.mesh.primitives import box, sheet
from fracture.refine.engine import RefineParams, Refiner
from fracture.refine.flow import AreaFlow, PsiFlow
from fracture.refine.remesh import LongEdgeSplits, PsiSplits


def setting():
    """A bumpy sheet across the unit box (its rim on the box) and a psi that falls along x."""
    V, F = sheet(lambda u, v: np.stack([u, v, 0.5 + 0.12 * np.sin(np.pi * u) * np.sin(np.pi * v)], 1), (0, 1),
                 (0, 1), 9, 9)
    mesh = FractureSurface.from_coarse(V, F, np.tile([0, 1], (len(F), 1)))
    grid = Grid.from_bounds([-0.05] * 3, [1.05] * 3, (23, 23, 23))
    P = grid.points().reshape(*grid.shape, 3)
    pyramid = StrengthPyramid(grid, 1.0 - 0.8 * P[..., 0] + 0.3 * np.abs(P[..., 2] - 0.5), levels=3, sigma=1.0)
    BV, BF = box([0, 0, 0], [1, 1, 1], (4, 4, 4))
    return mesh, pyramid, BV, BF


def area(mesh) -> float:
    T = mesh.V[mesh.F]
    return 0.5 * float(np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1).sum())


def refine(**seams) -> FractureSurface:
    mesh, pyramid, BV, BF = setting()
    Refiner(mesh, pyramid, BV, BF, RefineParams(max_triangles=3000, iterations=12), np.random.default_rng(0),
            search=None, **seams).run()
    return mesh


def test_mean_curvature_flow_and_long_edge_splits_swap_in_through_the_constructor():
    start = setting()[0]
    length = 0.08
    mesh = refine(flow=AreaFlow(), splits=LongEdgeSplits(length))
    assert area(mesh) < area(start) - 0.01  # the bump flattens: only area counts
    assert np.abs(mesh.V[:, 2] - 0.5).max() < 0.5 * np.abs(start.V[:, 2] - 0.5).max()
    E = np.concatenate([mesh.F[:, [0, 1]], mesh.F[:, [1, 2]], mesh.F[:, [2, 0]]])
    lengths = np.linalg.norm(mesh.V[E[:, 1]] - mesh.V[E[:, 0]], axis=1)
    assert len(mesh.F) > 4 * len(start.F) and np.percentile(lengths, 95) <= 1.5 * length  # uniformly refined
    paper = refine()
    assert not np.allclose(paper.V[: len(start.V)], mesh.V[: len(start.V)], atol=1e-3)  # psi moves it elsewhere


def test_the_defaults_are_the_paper_flow_and_split_rule():
    default, explicit = refine(), refine(flow=PsiFlow(), splits=PsiSplits())
    np.testing.assert_array_equal(default.F, explicit.F)
    np.testing.assert_array_equal(default.V, explicit.V)
