"""Import of per-frame piece meshes (the Blender Cell Fracture sample) and its errors."""

import json
import shutil
from pathlib import Path

import igl
import numpy as np
import pytest

from conftest import SAMPLE, mesh_area as area
from fracture.pipeline import runner
from fracture.coarse.surface import SourceFrames, special_edges
from fracture.mesh.topology import closed_oriented, fan, signed_volume, unique_edges
from fracture.pipeline.config import load_config
from fracture.errors import InputError
from fracture.coarse.mesh_sequence import load_coarse_sequence, read_sequence



@pytest.fixture(scope="module")
def imported():
    return load_coarse_sequence(SAMPLE)



def test_sample_imports_into_eight_consistent_components(imported):
    cf, extra = imported
    assert cf.n_components == 8 and cf.n_frames == 40
    assert cf.names[0] == "source_cell" and cf.names[7] == "source_cell.007"
    # every fracture triangle separates two different components, stored once
    assert np.all(cf.sides[:, 0] != cf.sides[:, 1])
    key = np.sort(cf.F, axis=1)
    assert len(np.unique(key, axis=0)) == len(key)
    # the shared surface's area is half of what the pieces cover inside the object (their areas less B's)
    frame = read_sequence(SAMPLE)[0]
    pieces = sum(area(frame.V, fan([np.asarray(f) for f in polys])[0]) for polys in frame.polygons)
    assert area(cf.V, cf.F) == pytest.approx(0.5 * (pieces - 24.0), rel=0.03)
    # the pieces move rigidly: the rigid fit is exact up to the files' 6 decimals
    assert extra["rigid_residual"].max() < 1e-5 and cf.fit_residual.max() < 1e-5


def test_exterior_is_the_closed_cube_and_holds_the_cut_boundary(imported):
    cf, _ = imported
    BV, BF = cf.exterior_V, cf.exterior_F
    assert np.all(unique_edges(BF)[1] == 2)
    # the cube, its edges cut by less than a grid cell
    assert area(BV, BF) == pytest.approx(24.0, rel=0.02)
    assert signed_volume(BV, BF) == pytest.approx(8.0, rel=0.01)
    assert np.abs(BV).max(axis=0)[:2] == pytest.approx([1.0, 1.0], abs=1e-3)
    sp = special_edges(cf.F, len(cf.V))
    assert sp.boundary.any() and sp.nonmanifold.any()
    d2, _, _ = igl.point_mesh_squared_distance(cf.V[sp.boundary_vertices], BV, BF)
    assert np.sqrt(d2).max() < 1e-9  # boundary vertices are vertices of B
    interior = ~sp.boundary_vertices
    d2, _, _ = igl.point_mesh_squared_distance(cf.V[interior], BV, BF)
    assert np.sqrt(d2).min() > 1e-6
    # every fracture triangle lies between its two pieces: on both pieces' surfaces, within a grid cell
    frame = read_sequence(SAMPLE)[0]
    C = cf.V[cf.F].mean(axis=1)
    for p in range(8):
        PV, PF = frame.V, fan([np.asarray(f) for f in frame.polygons[p]])[0]
        mine = (cf.sides == p).any(axis=1)
        d = np.sqrt(igl.point_mesh_squared_distance(C[mine], PV, PF)[0])
        assert np.median(d) < 0.1 * 2.0 / 32 and d.max() < 2.0 / 32


def test_flood_fill_gives_one_exterior_patch_per_piece(imported):
    cf, _ = imported
    patches = cf.exterior_patches()
    assert patches.max() + 1 == 8
    for p in range(8):
        assert len(np.unique(cf.exterior_component[patches == p])) == 1


def test_fracture_happens_during_the_animation(imported):
    cf, _ = imported
    assert cf.face_fracture_time.min() > 0  # not at the rest pose
    assert np.all(cf.face_fracture_time < cf.n_frames)  # every cut opens (the pieces scatter)
    # before its fracture time, both sides of every vertex move together (faces grouped by their two sides,
    # which share the earliest fracture time of the group)
    pairs, group = np.unique(cf.sides, axis=0, return_inverse=True)
    for k, (a, b) in enumerate(pairs):
        faces = np.flatnonzero(group.ravel() == k)
        t = cf.face_fracture_time[faces].min()
        if t > 0:
            X = cf.V[np.unique(cf.F[faces])]
            gap = np.linalg.norm(cf.animation.deform(a, t - 1, X) - cf.animation.deform(b, t - 1, X), axis=1)
            assert gap.max() <= 1e-3 * np.linalg.norm(np.ptp(cf.exterior_V, axis=0)) + 1e-12


def test_animation_reproduces_the_files(imported):
    cf, _ = imported
    frames = read_sequence(SAMPLE)
    for p in (0, 5):
        vids = frames[0].piece_vertices(p)
        for t in (0, 20, 39):
            moved = cf.animation.deform(p, t, frames[0].V[vids])
            assert np.abs(moved - frames[t].V[vids]).max() < 1e-5
        F = cf.animation.gradient(p, 39, frames[0].V[vids[:3]])
        assert np.allclose(F @ F.transpose(0, 2, 1), np.eye(3), atol=1e-5)  # a rotation


def test_runner_coarse_stage(tmp_path):
    cfg_path = tmp_path / "user.yaml"
    cfg_path.write_text(f"input:\n  kind: mesh_sequence\n  path: {SAMPLE}\n")
    out = runner.run(load_config(cfg_path, ["grid.resolution=16"]), tmp_path / "run", until="coarse", progress=False)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["counts"] == {"components": 8, "coarse_fracture_triangles": manifest["counts"]["coarse_fracture_triangles"],
                                  "frames": 40}
    assert manifest["counts"]["coarse_fracture_triangles"] > 8
    assert any("slits and dents" in n for n in manifest["notes"])
    from fracture.io.ply import read_ply

    V, F, vdata, fdata = read_ply(out / "coarse/fracture_surface.ply")
    assert len(F) == manifest["counts"]["coarse_fracture_triangles"]
    assert np.all(fdata["side0"] != fdata["side1"])


# --- bad input: each case names the file (and frame, piece) and writes nothing ---

def _copy_sample(tmp_path) -> Path:
    d = tmp_path / "seq"
    shutil.copytree(SAMPLE, d)
    return d


def _edit(path: Path, fn) -> None:
    lines = path.read_text().splitlines()
    path.write_text("\n".join(fn(lines)) + "\n")


def _object_lines(lines, name):
    start = lines.index(f"o {name}")
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("o ")), len(lines))
    return start, end


def _shift_piece(lines, name, delta):
    start, end = _object_lines(lines, name)
    out = list(lines)
    for i in range(start, end):
        if out[i].startswith("v "):
            x, y, z = map(float, out[i].split()[1:4])
            out[i] = f"v {x + delta[0]:.6f} {y + delta[1]:.6f} {z + delta[2]:.6f}"
    return out


def _scaled(lines, scale):
    """Every vertex's coordinates times ``scale`` (0 rounds an object to a point)."""
    out = []
    for line in lines:
        if line.startswith("v "):
            xyz = np.array(line.split()[1:4], float) * scale
            line = "v " + " ".join(f"{c:.6f}" for c in xyz)
        out.append(line)
    return out


def _drop_face(lines, name):
    start, end = _object_lines(lines, name)
    face = next(i for i in range(start, end) if lines[i].startswith("f "))
    return lines[:face] + lines[face + 1:]


def _rename(lines, old, new):
    return [f"o {new}" if l == f"o {old}" else l for l in lines]


def _set_nan(lines, name):
    start, end = _object_lines(lines, name)
    i = next(i for i in range(start, end) if lines[i].startswith("v "))
    return lines[:i] + ["v nan 0.0 1.0"] + lines[i + 1:]


def _twice(lines, name):
    """The frame with piece ``name`` written again at its end, as ``name + "_dup"`` (its faces renumbered)."""
    start, end = _object_lines(lines, name)
    first = 1 + sum(l.startswith("v ") for l in lines[:start])
    base = sum(l.startswith("v ") for l in lines)
    copy = [f"o {name}_dup"] + [("f " + " ".join(str(int(i.split("/")[0]) - first + 1 + base) for i in l.split()[1:]))
                                if l.startswith("f ") else l for l in lines[start + 1:end]]
    return lines + copy


def _piece_uses_a_new_vertex(lines, name):
    """A vertex added at the end, which the piece's first face uses instead of its first corner."""
    start, end = _object_lines(lines, name)
    lines = list(lines)
    count = sum(line.startswith("v ") for line in lines)
    face = next(i for i in range(start, end) if lines[i].startswith("f "))
    parts = lines[face].split()
    lines[face] = " ".join(["f", str(count + 1), *parts[2:]])
    return lines + ["v 0 0 0"]


def _remove_object(lines, name):
    start, end = _object_lines(lines, name)
    return lines[:start] + lines[end:]


@pytest.mark.parametrize("case, frames, edit, words", [
    ("vertex count", [5], lambda l: l + ["v 0 0 0"], ["frame_0005.obj (frame 5)", "207 vertices", "206",
                                                      "vertices no piece uses"]),
    ("piece vertex count", [5], lambda l: _piece_uses_a_new_vertex(l, "source_cell.003"),
     ["frame_0005.obj (frame 5)", "piece 'source_cell.003' has", "vertices, but", "in the rest pose"]),
    ("renamed piece", [3], lambda l: _rename(l, "source_cell.004", "chunk"), ["frame_0003.obj (frame 3)", "'source_cell.004'", "missing"]),
    ("missing piece", [2], lambda l: _remove_object(l, "source_cell.007"), ["frame_0002.obj", "'source_cell.007'", "missing"]),
    ("nan", [4], lambda l: _set_nan(l, "source_cell.003"), ["frame_0004.obj", "'source_cell.003'", "NaN"]),
    ("empty file", [6], lambda l: [], ["frame_0006.obj", "empty"]),
    ("moved piece", [1], lambda l: _shift_piece(l, "source_cell.005", (0.05, 0.05, 0.05)), ["frame_0001.obj", "'source_cell.005'", "must tile"]),
    ("piece twice", range(1, 41), lambda l: _twice(l, "source_cell.002"),
     ["frame_0001.obj", "'source_cell.002' and 'source_cell.002_dup' have the same", "vertices",
      "(is a piece exported twice?)"]),
    ("duplicate name", [1, 2], lambda l: _rename(l, "source_cell.004", "source_cell.003"),
     ["frame_0001.obj", "two pieces are named 'source_cell.003'"]),
    ("vertex 0", [1], lambda l: [("f 0 " + " ".join(x.split()[2:])) if x.startswith("f ") else x for x in l],
     ["frame_0001.obj", "a face uses vertex 0; OBJ counts its vertices from 1"]),
    ("rounded to a point", range(1, 41), lambda l: _scaled(l, (0.0, 0.0, 0.0)),
     ["frame_0001.obj", "the pieces' vertices all lie at one point"]),
    ("flat", range(1, 41), lambda l: _scaled(l, (1.0, 1.0, 0.0)), ["frame_0001.obj", "all lie in one plane"]),
])
def test_bad_sequences_are_rejected_with_their_place(tmp_path, case, frames, edit, words):
    d = _copy_sample(tmp_path)
    for t in frames:
        path = d / f"frame_{t:04d}.obj"
        if case == "empty file":
            path.write_text("")
        else:
            _edit(path, edit)
    with pytest.raises(InputError) as err:
        load_coarse_sequence(d)
    for w in words:
        assert w in str(err.value), str(err.value)
    # through the runner: nothing is written
    cfg_path = tmp_path / "c.yaml"
    cfg_path.write_text(f"input: {{kind: mesh_sequence, path: {d}}}\n")
    with pytest.raises(InputError):
        runner.run(load_config(cfg_path), tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def _pieces_reversed(lines):
    """The frame's objects written in the reverse order, each with its vertices (indices renumbered)."""
    starts = [i for i, l in enumerate(lines) if l.startswith("o ")] + [len(lines)]
    blocks = [lines[a:b] for a, b in zip(starts, starts[1:])]
    out, base, first = [], 0, 1
    firsts = []
    for b in blocks:
        firsts.append(first)
        first += sum(l.startswith("v ") for l in b)
    for b, f0 in reversed(list(zip(blocks, firsts))):
        for l in b:
            out.append("f " + " ".join(str(int(i) - f0 + 1 + base) for i in l.split()[1:]) if l.startswith("f ") else l)
        base += sum(l.startswith("v ") for l in b)
    return out


def test_pieces_written_in_another_order_are_matched_by_name(tmp_path, imported):
    d = _copy_sample(tmp_path)
    for t in (2, 17, 40):
        _edit(d / f"frame_{t:04d}.obj", _pieces_reversed)
    frames = read_sequence(d)
    original = read_sequence(SAMPLE)
    for t in (1, 16, 39):
        assert frames[t].names == original[t].names
        assert np.array_equal(frames[t].V, original[t].V)
        assert all(np.array_equal(a, b) for pa, pb in zip(frames[t].polygons, original[t].polygons)
                   for a, b in zip(pa, pb))
    cf, _ = load_coarse_sequence(d)
    assert np.allclose(cf.animation.deform(5, 39, cf.V[:4]), imported[0].animation.deform(5, 39, cf.V[:4]))


def connected_components(F) -> int:
    """How many parts of triangles joined by shared vertices ``F`` has."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components as parts

    n = int(F.max()) + 1
    A = sp.coo_matrix((np.ones(F.size), (np.repeat(np.arange(len(F)), 3), F.ravel())), shape=(len(F), n)).tocsr()
    return parts(A @ A.T, directed=False)[0]


def _plank_of_boxes(cuts, size, turn):
    """Boxes side by side along x (cut at ``cuts``) that tile a plank of ``size``, turned by ``turn``: one vertex
    array, per box six outward quads."""
    from scipy.spatial.transform import Rotation

    xs = [0.0, *cuts, size[0]]
    quads = np.array([[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]])[:, ::-1]
    V, polygons = [], []
    for a, b in zip(xs, xs[1:]):
        corners = np.array([[x, y, z] for x in (a, b) for y in (0.0, size[1]) for z in (0.0, size[2])])
        polygons.append([q + 8 * len(polygons) for q in quads])
        V.append(corners)
    return Rotation.from_euler("xyz", turn, degrees=True).apply(np.concatenate(V)), polygons


def test_a_thin_plank_turned_any_way_keeps_every_piece():
    """A plank 40 times longer than thick, turned: the import's grid takes enough cells across its thickness
    (at 32 along its length it had less than one, and lost pieces); every piece is kept and B is its box."""
    from fields.grid import thinnest_extent
    from fracture.coarse.tiling import label_tiling

    size = (6.0, 0.8, 0.15)
    V, polygons = _plank_of_boxes([1.5, 1.7, 4.0], size, (25.0, 40.0, 10.0))
    assert thinnest_extent(V) == pytest.approx(0.15)
    t = label_tiling(V, polygons, ["a", "b", "c", "d"])
    assert list(t.kept) == [0, 1, 2, 3] and not t.notes
    assert closed_oriented(t.exterior_F)
    assert signed_volume(t.V, t.exterior_F) == pytest.approx(np.prod(size), rel=0.02)



def test_a_ground_a_ball_and_a_plane_exported_with_the_pieces_are_left_out():
    """A Blender scene exported whole: the fractured plank's four pieces, a ground slab below it, a ball (a
    box) thrown at it and a ground plane it rests on, written twice. The slab and the ball touch no piece, the
    planes are flat: all four are left out with notes, and the import is the one of the pieces alone (the slab's 20
    units made the grid's cells three times coarser, and it became a piece)."""
    from fracture.coarse.tiling import label_tiling

    size = (6.0, 0.8, 0.5)
    V, polygons = _plank_of_boxes([1.5, 1.7, 4.0], size, (0.0, 0.0, 0.0))
    alone = label_tiling(V, polygons, ["a", "b", "c", "d"])
    ground, _ = _plank_of_boxes([], (20.0, 20.0, 0.2), (0.0, 0.0, 0.0))
    ball, _ = _plank_of_boxes([], (0.3, 0.3, 0.3), (0.0, 0.0, 0.0))
    extra = [ground + (-7.0, -10.0, -1.2), ball + (3.0, 2.0, 0.1)]  # 1 and 1.2 from the plank
    plane = np.array([[-10.0, -10.0, 0.0], [10.0, -10.0, 0.0], [10.0, 10.0, 0.0], [-10.0, 10.0, 0.0]])  # under it
    X = np.concatenate([V, *extra, plane, plane])  # the plane twice: left out, not refused as a piece twice
    P = polygons + [[q + len(V) + 8 * k for q in polygons[0]] for k in range(2)]  # the first box's quads
    P += [[np.arange(4) + len(X) - 8], [np.arange(4) + len(X) - 4]]
    t = label_tiling(X, P, ["a", "b", "c", "d", "Ground", "Ball", "Plane", "Plane.001"])
    assert list(t.kept) == [0, 1, 2, 3]
    assert t.notes[0] == "left out flat pieces (a ground plane?): not solids: 'Plane', 'Plane.001'"
    assert t.notes[1].startswith("left out pieces that touch no other piece") and "'Ground', 'Ball'" in t.notes[1]
    assert t.notes[2:] == alone.notes and t.cells == alone.cells
    np.testing.assert_array_equal(t.exterior_F, alone.exterior_F)
    np.testing.assert_array_equal(t.sides, alone.sides)
    assert signed_volume(t.V, t.exterior_F) == pytest.approx(np.prod(size), rel=0.02)


def test_the_unfractured_object_exported_with_its_pieces_is_left_out(monkeypatch):
    """The plank's four pieces and the plank itself (Cell Fracture hides the object it fractured; an export
    of the whole scene writes it): the plank is left out with a note. Were it not found so, the overlap
    says what it is (it was "pieces 'a' and 'Plank' overlap ... (is a piece moved?)")."""
    import fracture.coarse.tiling as tiling

    size = (6.0, 0.8, 0.5)
    V, polygons = _plank_of_boxes([1.5, 1.7, 4.0], size, (15.0, 0.0, 30.0))
    whole, _ = _plank_of_boxes([], size, (15.0, 0.0, 30.0))
    X = np.concatenate([V, whole])
    P = polygons + [[q + len(V) for q in polygons[0]]]
    names = ["a", "b", "c", "d", "Plank"]
    t = tiling.label_tiling(X, P, names)
    assert list(t.kept) == [0, 1, 2, 3]
    assert t.notes[0] == ("left out pieces that hold the others (the unfractured object, exported with its "
                          "pieces?): 'Plank'")
    monkeypatch.setattr(tiling, "holding_the_rest", lambda pieces: np.zeros(len(pieces), bool))
    with pytest.raises(InputError, match="piece 'Plank' holds the other pieces .* is the unfractured object "
                                         "exported with its pieces"):
        tiling.label_tiling(X, P, names)

def test_slits_left_by_cell_fractures_margin_are_closed_flush_with_the_surface():
    """Cell Fracture's margin shrinks every piece from its neighbours: eight boxes tiling a cube of side 2 leave
    slits 0.02 wide (a third of a cell of the import's grid), turned. The import closes them: B is the cube, without a
    groove along the cracks (it dipped into the slits' mouths, and its creases crossed the refined cracks'
    traces), and the cracks run in the slits' middles."""
    from scipy.spatial.transform import Rotation

    from fracture.coarse.tiling import label_tiling

    m = 0.01
    quads = np.array([[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]])[:, ::-1]
    V, polygons = [], []
    for lo in np.ndindex(2, 2, 2):
        a = np.array(lo) * 1.0 - 1.0 + np.array(lo) * m  # the box's inner faces drawn back by the margin
        b = a + 1.0 - m
        corners = np.array([[x, y, z] for x in (a[0], b[0]) for y in (a[1], b[1]) for z in (a[2], b[2])])
        polygons.append([q + 8 * len(polygons) for q in quads])
        V.append(corners)
    turn = Rotation.from_euler("xyz", (20.0, 35.0, 10.0), degrees=True)
    t = label_tiling(turn.apply(np.concatenate(V)), polygons, [f"p{k}" for k in range(8)])
    t.V = turn.inv().apply(t.V)  # measured in the cube's frame
    assert list(t.kept) == list(range(8))
    assert closed_oriented(t.exterior_F)
    assert connected_components(t.exterior_F) == 1  # no bubble of B left in a slit
    assert signed_volume(t.V, t.exterior_F) == pytest.approx(8.0, rel=0.01)
    assert area(t.V, t.exterior_F) == pytest.approx(24.0, rel=0.03)  # no groove's walls (the grid bevels the edges)
    # no groove: away from the cube's edges (which the grid bevels) B's points lie on its faces, where slits
    # the width of the margin met them (a groove along a crack there reached 0.02-0.04 deep)
    P = t.V[np.unique(t.exterior_F)]
    faces = np.sort(np.abs(P), axis=1)[:, 1] < 1.0 - 0.2
    assert faces.sum() > 1000
    depth = 1.0 - np.abs(P[faces]).max(axis=1)
    assert depth.max() < 0.3 * m, (np.round(P[faces][np.argsort(-depth)[:8]], 3).tolist(), np.sort(depth)[-20:])
    # the sheets lie in the slits (x, y or z within m of 0), but where three or four pieces meet and the
    # sheets turn from one slit into another (within a cell and a half: the grid's cell is 0.1 here)
    off = np.abs(t.V[np.unique(t.fracture_F)]).min(axis=1)
    assert np.median(off) <= m and off.max() <= 0.15


def test_the_rounding_of_the_files_is_found():
    from fracture.coarse.mesh_sequence import coordinate_quantum

    V = np.random.default_rng(0).random((500, 3)) * 0.03
    assert coordinate_quantum(np.round(V, 6)) == 1e-6  # a text file's %.6f
    assert coordinate_quantum(np.round(V, 6).astype(np.float32).astype(float)) == 1e-6  # ... read as singles
    assert coordinate_quantum(V) == 0.0  # exact doubles
    far = (V + 1000.0).astype(np.float32).astype(float)  # singles far from the origin (a USD's points)
    assert coordinate_quantum(far) == np.spacing(np.float32(1000.03))


def test_a_small_object_written_with_six_decimals_moves_rigidly(tmp_path):
    """The sample a hundred times smaller (3.5 cm across), written with Blender's 6 decimals: the rounding is
    5e-7, more than the rigid test's 1e-5 of the diagonal, and every piece was fitted with a lattice."""
    d = tmp_path / "small"
    d.mkdir()
    for path in sorted(SAMPLE.glob("*.obj"))[:10]:
        lines = [f"v {' '.join(f'{0.01 * float(x):.6f}' for x in l.split()[1:4])}" if l.startswith("v ") else l
                 for l in path.read_text().splitlines()]
        (d / path.name).write_text("\n".join(lines) + "\n")
    cf, extra = load_coarse_sequence(d)
    assert not any("do not move rigidly" in n for n in cf.notes), cf.notes
    assert extra["rigid_residual"].max() < 5e-6


def test_a_narrow_slit_between_pieces_is_filled_and_noted(tmp_path):
    d = _copy_sample(tmp_path)
    # move one corner piece away from its neighbours along the cube's diagonal
    _edit(d / "frame_0001.obj", lambda l: _shift_piece(l, "source_cell", (-0.01, -0.01, -0.01)))
    cf, _ = load_coarse_sequence(d)
    assert cf.n_components == 8
    assert any("the widest: between pieces 'source_cell' and" in n and "wide on average" in n
               for n in cf.notes), cf.notes
    assert signed_volume(cf.exterior_V, cf.exterior_F) == pytest.approx(8.0, rel=0.01)


def test_a_wide_gap_between_pieces_stays_a_gap(tmp_path):
    d = _copy_sample(tmp_path)
    _edit(d / "frame_0001.obj", lambda l: _shift_piece(l, "source_cell", (-0.1, -0.1, -0.1)))
    cf, _ = load_coarse_sequence(d)
    assert cf.n_components == 8
    # the corner piece is apart: B runs around it, through the gap (whose walls add to its area)
    assert np.all(unique_edges(cf.exterior_F)[1] == 2)
    assert cf.exterior_V.min(axis=0)[:2] == pytest.approx([-1.1, -1.1], abs=1e-3)
    assert area(cf.exterior_V, cf.exterior_F) > 24.0 + 2.0


def test_a_tiny_gap_or_overlap_is_accepted(tmp_path):
    d = _copy_sample(tmp_path)
    _edit(d / "frame_0001.obj", lambda l: _shift_piece(l, "source_cell.006", (0.0015, 0.0, 0.0)))
    cf, _ = load_coarse_sequence(d)
    assert cf.n_components == 8 and np.all(unique_edges(cf.exterior_F)[1] == 2)


def test_an_open_piece_is_taken_by_its_winding_number_and_noted(tmp_path):
    d = _copy_sample(tmp_path)
    for t in range(1, 41):
        _edit(d / f"frame_{t:04d}.obj", lambda l: _drop_face(l, "source_cell.002"))
    cf, _ = load_coarse_sequence(d)
    assert cf.n_components == 8
    assert any("'source_cell.002' is not a closed surface" in n for n in cf.notes)


def _turn_faces(lines, name, every=1):
    """Every ``every``-th face of piece ``name`` written in the reverse order of its corners."""
    start, end = _object_lines(lines, name)
    out, k = list(lines), 0
    for i in range(start, end):
        if out[i].startswith("f "):
            if k % every == 0:
                out[i] = "f " + " ".join(reversed(out[i].split()[1:]))
            k += 1
    return out


def test_pieces_exported_inside_out_or_with_faces_turned_import_as_the_sample(tmp_path, imported):
    """A piece written inside out (as some exporters write a piece whose scale is negative), and one with
    every third face turned: their insides (winding numbers) would be -1 and about 0, and the piece lost or
    cut down; they are turned outward, with a note, and the object imports as the sample does."""
    d = _copy_sample(tmp_path)
    for t in range(1, 41):
        _edit(d / f"frame_{t:04d}.obj", lambda l: _turn_faces(_turn_faces(l, "source_cell.002"), "source_cell.005", 3))
    cf, _ = load_coarse_sequence(d)
    ref = imported[0]
    assert cf.n_components == 8
    # the same surfaces within the turned n-gons' other fans (a reversed polygon is fanned from another corner)
    assert area(cf.exterior_V, cf.exterior_F) == pytest.approx(area(ref.exterior_V, ref.exterior_F), rel=1e-4)
    assert area(cf.V, cf.F) == pytest.approx(area(ref.V, ref.F), rel=1e-3)
    for c in range(8):  # every piece keeps its part of B
        mine, theirs = cf.exterior_component == c, ref.exterior_component == c
        assert area(cf.exterior_V, cf.exterior_F[mine]) == pytest.approx(
            area(ref.exterior_V, ref.exterior_F[theirs]), rel=1e-3)
    assert [n for n in cf.notes if "turned the faces" in n] == [
        "turned the faces of pieces exported inside out or with faces facing in (their insides are taken from "
        "their faces' orientation): 'source_cell.002', 'source_cell.005'"]
    assert not any("turned" in n for n in ref.notes)


def test_outward_turns_inverted_parts_and_keeps_a_cavity():
    from fracture.coarse.tiling import outward
    from fracture.mesh.primitives import box

    V1, F1 = box(np.zeros(3), np.ones(3))
    V2, F2 = box(np.full(3, 0.25), np.full(3, 0.75))  # a cavity: its faces face in, into the hole
    V = np.concatenate([V1, V2])
    hollow = np.concatenate([F1, F2[:, ::-1] + len(V1)])
    G, changed = outward(V, hollow)
    assert not changed and np.array_equal(G, hollow)
    assert signed_volume(V, G) == pytest.approx(1.0 - 0.125)
    G, changed = outward(V, hollow[:, ::-1])  # inside out: both turn
    assert changed and signed_volume(V, G) == pytest.approx(1.0 - 0.125) and closed_oriented(G)
    V3, F3 = box(np.full(3, 0.8), np.full(3, 1.3))  # a part overlapping another (Suzanne's eyes): kept
    eye = np.concatenate([F1, F3 + len(V1)])
    G, changed = outward(np.concatenate([V1, V3]), eye)
    assert not changed
    G, changed = outward(np.concatenate([V1, V3]), np.concatenate([F1, F3[:, ::-1] + len(V1)]))
    assert changed and np.array_equal(G, eye)
    opened = F1[2:, ::-1]  # open (a side missing), facing in: no inside to tell by, kept as it is
    G, changed = outward(V1, opened)
    assert not changed
    split = V1[F1].reshape(-1, 3)  # every face with corners of its own, as Cell Fracture writes some edges
    G, changed = outward(split, np.arange(len(split)).reshape(-1, 3)[:, ::-1])
    assert changed and signed_volume(split, G) == pytest.approx(1.0)
    turned = F1.copy()
    turned[::2] = turned[::2, ::-1]
    G, changed = outward(V1, turned)
    assert changed and np.array_equal(G, F1)


def test_an_object_far_from_the_origin_imports_as_it_does_at_the_origin(tmp_path, imported):
    """The sample a million units away (written with six decimals, as Blender writes): its pieces' insides
    (winding numbers) are taken about their own centres, and it imports as the sample does."""
    d = _copy_sample(tmp_path)
    away = np.array([1e6, -5e5, 0.0])
    for t in range(9, 41):  # eight frames are enough: the rest pose makes B and the cracks
        (d / f"frame_{t:04d}.obj").unlink()
    for t in range(1, 9):
        _edit(d / f"frame_{t:04d}.obj", lambda l: [
            "v " + " ".join(f"{c:.6f}" for c in np.array(x.split()[1:4], float) + away) if x.startswith("v ") else x
            for x in l])
    cf, _ = load_coarse_sequence(d)
    ref = imported[0]
    assert cf.n_components == 8
    assert np.allclose(cf.exterior_V.mean(axis=0) - away, ref.exterior_V.mean(axis=0), atol=1e-3)
    assert area(cf.exterior_V, cf.exterior_F) == pytest.approx(area(ref.exterior_V, ref.exterior_F), rel=1e-3)
    assert area(cf.V, cf.F) == pytest.approx(area(ref.V, ref.F), rel=1e-3)


def test_missing_directory_and_no_frames(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_sequence(tmp_path / "nope")
    with pytest.raises(InputError, match="no frame files match"):
        read_sequence(tmp_path)
    (tmp_path / "frac.0001.ply").write_text("ply\n")  # a PLY sequence read with the default glob: said how
    with pytest.raises(InputError, match=r"no frame files match '\*\.obj'; it holds \.ply files: set input\.glob: '\*\.ply'"):
        read_sequence(tmp_path)
    (tmp_path / "frac.0001.ply").rename(tmp_path / "FRAC.0001.OBJ")  # the suffix as the files spell it
    with pytest.raises(InputError, match=r"no frame files match '\*\.obj'; it holds \.OBJ files: set input\.glob: '\*\.OBJ'"):
        read_sequence(tmp_path)


def test_houdini_names_its_preroll_frames_below_zero_and_may_start_a_file_with_a_bom(tmp_path):
    """frac.-3.obj ... frac.36.obj (a pre-roll from frame -3) in order; cube-0007.obj is frame 7 (a hyphen
    between name and number); a UTF-8 byte order mark does not rename the first piece."""
    from fracture.coarse.mesh_sequence import frame_number

    assert [frame_number(Path(n)) for n in ("frac.-3.obj", "frac_-12.obj", "cube-0007.obj", "frame12.obj")] == [
        -3, -12, 7, 12]
    d = _renamed_sample(tmp_path, lambda t: f"frac.{t - 5}.obj")
    for path in d.glob("*.obj"):
        path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    frames = read_sequence(d)
    want = read_sequence(SAMPLE)
    assert [f.path.name for f in frames] == [f"frac.{t - 5}.obj" for t in range(1, 41)]
    assert frames[0].names == want[0].names and np.array_equal(frames[7].V, want[7].V)


def _renamed_sample(tmp_path, name_of):
    """The sample's frames copied under new names ``name_of(t)`` (t from 1)."""
    d = tmp_path / "renamed"
    d.mkdir()
    for t in range(1, 41):
        shutil.copy(SAMPLE / f"frame_{t:04d}.obj", d / name_of(t))
    return d



def test_one_object_holding_every_piece_is_split_into_its_parts(tmp_path):
    """The sample's frames with every piece written into one object (an exporter asked to merge the
    fracture): the object's connected parts are the pieces, named after it, in the order of their first
    vertex; the import is the one of the pieces written apart."""
    d = _copy_sample(tmp_path)
    for path in sorted(d.glob("*.obj")):
        _edit(path, lambda lines: ["o Fractured"] + [l for l in lines if not l.startswith("o ")])
    cf, _ = load_coarse_sequence(d)
    want, _ = load_coarse_sequence(SAMPLE)
    assert cf.names == [f"Fractured_{i:03d}" for i in range(8)]
    assert cf.n_components == want.n_components == 8
    np.testing.assert_array_equal(cf.F, want.F)
    np.testing.assert_allclose(cf.V, want.V)

def test_frames_are_ordered_by_their_number_not_their_text(tmp_path):
    d = _renamed_sample(tmp_path, lambda t: f"frame{t}.obj")  # Blender's exporter: frame1 ... frame40
    frames = read_sequence(d)
    want = read_sequence(SAMPLE)
    assert [f.path.name for f in frames] == [f"frame{t}.obj" for t in range(1, 41)]
    for a, b in zip(frames, want):
        assert np.array_equal(a.V, b.V)


@pytest.mark.parametrize("drop, rename, words", [
    ([7], {}, ["frame 7 missing between frame6.obj and frame8.obj"]),
    ([7, 8], {}, ["frame 7, 8 missing"]),
    (list(range(7, 30)), {}, ["frames 7 to 29 missing (23 frames) between frame6.obj and frame30.obj"]),
    ([], {12: "frame_12.obj"}, ["frame12.obj and frame_12.obj are both frame 12"]),
    ([], {5: "rest.obj"}, ["rest.obj", "no frame number"]),
])
def test_a_missing_duplicate_or_unnumbered_frame_is_named(tmp_path, drop, rename, words):
    d = _renamed_sample(tmp_path, lambda t: f"frame{t}.obj")
    for t in drop:
        (d / f"frame{t}.obj").unlink()
    for t, new in rename.items():
        shutil.copy(d / f"frame{t}.obj", d / new)
        if not new.startswith("frame_"):
            (d / f"frame{t}.obj").unlink()
    with pytest.raises(InputError) as err:
        read_sequence(d)
    for w in words:
        assert w in str(err.value), str(err.value)


def test_the_frame_numbers_of_the_files_are_kept(tmp_path):
    """A sequence numbered from 10 every other frame: the coarse fracture says so, for the outputs."""
    d = tmp_path / "seq"
    d.mkdir()
    for t, path in enumerate(sorted(SAMPLE.glob("*.obj"))[:6]):
        shutil.copy(path, d / f"shot{10 + 2 * t}.obj")
    cf, _ = load_coarse_sequence(d)
    assert (cf.source.first_frame, cf.source.frame_step, cf.source.fps, cf.source.meters_per_unit) == (
        10, 2, None, None)
    assert cf.source.file_numbers(3) == [10, 12, 14]  # the output frames' files are numbered so
    # numbers that are not whole (USD time codes half a frame apart) or below 0: the files from 1
    assert SourceFrames(first_frame=1.0, frame_step=0.5).file_numbers(3) == [1, 2, 3]
    assert SourceFrames(first_frame=-2.0).file_numbers(2) == [1, 2]


def test_frames_exported_every_other_frame_are_accepted(tmp_path):
    d = _renamed_sample(tmp_path, lambda t: f"frame{2 * t - 1}.obj")
    assert len(read_sequence(d)) == 40


def _shells(lo, hi, cut_axis, cut_side):
    """Two open shells of a box, each with vertices of its own: its face on
    ``cut_axis``/``cut_side`` (the cut face, split into two triangles) and the other five."""
    from fracture.mesh.primitives import box

    V, F = box(lo, hi)
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    cut = (np.abs(n[:, cut_axis]) > 0) & (np.sign(n[:, cut_axis]) == (1 if cut_side else -1))
    out = []
    for sel in (~cut, cut):
        ids, local = np.unique(F[sel], return_inverse=True)
        out.append((V[ids], local.reshape(-1, 3)))
    return out


def _polys(parts):
    V, polys, offset = [], [], 0
    for P, F in parts:
        V.append(P)
        polys += [f + offset for f in F]
        offset += len(P)
    return np.concatenate(V), polys


def test_open_shells_of_one_piece_are_joined_and_neighbours_stay_apart():
    from fracture.coarse.mesh_sequence import join_open_shells
    from fracture.mesh.primitives import box

    # a box cut in two: four shells on one loop pair up by file order (A's outer faces and
    # its cut face, then B's), not A's outer faces with B's
    A = _shells([0, 0, 0], [1, 1, 1], 0, 1)
    B = _shells([1, 0, 0], [2, 1, 1], 0, 0)
    V, polys = _polys(A + B)
    joined = join_open_shells(V, polys, np.repeat(np.arange(4), [10, 2, 10, 2]))
    assert joined.tolist() == [0] * 12 + [2] * 12
    # a closed neighbour touching the shells' loop stays a piece of its own
    V, polys = _polys(A + [box([1, 0, 0], [2, 1, 1])])
    joined = join_open_shells(V, polys, np.repeat(np.arange(3), [10, 2, 12]))
    assert joined.tolist() == [0] * 12 + [2] * 12
    # the order of the labels does not matter, only where the vertices are in the file
    V, polys = _polys(A + B)
    joined = join_open_shells(V, polys, np.repeat([0, 2, 1, 3], [10, 2, 10, 2]))
    assert joined.tolist() == [0] * 12 + [1] * 12


def test_a_ply_of_split_shells_reads_as_its_pieces(tmp_path):
    from fracture.coarse.mesh_sequence import read_frame
    from fracture.io.ply import write_ply

    V, polys = _polys(_shells([0, 0, 0], [1, 1, 1], 0, 1) + _shells([1, 0, 0], [2, 1, 1], 0, 0))
    write_ply(tmp_path / "f.ply", V, np.array(polys))
    frame = read_frame(tmp_path / "f.ply")
    assert frame.names == ["piece_000", "piece_001"]
    assert [len(p) for p in frame.polygons] == [12, 12]


@pytest.mark.parametrize("scale", [2.0 ** -14, 2.0 ** 14])
def test_the_coarse_cut_does_not_depend_on_the_unit(tmp_path, scale):
    """The sample sixteen thousand times smaller and larger, by a power of two (every coordinate scaled
    exactly): the same coarse fracture surface, scaled. Its sheets were coarsened with the simplifier's
    absolute tolerances: at 2^-14 it kept 10,864 triangles against 6,192. (Scaled by 3 or 1e-4, the points'
    last bits differ and the collapse takes another path: 7,700-9,200 triangles.)"""
    def scaled(line: str) -> str:
        if not line.startswith("v "):
            return line
        return "v " + " ".join(repr(scale * float(x)) for x in line.split()[1:4])

    frames = sorted(SAMPLE.glob("*.obj"))[:5]
    for d, step in ((tmp_path / "one", lambda l: l), (tmp_path / "scaled", scaled)):
        d.mkdir()
        for path in frames:
            (d / path.name).write_text("\n".join(map(step, path.read_text().splitlines())) + "\n")
    one, _ = load_coarse_sequence(tmp_path / "one")
    other, _ = load_coarse_sequence(tmp_path / "scaled")
    assert len(other.F) == len(one.F) and (other.F == one.F).all()
    assert np.abs(other.V / scale - one.V).max() <= 1e-12 * np.ptp(one.V)


def test_an_overlap_of_a_whole_piece_is_said_to_be_a_piece_exported_twice():
    """Twins that differ in a vertex pass the check of equal vertices; the labels' overlap names them: every
    node of the smaller piece inside the other too (and a partial overlap says the piece is moved)."""
    from fracture.coarse.tiling import _check_tiling

    names = ["a", "a_dup", "b"]
    label = np.zeros((12, 12, 12), np.int64)
    label[1:5, 1:5, 1:5] = 1  # 64 nodes of a, inside a_dup too (the argmax gave them to a)
    label[6:11, 1:11, 1:11] = 3
    twins = np.tile([0, 1], (64, 1))
    with pytest.raises(InputError, match=r"'a' and 'a_dup' overlap by .* 100% of the smaller piece.*exported twice"):
        _check_tiling(label, twins, np.zeros((0, 2), np.int64), names, 0.1, "f.obj: ")
    moved = np.tile([0, 2], (40, 1))  # 40 of b's 500 nodes inside a
    with pytest.raises(InputError, match=r"'a' and 'b' overlap by .*\(is a piece moved\?\)"):
        _check_tiling(label, moved, np.zeros((0, 2), np.int64), names, 0.1, "f.obj: ")
