"""Small holes of the refined surface that touch B are closed: the sheet passes just inside B, oriented and
sided as around the hole, and the new vertex hangs in the tree."""

from __future__ import annotations

import numpy as np

from fracture.mesh.exterior import Exterior
from fracture.mesh.fracture_surface import FractureSurface
from fracture.mesh.primitives import box, sheet
from fracture.mesh.edges import row_edges
from fracture.mesh.topology import simple_boundary_loops as boundary_loops, unique_edges
from fracture.pieces.holes import INSET, close_holes, holes_at


def _sheet_with_a_hole(sides=(2, 5)):
    """The unit box's top face as a sheet (12 x 12 quads), the fan of its middle vertex removed: a hole of six
    edges, 0.57 around, whose rim lies on B."""
    V, F = sheet(lambda u, v: np.stack([u, v, np.ones_like(u)], 1), (0, 1), (0, 1), 13, 13)
    F = np.asarray(F, np.int64)
    centre = int(np.argmin(np.linalg.norm(V[:, :2] - 0.5, axis=1)))
    keep = ~(F == centre).any(axis=1)
    mesh = FractureSurface.from_coarse(V, F[keep], np.tile(sides, (keep.sum(), 1)))
    return mesh, V[centre], Exterior(*box([0, 0, 0], [1, 1, 1], (4, 4, 4)))


def test_only_small_loops_near_the_disagreeing_cuts_are_holes():
    mesh, centre, _ = _sheet_with_a_hole()
    assert len(boundary_loops(mesh.F, len(mesh.V))) == 2  # the sheet's rim and the hole's
    h = 0.25  # B's edges
    assert [len(loop) for loop in holes_at(mesh, centre[None], h)] == [6]
    assert holes_at(mesh, np.array([[5.0, 5.0, 5.0]]), h) == []  # far from the disagreeing cuts
    assert holes_at(mesh, np.array([[0.0, 0.0, 1.0]]), h) == []  # the rim: 4 around, more than 3 edges of B
    assert holes_at(mesh, centre[None], 0.1) == []  # more than 3 edges of a finer B around


def test_a_small_hole_is_closed_inside_b_with_its_sides():
    mesh, centre, B = _sheet_with_a_hole()
    h = 0.25
    loops = holes_at(mesh, centre[None], h)
    assert len(loops) == 1 and len(loops[0]) == 6
    ring = row_edges(mesh.F, loops[0])[:, 0]
    n, m = len(mesh.V), len(mesh.F)
    assert close_holes(mesh, loops, B, h) == 1
    assert len(mesh.V) == n + 1 and len(mesh.F) == m + 6
    # the hole is gone: only the sheet's outer rim is left, and every inner edge has two triangles that
    # run it both ways (the cap is oriented as the sheet)
    assert len(boundary_loops(mesh.F, len(mesh.V))) == 1
    E = np.concatenate([mesh.F[:, [0, 1]], mesh.F[:, [1, 2]], mesh.F[:, [2, 0]]])
    directed = {tuple(e) for e in E.tolist()}
    assert len(directed) == len(E)  # no directed edge twice
    inner = [e for e in E.tolist() if (e[1], e[0]) in directed]
    assert len(inner) == 2 * int((unique_edges(mesh.F)[1] == 2).sum())
    assert (mesh.sides[m:] == [2, 5]).all()
    # the cap and its rim just inside B, by INSET of B's edge
    moved = np.r_[ring, n]
    assert B.inside(mesh.V[moved]).all()
    assert np.allclose(B.distance(mesh.V[moved]), INSET * h)
    # the new vertex hangs from three of the rim's vertices
    assert set(mesh.parents[-1][0].tolist()) <= set(mesh.label[ring].tolist())
    assert np.allclose(mesh.weights[-1], 1.0 / 3.0)


def test_a_hole_between_other_pieces_on_each_side_is_left_open():
    mesh, centre, B = _sheet_with_a_hole(sides=(0, 1))
    loops = holes_at(mesh, centre[None], 0.25)
    a, b = row_edges(mesh.F, loops[0])[0]
    on_rim = np.flatnonzero(((mesh.F == a) & (np.roll(mesh.F, -1, axis=1) == b)).any(axis=1))
    mesh.sides[on_rim] = [0, 2]  # the triangle on one rim edge separates another pair of pieces
    assert close_holes(mesh, loops, B, 0.25) == 0 and len(boundary_loops(mesh.F, len(mesh.V))) == 2


def test_the_whole_rim_of_a_small_sheet_is_no_hole():
    """A small sheet of its own (two triangles, 0.2 around) near the disagreeing cuts keeps its rim: capping
    it would lay a second layer on it."""
    mesh, centre, _ = _sheet_with_a_hole()
    n = len(mesh.V)
    square = np.array([[0.2, 0.2, 0.5], [0.25, 0.2, 0.5], [0.25, 0.25, 0.5], [0.2, 0.25, 0.5]])
    mesh.V = np.concatenate([mesh.V, square])
    mesh.label = np.arange(len(mesh.V))
    mesh.F = np.concatenate([mesh.F, [[n, n + 1, n + 2], [n, n + 2, n + 3]]])
    mesh.sides = np.concatenate([mesh.sides, [[2, 5], [2, 5]]])
    assert len(boundary_loops(mesh.F, len(mesh.V))) == 3
    assert holes_at(mesh, square, 0.25) == []
    assert [len(loop) for loop in holes_at(mesh, np.r_[square, centre[None]], 0.25)] == [6]
