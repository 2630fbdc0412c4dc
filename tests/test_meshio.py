import numpy as np
import pytest

from fracture.errors import InputError
from fracture.io.meshes import check_triangle_mesh, read_mesh
from fracture.io.obj import write_obj
from fracture.mesh.primitives import box, cylinder
from fracture.mesh.topology import signed_volume


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
             ("nan.obj", "NaN"), ("points.obj", "no faces found; expected a triangle mesh"), ("open.obj", "closed surface")]
    for name, match in cases:
        with pytest.raises(InputError, match=match) as err:
            read_mesh(tmp_path / name, "input.exterior", closed=True)
        assert name in str(err.value) and "input.exterior" in str(err.value)


def test_a_closed_surface_whose_faces_are_not_joined_says_so(tmp_path):
    """A box whose faces each keep their own corners (written unwelded): its edges are all open, and the message
    says why."""
    from fracture.mesh.primitives import box

    V, F = box([0, 0, 0], [1, 1, 1])
    loose = V[F].reshape(-1, 3)  # every face its own three vertices
    lines = [f"v {x} {y} {z}" for x, y, z in loose] + [f"f {3 * k + 1} {3 * k + 2} {3 * k + 3}" for k in range(len(F))]
    (tmp_path / "loose.obj").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=rf"found {3 * len(F)} boundary edges and 0 edges shared by more than 2 "
                                         rf"triangles; {len(loose) - len(V)} vertices lie exactly where others do: the "
                                         r"faces are not joined there"):
        read_mesh(tmp_path / "loose.obj", "input.exterior", closed=True)


def test_check_triangle_mesh_errors():
    V = np.zeros((3, 3))
    with pytest.raises(InputError, match=r"face 2 refers to vertex 4 \(both counted from 1\), but there are 3 "
                                         r"vertices \(2 such faces\)"):
        check_triangle_mesh(V, [[0, 1, 2], [0, 1, 3], [-1, 1, 2]], "m")
    with pytest.raises(InputError, match=r"2 vertices have NaN or infinite coordinates \(first: vertex 2, counted"):
        check_triangle_mesh(np.array([[0, 0, 0], [np.nan, 0, 0], [0, np.inf, 0.0]]), [[0, 1, 2]], "m")
    with pytest.raises(InputError, match="repeat a vertex"):
        check_triangle_mesh(V, [[0, 1, 1]], "m")
    with pytest.raises(InputError, match=r"shape \(3, 2\)"):
        check_triangle_mesh(np.zeros((3, 2)), [[0, 1, 2]], "m")


def _write_ply_polygons(path, V, polys, binary):
    from plyfile import PlyData, PlyElement

    vert = np.array([tuple(v) for v in V], dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    face = np.empty(len(polys), dtype=[("vertex_indices", "O")])
    face["vertex_indices"] = [np.asarray(f, np.int32) for f in polys]
    PlyData([PlyElement.describe(vert, "vertex"), PlyElement.describe(face, "face")],
            text=not binary).write(str(path))


def _cube_polygons(mixed: bool):
    """A unit cube as six quads, or (mixed) three quads and six triangles, as Blender's PLY export keeps them."""
    V = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    if not mixed:
        return V, quads
    return V, quads[:3] + [t for q in quads[3:] for t in ([q[0], q[1], q[2]], [q[0], q[2], q[3]])]


@pytest.mark.parametrize("mixed", [False, True])
@pytest.mark.parametrize("binary", [False, True])
def test_ply_polygons_of_any_size_are_triangulated(tmp_path, mixed, binary):
    V, polys = _cube_polygons(mixed)
    _write_ply_polygons(tmp_path / "cube.ply", V, polys, binary)
    V2, F2 = read_mesh(tmp_path / "cube.ply", "input.exterior", closed=True)
    assert len(F2) == 12
    assert signed_volume(V2, F2) == pytest.approx(1.0)


def _write_stl(path, V, F, binary):
    T = V[F].astype(np.float32)
    N = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    if binary:
        rec = np.zeros(len(F), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
        rec["n"], rec["v"] = N, T
        path.write_bytes(b"\0" * 80 + np.uint32(len(F)).tobytes() + rec.tobytes())
    else:
        lines = ["solid cube"]
        for n, t in zip(N, T):
            lines += [f"facet normal {n[0]} {n[1]} {n[2]}", "outer loop"]
            lines += [f"vertex {x:.7g} {y:.7g} {z:.7g}" for x, y, z in t]
            lines += ["endloop", "endfacet"]
        path.write_text("\n".join(lines + ["endsolid cube"]) + "\n")


@pytest.mark.parametrize("binary", [False, True])
def test_stl_corners_are_merged_into_a_closed_surface(tmp_path, binary):
    V, F = box([0, 0, 0], [1, 2, 3], (2, 2, 2))
    _write_stl(tmp_path / "b.stl", V, F, binary)
    V2, F2 = read_mesh(tmp_path / "b.stl", "input.exterior", closed=True)
    assert len(V2) == len(V) and len(F2) == len(F)
    assert signed_volume(V2, F2) == pytest.approx(6.0)


def test_a_repeated_or_flat_triangle_is_named_from_one():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [1, 0, 0.0]])
    with pytest.raises(InputError, match=r"faces 1 and 3 \(counted from 1\) are the same triangle"):
        check_triangle_mesh(V, [[0, 1, 2], [1, 3, 2], [2, 0, 1]], "m")
    with pytest.raises(InputError, match=r"face 2 \(counted from 1\) has no area"):
        check_triangle_mesh(V, [[0, 1, 2], [0, 1, 3]], "m")  # corners on a line
    with pytest.raises(InputError, match=r"face 2 \(counted from 1\) has no area"):
        check_triangle_mesh(V, [[0, 1, 2], [1, 4, 2]], "m")  # two corners at one place


def test_an_unreadable_ply_names_its_file(tmp_path):
    (tmp_path / "bad.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nend_header\n\x00")
    with pytest.raises(InputError, match="bad.ply"):
        read_mesh(tmp_path / "bad.ply", "input.exterior")


@pytest.mark.parametrize("name, content, words", [
    ("garbage.obj", bytes(np.random.default_rng(5).integers(0, 256, 20000, dtype=np.uint8)), "no vertices found"),
    ("points.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no faces found"),
])
def test_a_file_with_no_mesh_in_it_says_so_in_words(tmp_path, name, content, words):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(InputError) as error:
        read_mesh(tmp_path / name, "input.fracture")
    assert f"input.fracture ({tmp_path / name}): {words}; expected a triangle mesh" in str(error.value)


def test_ply_written_in_one_piece_is_what_plyfile_writes_and_reads_back(tmp_path):
    """write_ply packs the face rows itself: the bytes are plyfile's own, and plyfile, Open3D and
    read_ply read the file back with every property."""
    import open3d as o3d
    from plyfile import PlyData, PlyElement

    from fracture.io.ply import read_ply, write_ply

    rng = np.random.default_rng(3)
    V = rng.random((40, 3))
    F = rng.integers(0, 40, (70, 3))
    vdata = {"psi": rng.random(40).astype(np.float32), "tag": rng.integers(0, 9, 40)}
    fdata = {"side_a": rng.integers(-1, 5, 70), "side_b": rng.integers(0, 250, 70).astype(np.uint8)}
    write_ply(tmp_path / "ours.ply", V, F, vdata, fdata)

    vrec = np.empty(40, [("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("psi", "<f4"), ("tag", "<i4")])
    for c, name in enumerate("xyz"):
        vrec[name] = V[:, c]
    vrec["psi"], vrec["tag"] = vdata["psi"], vdata["tag"]
    frec = np.empty(70, [("vertex_indices", "<i4", (3,)), ("side_a", "<i4"), ("side_b", "u1")])
    frec["vertex_indices"], frec["side_a"], frec["side_b"] = F, fdata["side_a"], fdata["side_b"]
    faces = PlyElement.describe(frec, "face", len_types={"vertex_indices": "u1"}, val_types={"vertex_indices": "i4"})
    with open(tmp_path / "plyfile.ply", "wb") as f:
        PlyData([PlyElement.describe(vrec, "vertex"), faces], text=False, byte_order="<").write(f)
    assert (tmp_path / "ours.ply").read_bytes() == (tmp_path / "plyfile.ply").read_bytes()

    V2, F2, vd, fd = read_ply(tmp_path / "ours.ply")
    assert np.array_equal(V2, V) and np.array_equal(F2, F)
    assert np.array_equal(vd["psi"], vdata["psi"]) and np.array_equal(vd["tag"], vdata["tag"])
    assert np.array_equal(fd["side_a"], fdata["side_a"]) and np.array_equal(fd["side_b"], fdata["side_b"])
    mesh = o3d.io.read_triangle_mesh(str(tmp_path / "ours.ply"))
    assert np.allclose(np.asarray(mesh.vertices), V) and np.array_equal(np.asarray(mesh.triangles), F)
