import numpy as np
import pytest

from fracture.errors import InputError
from fracture.meshio import check_triangle_mesh, read_mesh
from fracture.primitives import box, cylinder, write_obj
from fracture.topology import signed_volume


def test_box_is_closed_and_has_the_right_volume():
    V, F = box([0, 0, 0], [3, 1, 0.2], (6, 2, 1))
    check_triangle_mesh(V, F, "box", closed=True)
    assert signed_volume(V, F) == pytest.approx(0.6)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_cylinder_is_closed_and_has_the_right_volume(axis):
    V, F = cylinder(0.5, 3.0, 64, 5, axis=axis)
    check_triangle_mesh(V, F, "cylinder", closed=True)
    assert signed_volume(V, F) == pytest.approx(3.0 * 0.5 * 64 * 0.25 * np.sin(2 * np.pi / 64))
    assert np.ptp(V[:, axis]) == pytest.approx(3.0)


def test_read_mesh_round_trip(tmp_path):
    V, F = box([0, 0, 0], [1, 2, 3], (2, 2, 2))
    write_obj(tmp_path / "b.obj", V, F)
    V2, F2 = read_mesh(tmp_path / "b.obj", closed=True)
    np.testing.assert_allclose(V2, V, atol=1e-6)
    np.testing.assert_array_equal(F2, F)


def test_read_mesh_errors(tmp_path):
    (tmp_path / "empty.obj").write_text("")
    (tmp_path / "mesh.xyz").write_text("1 2 3\n")
    (tmp_path / "nan.obj").write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "points.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    (tmp_path / "open.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    cases = [("missing.obj", "not found"), ("empty.obj", "empty"), ("mesh.xyz", "unsupported mesh format"),
             ("nan.obj", "NaN"), ("points.obj", r"expected \(m, 3\) triangles"), ("open.obj", "closed surface")]
    for name, match in cases:
        with pytest.raises(InputError, match=match) as err:
            read_mesh(tmp_path / name, "input.exterior", closed=True)
        assert name in str(err.value) and "input.exterior" in str(err.value)


def test_check_triangle_mesh_errors():
    V = np.zeros((3, 3))
    with pytest.raises(InputError, match=r"span \[0, 3\]"):
        check_triangle_mesh(V, [[0, 1, 3]], "m")
    with pytest.raises(InputError, match="repeat a vertex"):
        check_triangle_mesh(V, [[0, 1, 1]], "m")
    with pytest.raises(InputError, match=r"shape \(3, 2\)"):
        check_triangle_mesh(np.zeros((3, 2)), [[0, 1, 2]], "m")
