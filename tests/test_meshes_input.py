"""A still object given as an exterior and a cut (``input.kind: meshes``): what the door does with
cuts that overhang, miss or enclose, and with exteriors turned inside out."""

import numpy as np
import pytest

from fracture.errors import InputError
from fracture.io.obj import write_obj
from fracture.mesh.primitives import box, grid_faces
from fracture.pipeline.stages.coarse import coarse_from_meshes
from fracture.mesh.topology import orient_outward, signed_volume
from fracture.coarse.trim import trim_to_object


def _plane(z, lo=-0.3, hi=1.3, n=8):
    g = np.linspace(lo, hi, n + 1)
    X, Y = np.meshgrid(g, g, indexing="ij")
    return np.c_[X.ravel(), Y.ravel(), np.full(X.size, z)], grid_faces(n + 1, n + 1)


def _area(V, F):
    return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum()


@pytest.mark.parametrize("z", [0.43, 0.5])  # 0.5 runs through the box's vertices and edges
def test_an_overhanging_plane_is_trimmed_exactly_to_the_box(z):
    BV, BF = box([0, 0, 0], [1, 1, 1], (4, 4, 4))
    V, F = _plane(z)
    TV, TF, outside = trim_to_object(V, F, BV, BF)
    assert _area(TV, TF) == pytest.approx(1.0, abs=1e-12)
    assert outside == pytest.approx(1 - 1 / 1.6 ** 2)
    assert TV.min(axis=0) == pytest.approx([0, 0, z]) and TV.max(axis=0) == pytest.approx([1, 1, z])


def test_a_cut_inside_the_object_is_left_alone():
    BV, BF = box([0, 0, 0], [1, 1, 1], (4, 4, 4))
    V, F = _plane(0.43, 0.0, 1.0)
    TV, TF, outside = trim_to_object(V, F, BV, BF)
    assert outside == 0.0 and TV is V and TF is F


def _meshes(tmp_path, exterior, cut):
    write_obj(tmp_path / "exterior.obj", *exterior)
    write_obj(tmp_path / "cut.obj", *cut)
    return {"kind": "meshes", "exterior": str(tmp_path / "exterior.obj"), "fracture": str(tmp_path / "cut.obj"),
            "separation": 1e-3}


def test_an_overhanging_cut_makes_the_two_halves(tmp_path):
    cf = coarse_from_meshes(_meshes(tmp_path, box([0, 0, 0], [1, 1, 1], (4, 4, 4)), _plane(0.5)))
    assert cf.n_components == 2
    assert cf.V.min(axis=0) == pytest.approx([0, 0, 0.5]) and cf.V.max(axis=0) == pytest.approx([1, 1, 0.5])
    assert any("trimmed to the object" in n for n in cf.notes)


def test_a_cut_half_outside_is_trimmed_and_extended_to_the_far_side(tmp_path):
    cut = _plane(0.43, -0.5, 0.6)  # leaves the box at x = 0 and stops inside at x = y = 0.6
    cf = coarse_from_meshes(_meshes(tmp_path, box([0, 0, 0], [1, 1, 1], (4, 4, 4)), cut))
    assert cf.n_components == 2
    assert cf.V.min(axis=0)[:2] == pytest.approx([0, 0], abs=1e-9)
    assert any("trimmed" in n for n in cf.notes) and cf.virtual.any()


def test_a_cut_that_misses_the_object_is_refused(tmp_path):
    inp = _meshes(tmp_path, box([0, 0, 0], [1, 1, 1], (4, 4, 4)), _plane(1.4))
    with pytest.raises(InputError, match=r"cut\.obj.*no part of the fracture surface lies inside the object"):
        coarse_from_meshes(inp)


def test_a_closed_cut_inside_the_object_is_refused_naming_its_faces(tmp_path):
    inp = _meshes(tmp_path, box([0, 0, 0], [1, 1, 1], (4, 4, 4)), box([0.3, 0.3, 0.3], [0.7, 0.7, 0.7]))
    with pytest.raises(InputError, match=r"cut\.obj.*encloses a piece that does not reach the object's surface "
                                         r"\(the piece inside faces 1, 2, 3"):
        coarse_from_meshes(inp)


def test_an_inside_out_exterior_is_turned_and_gives_the_same_pieces(tmp_path):
    BV, BF = box([0, 0, 0], [1, 1, 1], (4, 4, 4))
    cut = _plane(0.43, 0.0, 1.0)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    right = coarse_from_meshes(_meshes(tmp_path / "a", (BV, BF), cut))
    turned = coarse_from_meshes(_meshes(tmp_path / "b", (BV, BF[:, ::-1]), cut))
    assert any(f"{len(BF)} faces turned to face outward" in n for n in turned.notes)
    np.testing.assert_array_equal(turned.exterior_F, right.exterior_F)
    np.testing.assert_array_equal(turned.sides, right.sides)


def test_an_exterior_of_two_overlapping_solids_is_refused_naming_two_faces(tmp_path):
    """Two cubes that overlap (one surface crossing itself): one would be taken for a cavity of the other, and
    the object would hold no volume to cut."""
    AV, AF = box([0, 0, 0], [1, 1, 1], (3, 3, 3))
    BV, BF = box([0.5, 0.5, 0.5], [1.5, 1.5, 1.5], (3, 3, 3))
    with pytest.raises(InputError, match=r"input\.exterior \(.*\): the surface crosses or touches itself \(\d+ pairs "
                                         r"of faces, first faces \d+ and \d+, counted from 1\); expected the closed "
                                         r"surface of one solid"):
        coarse_from_meshes(_meshes(tmp_path, (np.r_[AV, BV], np.r_[AF, BF + len(AV)]), _plane(0.43, 0.0, 1.0)))


def test_a_hollow_exterior_keeps_its_cavity_inward():
    OV, OF = box([0, 0, 0], [1, 1, 1], (2, 2, 2))
    IV, IF = box([0.3, 0.3, 0.3], [0.7, 0.7, 0.7])
    V, F = np.r_[OV, IV], np.r_[OF[:, ::-1], IF + len(OV)]  # outer shell inward, cavity outward: both wrong
    F2, turned, conflict = orient_outward(V, F)
    assert conflict is None and turned == len(F)
    assert signed_volume(V, F2) == pytest.approx(1 - 0.4 ** 3)
    F3, turned, _ = orient_outward(V, F2)
    assert turned == 0 and np.array_equal(F3, F2)


def test_flat_triangles_of_a_boolean_made_exterior_are_removed_and_its_shape_kept(tmp_path):
    """CGAL's union of three boxes (a staircase) keeps corners at one place under two numbers and triangles
    without area between them; the cracks could not be traced across those. They go, the solid stays."""
    import cutgen
    from fracture.mesh.clean import flat_triangles, remove_flat_triangles
    from fracture.mesh.topology import unique_edges

    BV, BF = cutgen.exterior("stairs", np.random.default_rng(0))
    assert flat_triangles(BV, BF).sum() > 10
    V, F, removed = remove_flat_triangles(BV, BF)
    assert removed == flat_triangles(BV, BF).sum() and not flat_triangles(V, F).any()
    assert (unique_edges(F)[1] == 2).all()
    assert signed_volume(V, F) == pytest.approx(signed_volume(BV, BF), rel=1e-12)
    assert remove_flat_triangles(V, F)[2] == 0  # nothing more to do
    cf = coarse_from_meshes(_meshes(tmp_path, (BV, BF), _plane(0.5)))
    assert cf.n_components == 2 and any("without area removed" in n for n in cf.notes)


def test_an_incomplete_cut_in_a_staircase_is_extended_round_its_step(tmp_path):
    """An incomplete plane whose extension leaves the staircase across a step: each new boundary point
    goes where the sheet's plane meets the surface (B's closest point to a midpoint deep inside lay on
    another face, and the cut split nothing)."""
    import cutgen

    ext_kind, cut_kind, exterior, cut = cutgen.case(cutgen.EXTERIORS.index("stairs") + 6 * cutgen.CUTS.index("incomplete"))
    assert (ext_kind, cut_kind) == ("stairs", "incomplete")
    cf = coarse_from_meshes(_meshes(tmp_path, exterior, cut))
    assert cf.n_components == 2 and cf.virtual.any()
    assert (cf.sides[:, 0] != cf.sides[:, 1]).all()


def test_a_cut_that_splits_nothing_is_refused(tmp_path):
    """A disk through one arm of a ring: the ring stays one piece."""
    import cutgen

    BV, BF = cutgen.exterior("torus", np.random.default_rng(0))
    X, Z = np.meshgrid(np.linspace(0.55, 1.3, 9), np.linspace(-0.3, 1.3, 9), indexing="ij")
    cut = np.c_[X.ravel(), np.full(X.size, 0.5), Z.ravel()], grid_faces(9, 9)  # across the arm at x > 1/2
    with pytest.raises(InputError, match="the cut does not split the object anywhere"):
        coarse_from_meshes(_meshes(tmp_path, (BV, BF), cut))
