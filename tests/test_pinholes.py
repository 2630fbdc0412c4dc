"""Pinholes (fracture/coarse/pinholes.py): a real Cell Fracture cube whose contoured crack reaches the surface
through a hole of 0.018 grid cells; closed at import, the pieces still tile the object."""

import numpy as np
import pytest

from conftest import REPO
from fracture.coarse import tiling
from fracture.coarse.mesh_sequence import read_frame
from fracture.coarse.pinholes import PINHOLE, _loops
from fracture.mesh.intersect import self_intersections
from fracture.mesh.topology import closed_oriented, signed_volume

REST = REPO / "tests" / "data" / "cellfracture_pinhole_rest.obj"  # frame 1 of a Blender 3.4 OBJ export, 12 pieces


def _tiling():
    frame = read_frame(REST)
    return tiling.label_tiling(frame.V, frame.polygons, frame.names, source=str(REST))


def _loop_sizes(t):
    return sorted(float(np.linalg.norm(np.ptp(t.V[loop], axis=0))) for loop in _loops(t.fracture_F, len(t.V)))


def _cell(t):
    """The tiling's grid cell (the object's largest extent over its cells)."""
    return float(np.ptp(t.V[t.exterior_F].reshape(-1, 3), axis=0).max()) / t.cells


@pytest.fixture(scope="module")
def closed_and_open():
    closed = _tiling()
    with pytest.MonkeyPatch.context() as mp:  # the same import without the closing
        mp.setattr(tiling, "close_pinholes", lambda X, FF, sides, BF, bpiece, h: (X, FF, sides, BF, bpiece, 0))
        left = _tiling()
    return closed, left


def test_the_export_has_a_pinhole_and_the_import_closes_it(closed_and_open):
    closed, left = closed_and_open
    h = _cell(closed)
    assert min(_loop_sizes(left)) < 0.05 * h  # the sample is what this is about: a mouth of 0.018 cells
    assert min(_loop_sizes(closed)) >= PINHOLE * h
    assert len(_loop_sizes(closed)) == len(_loop_sizes(left)) - 1
    assert any("closed 1 pinhole" in note for note in closed.notes)
    assert not any("pinhole" in note for note in left.notes)


def test_after_closing_every_piece_is_closed_and_together_they_fill_b(closed_and_open):
    t, _ = closed_and_open
    assert closed_oriented(t.exterior_F)
    for c in range(len(t.kept)):
        F = np.concatenate([t.exterior_F[t.exterior_piece == c], t.fracture_F[t.sides[:, 0] == c],
                            t.fracture_F[t.sides[:, 1] == c][:, ::-1]])
        assert closed_oriented(F), c
        assert signed_volume(t.V, F) > 0
    total = sum(signed_volume(t.V, np.concatenate([t.exterior_F[t.exterior_piece == c],
                                                   t.fracture_F[t.sides[:, 0] == c],
                                                   t.fracture_F[t.sides[:, 1] == c][:, ::-1]]))
                for c in range(len(t.kept)))
    assert total == pytest.approx(signed_volume(t.V, t.exterior_F), rel=1e-9)
    assert self_intersections(t.V, t.fracture_F) == 0


def test_the_apex_is_inside_b_and_off_it(closed_and_open):
    import igl

    t, _ = closed_and_open
    apex = len(t.V) - 1  # the last vertex added: the cone's apex (B's point is the one before it)
    assert (t.fracture_F == apex).any() and not (t.exterior_F == apex).any()
    assert (t.exterior_F == apex - 1).any() and not (t.fracture_F == apex - 1).any()
    assert igl.winding_number(t.V, t.exterior_F, t.V[apex][None, :])[0] == pytest.approx(1.0, abs=1e-6)
    d = np.sqrt(igl.point_mesh_squared_distance(t.V[apex][None, :], t.V, t.exterior_F)[0][0])
    assert 0 < d < 0.1 * _cell(t)
