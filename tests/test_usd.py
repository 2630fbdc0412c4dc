"""The USD output: what the file holds (usd-core), and what real Blender (bpy) makes of it."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO, scene_config
from fracture.io.usd import prim_name, write_pieces_usd

BLENDER_PYTHON = REPO / ".venv-blender" / "bin" / "python"
CHECK = REPO / "tools" / "blender_check_usd.py"


def _tetra(shift):
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) + shift
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return V, F


def _two_tetras_falling(n_frames):
    """Two tetrahedra; per frame the first falls along -z, the second slides along +x."""
    (A, FA), (B, FB) = _tetra([0, 0, 0]), _tetra([2, 0, 0])
    frames = [[A - [0, 0, 0.5 * t], B + [0.25 * t, 0, 0]] for t in range(n_frames)]
    return (FA, FB), frames


def test_prim_names_are_valid_and_unique():
    taken: set[str] = set()
    got = [prim_name(n, taken) for n in ["source_cell.001", "source_cell_001", "1st piece", "", "a/b"]]
    assert got == ["source_cell_001", "source_cell_001_1", "_1st_piece", "piece", "a_b"]


def _stage_positions(stage, path: str, t: float) -> np.ndarray:
    """A piece's points at time ``t`` in world space: its mesh's points through its transforms."""
    from pxr import UsdGeom

    prim = stage.GetPrimAtPath(path)
    mesh = UsdGeom.Mesh(prim.GetChild(prim.GetName()))
    P = np.array(mesh.GetPointsAttr().Get(t), np.float64)
    M = np.array(UsdGeom.XformCache(t).GetLocalToWorldTransform(mesh.GetPrim()))
    return P @ M[:3, :3] + M[3, :3]


def _turn(t: float) -> np.ndarray:
    c, s = np.cos(0.3 * t), np.sin(0.3 * t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_rigid_pieces_are_written_once_under_moving_transforms_and_deforming_frames_as_points(tmp_path):
    """One piece turns and falls (rigid at every frame), the other squashes at frames 3 and 4 only: the
    file gives every piece's positions at every frame through its transform and points, the rigid piece
    has no point samples, and the squashed one only around its squashed frames."""
    from pxr import Usd, UsdGeom, UsdShade

    (A, FA), (B, FB) = _tetra([0, 0, 0]), _tetra([2, 0, 0])
    frames = []
    for t in range(7):
        squash = np.diag([1.0, 1.0, 0.6]) if t in (3, 4) else np.eye(3)
        frames.append([A @ _turn(t).T + [0.1 * t, 0, -0.5 * t], B @ squash.T + [0.25 * t, 0, 0]])
    exterior = [np.array([1, 1, 0, 0], bool), np.array([0, 1, 1, 1], bool)]
    out = write_pieces_usd(tmp_path / "p.usdc", ["cell.000", "cell.001"], (FA, FB), exterior, frames,
                           rest=[A, B], start_frame=3, fps=30.0)
    stage = Usd.Stage.Open(str(out))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode(), stage.GetTimeCodesPerSecond()) == (3, 9, 30)
    paths = ["/Fracture/cell_000", "/Fracture/cell_001"]
    size = 4.0
    for t in range(7):
        for k, path in enumerate(paths):
            np.testing.assert_allclose(_stage_positions(stage, path, 3 + t), frames[t][k], atol=1e-6 * size)
    rigid, soft = (UsdGeom.Mesh(stage.GetPrimAtPath(p).GetChild(p.split("/")[-1])) for p in paths)
    assert not rigid.GetPointsAttr().GetNumTimeSamples()  # the turning piece: its points once
    assert rigid.GetPointsAttr().GetTimeSamples() == []
    assert soft.GetPointsAttr().GetTimeSamples() == [5, 6, 7, 8]  # rest before and after its squashed frames
    for k, (path, F) in enumerate(zip(paths, (FA, FB))):
        xform = stage.GetPrimAtPath(path)
        assert xform.IsA(UsdGeom.Xform) and xform.GetAttribute("fracref:sourceName").Get() == f"cell.00{k}"
        mesh = UsdGeom.Mesh(xform.GetChild(xform.GetName()))
        assert UsdGeom.PrimvarsAPI(mesh).GetPrimvar("piecename").Get() == f"cell.00{k}"
        assert UsdGeom.PrimvarsAPI(mesh).GetPrimvar("piecename").GetInterpolation() == UsdGeom.Tokens.constant
        assert not mesh.GetFaceVertexIndicesAttr().GetNumTimeSamples()  # topology once
        assert np.array_equal(np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3), F)
        subsets = {s.GetPrim().GetName(): s for s in UsdGeom.Subset.GetGeomSubsets(mesh)}
        assert set(subsets) == {"interior", "exterior"}
        assert UsdGeom.Subset.GetFamilyType(mesh, UsdShade.Tokens.materialBind) == UsdGeom.Tokens.partition
        assert UsdGeom.Subset.ValidateSubsets(list(subsets.values()), 4, UsdGeom.Tokens.partition)[0]
        for kind, want in (("exterior", exterior[k]), ("interior", ~exterior[k])):
            assert subsets[kind].GetFamilyNameAttr().Get() == "materialBind"
            assert sorted(subsets[kind].GetIndicesAttr().Get()) == np.flatnonzero(want).tolist()
            bound = UsdShade.MaterialBindingAPI(subsets[kind].GetPrim()).ComputeBoundMaterial()[0]
            assert bound.GetPath() == f"/Fracture/Materials/{kind}"


def test_without_rest_points_every_frame_holds_the_points(tmp_path):
    from pxr import Usd, UsdGeom

    faces, frames = _two_tetras_falling(5)
    exterior = [np.ones(4, bool), np.ones(4, bool)]
    out = write_pieces_usd(tmp_path / "p.usda", ["a", "b"], faces, exterior, frames)
    stage = Usd.Stage.Open(str(out))
    for k, path in enumerate(["/Fracture/a", "/Fracture/b"]):
        mesh = UsdGeom.Mesh(stage.GetPrimAtPath(path).GetChild(path.split("/")[-1]))
        assert mesh.GetPointsAttr().GetTimeSamples() == [1, 2, 3, 4, 5]
        for t in range(5):
            np.testing.assert_allclose(_stage_positions(stage, path, 1 + t), frames[t][k], atol=1e-6)


def test_a_failed_write_keeps_the_earlier_file_and_leaves_nothing(tmp_path):
    faces, frames = _two_tetras_falling(3)
    ext = [np.ones(4, bool)] * 2
    out = write_pieces_usd(tmp_path / "p.usdc", ["a", "b"], faces, ext, frames)
    before = out.read_bytes()

    def broken():
        yield frames[0]
        raise RuntimeError("killed")

    with pytest.raises(RuntimeError):
        write_pieces_usd(out, ["a", "b"], faces, ext, broken())
    with pytest.raises(ValueError, match="frame 2: 1 point arrays for 2 pieces"):
        write_pieces_usd(out, ["a", "b"], faces, ext, [frames[0], frames[1][:1]])
    assert out.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.usdc"]


def _blender(path: Path) -> dict:
    """What Blender (the bpy module) sees when it imports ``path``."""
    assert BLENDER_PYTHON.is_file(), "Blender's Python is missing: run `make install` (it creates .venv-blender)"
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    done = subprocess.run([str(BLENDER_PYTHON), str(CHECK), str(path)], capture_output=True, text=True,
                          timeout=600, env=env, cwd=path.parent)
    assert done.returncode == 0, done.stderr[-2000:]
    line = [x for x in done.stdout.splitlines() if x.startswith("FRACREF-JSON ")]
    assert line, done.stdout[-2000:]
    return json.loads(line[0][len("FRACREF-JSON "):])


@pytest.fixture(scope="module")
def cube8_run(tmp_path_factory):
    """The shipped Blender Cell Fracture sample, run end to end at a small budget."""
    from fracture.pipeline import runner

    out = tmp_path_factory.mktemp("usd") / "run"
    cfg = scene_config("blender_cube8", ["refine.max_triangles=15000", "animate.check_samples=1000",
                                         "animate.obj_frames=true"])
    return runner.run(cfg, out, progress=False)


@pytest.mark.slow
def test_blender_imports_the_run_usd_with_names_closed_pieces_materials_and_motion(cube8_run):
    from fracture.io.ply import read_ply
    from fracture.pieces.transfer import load_transfer

    names = json.loads((cube8_run / "coarse/components.json").read_text())["names"]
    got = _blender(cube8_run / "animation/pieces.usdc")
    tr = load_transfer(cube8_run / "animation/transfer.npz")
    assert (got["frame_start"], got["frame_end"]) == (1, tr.n_frames)
    objects = {o["name"]: o for o in got["objects"]}
    taken: set[str] = set()
    assert sorted(objects) == sorted(prim_name(n, taken) for n in names)
    taken = set()
    first, last = tr.positions(0), tr.positions(tr.n_frames - 1)
    assert np.abs(last - first).max() > 0.5  # the pieces fall: the frames differ
    for c, name in enumerate(names):
        o = objects[prim_name(name, taken)]
        _, F, _, face_data = read_ply(cube8_run / f"pieces/piece_{c:03d}.ply")
        ext = face_data["exterior"].astype(bool)
        assert o["closed"] and o["faces"] == len(F)
        assert o["materials"] == {"exterior": int(ext.sum()), "interior": int((~ext).sum())}
        np.testing.assert_allclose(o["first"], tr.piece(first, c), atol=1e-5)
        np.testing.assert_allclose(o["last"], tr.piece(last, c), atol=1e-5)


@pytest.mark.slow
def test_blender_imports_an_obj_frame_with_the_z_up_axes_the_readme_gives(cube8_run):
    from fracture.pieces.transfer import load_transfer

    names = json.loads((cube8_run / "coarse/components.json").read_text())["names"]
    tr = load_transfer(cube8_run / "animation/transfer.npz")
    t = tr.n_frames
    got = {o["name"]: o for o in _blender(cube8_run / f"frames/frame_{t:04d}.obj")["objects"]}
    assert sorted(got) == sorted(names)
    X = tr.positions(t - 1)
    for c, name in enumerate(names):
        assert got[name]["closed"]
        np.testing.assert_allclose(np.sort(np.array(got[name]["first"]), axis=0), np.sort(tr.piece(X, c), axis=0),
                                   atol=1e-5)


@pytest.mark.slow
def test_fracref_export_rewrites_the_same_usd_elsewhere(cube8_run, tmp_path):
    from pxr import Usd, UsdGeom

    from fracref.cli import main

    assert main(["export", str(cube8_run), "--format", "usd", "--out", str(tmp_path / "again.usda")]) == 0
    a = Usd.Stage.Open(str(cube8_run / "animation/pieces.usdc"))
    b = Usd.Stage.Open(str(tmp_path / "again.usda"))
    pa = [p.GetPath() for p in a.Traverse()]
    assert pa == [p.GetPath() for p in b.Traverse()]
    for p in pa:
        if a.GetPrimAtPath(p).IsA(UsdGeom.Mesh):
            for t in (1, a.GetEndTimeCode()):
                path = str(p.GetParentPath())
                np.testing.assert_allclose(_stage_positions(a, path, t), _stage_positions(b, path, t), atol=1e-6)


@pytest.mark.slow
def test_the_run_usd_gives_every_frame_of_the_run_and_moves_rigid_pieces_by_transforms(cube8_run):
    """Blender's rigid-body pieces: each is written once, its transform sampled per frame, its points only
    at the frames where it deforms (while it separates: its fracture vertices follow their neighbours
    until their fracture time); the file's positions at every frame are the run's within a millionth of
    the scene's size."""
    from pxr import Usd, UsdGeom

    from fracture.io.usd import RIGID, rigid_motion
    from fracture.pieces.transfer import load_transfer, rest_points

    names = json.loads((cube8_run / "coarse/components.json").read_text())["names"]
    tr = load_transfer(cube8_run / "animation/transfer.npz")
    stage = Usd.Stage.Open(str(cube8_run / "animation/pieces.usdc"))
    size = float(np.linalg.norm(np.ptp(tr.material, axis=0)))
    taken: set[str] = set()
    paths = [f"/Fracture/{prim_name(n, taken)}" for n in names]
    rest = rest_points(tr)
    deforming = [set() for _ in names]
    for t in range(tr.n_frames):
        X = tr.positions(t)
        for c, path in enumerate(paths):
            np.testing.assert_allclose(_stage_positions(stage, path, t + 1), tr.piece(X, c), atol=1e-6 * size)
            if rigid_motion(rest[c], tr.piece(X, c))[2] > RIGID * size:
                deforming[c].add(t + 1)
    for c, (path, name) in enumerate(zip(paths, names)):
        prim = stage.GetPrimAtPath(path)
        assert prim.GetAttribute("fracref:sourceName").Get() == name
        samples = set(UsdGeom.Mesh(prim.GetChild(prim.GetName())).GetPointsAttr().GetTimeSamples())
        near = deforming[c] | {t - 1 for t in deforming[c]} | {t + 1 for t in deforming[c]}
        assert deforming[c] <= samples <= near, (name, sorted(deforming[c]), sorted(samples))
        assert len(samples) < tr.n_frames // 2  # the rest of the frames: the transform alone


def test_fracref_export_refuses_what_is_not_a_finished_run(tmp_path, capsys):
    from fracref.cli import main

    assert main(["export", str(tmp_path / "nowhere")]) == 2
    assert "not a run directory" in capsys.readouterr().err
    (tmp_path / "half").mkdir()
    assert main(["export", str(tmp_path / "half")]) == 2
    assert "coarse/components.json is missing" in capsys.readouterr().err


@pytest.mark.parametrize("rel, damage", [
    ("manifest.json", b"{\"name\": \x01"),
    ("manifest.json", b""),
    ("animation/transfer.npz", b"PK\x03\x04 cut short"),
    ("coarse/components.json", b"[1, 2"),
    ("manifest.json", b"[]"),
])
def test_fracref_export_of_a_damaged_run_names_the_file(cube8_run, tmp_path, capsys, rel, damage):
    import shutil

    from fracref.cli import main

    run = tmp_path / "run"
    shutil.copytree(cube8_run, run)
    (run / rel).write_bytes(damage)
    assert main(["export", str(run), "--out", str(tmp_path / "x.usdc")]) == 2
    err = capsys.readouterr().err
    assert (f"cannot export, {rel} cannot be read (" in err or f"{rel}: holds a JSON list; expected a run's manifest"
            in err) and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "x.usdc").exists()


# -- USD input ------------------------------------------------------------------------------------

def _write_points_usd(path, frames, names, up="Z", left_handed=False, start=1, fps=None, meters_per_unit=None,
                      scale=1.0):
    """A Houdini-style USD: one mesh per piece, its points time-sampled per frame, no transforms; with
    ``left_handed`` its faces wound the other way and said to be (Houdini's default orientation)."""
    from pxr import Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up == "Y" else UsdGeom.Tokens.z)
    if meters_per_unit is not None:
        UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    if fps is not None:
        stage.SetTimeCodesPerSecond(fps)
    stage.SetStartTimeCode(start)
    stage.SetEndTimeCode(start + len(frames) - 1)
    for p, name in enumerate(names):
        mesh = UsdGeom.Mesh.Define(stage, f"/geo/{name.replace('.', '_')}")
        polys = [f[::-1] for f in frames[0].polygons[p]] if left_handed else frames[0].polygons[p]
        used = np.unique(np.concatenate(polys))
        local = {v: i for i, v in enumerate(used.tolist())}
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray([len(f) for f in polys]))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([local[v] for f in polys for v in f.tolist()]))
        if left_handed:
            mesh.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
        for t, fr in enumerate(frames, start=start):
            mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy((scale * fr.V[used]).astype(np.float32)), t)
    stage.GetRootLayer().Save()



def _rest_mesh(stage, path, rest, k):
    """Piece ``k`` of the rest frame ``rest`` as a mesh at ``path``: its own points, its polygons."""
    from pxr import UsdGeom, Vt

    mesh = UsdGeom.Mesh.Define(stage, path)
    polys = rest.polygons[k]
    used = np.unique(np.concatenate(polys))
    local = {v: i for i, v in enumerate(used.tolist())}
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([len(f) for f in polys]))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([local[v] for f in polys for v in f.tolist()]))
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(rest.V[used].astype(np.float32)))
    return mesh


def test_instanced_pieces_are_read_through_their_instances(tmp_path):
    """Pieces written as instanceable references (``/geo/NAME`` an instance moved by its own transform, its
    mesh ``/Prototypes/pK/mesh`` in a class): each is read through its instance, named by it, at the
    instance's place in every frame (the meshes were not found: "no Mesh prims")."""
    from pxr import Gf, Usd, UsdGeom, Vt

    from conftest import SAMPLE
    from fracture.coarse.mesh_sequence import read_sequence
    from fracture.coarse.usd_input import read_usd_frames

    rest = read_sequence(SAMPLE)[0]
    path = tmp_path / "instanced.usda"
    stage = Usd.Stage.CreateNew(str(path))
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(3)
    for k, name in enumerate(rest.names):
        stage.CreateClassPrim(f"/Prototypes/p{k}")
        _rest_mesh(stage, f"/Prototypes/p{k}/mesh", rest, k)
        instance = UsdGeom.Xform.Define(stage, f"/geo/{name.replace('.', '_')}")
        instance.GetPrim().GetReferences().AddInternalReference(f"/Prototypes/p{k}")
        instance.GetPrim().SetInstanceable(True)
        move = instance.AddTranslateOp()
        for t in (1, 2, 3):
            move.Set(Gf.Vec3d(0.0, 0.0, -0.1 * (t - 1) * k), t)
    stage.GetRootLayer().Save()
    got = read_usd_frames(path).frames
    assert len(got) == 3 and got[0].names == [n.replace(".", "_") for n in rest.names]
    for t in (0, 2):
        for k in range(len(rest.names)):
            X = got[t].V[got[t].piece_vertices(k)]
            want = rest.V[np.unique(np.concatenate(rest.polygons[k]))] + (0.0, 0.0, -0.1 * t * k)
            np.testing.assert_allclose(X, want, atol=1e-6)


def test_pieces_of_a_point_instancer_are_read_where_its_instances_put_them(tmp_path):
    """Pieces written as a point instancer (``/geo/rbd``: one prototype per piece, each instance's position
    and orientation time-sampled, as Houdini may write packed fragments): each instance is a piece named
    after its prototype, at the instance's place in every frame; the prototypes themselves are no pieces."""
    from pxr import Gf, Usd, UsdGeom, Vt

    from conftest import SAMPLE
    from fracture.coarse.mesh_sequence import read_sequence
    from fracture.coarse.usd_input import read_usd_frames

    rest = read_sequence(SAMPLE)[0]
    path = tmp_path / "instancer.usda"
    stage = Usd.Stage.CreateNew(str(path))
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(3)
    instancer = UsdGeom.PointInstancer.Define(stage, "/geo/rbd")
    protos = []
    for k, name in enumerate(rest.names):
        root = UsdGeom.Xform.Define(stage, f"/geo/rbd/Prototypes/{name.replace('.', '_')}")
        _rest_mesh(stage, root.GetPath().AppendChild("mesh"), rest, k)
        protos.append(root.GetPath())
    instancer.CreatePrototypesRel().SetTargets(protos)
    n = len(protos)
    instancer.CreateProtoIndicesAttr(Vt.IntArray(list(range(n))))
    turn = Gf.Rotation(Gf.Vec3d(0, 0, 1), 90.0).GetQuat()  # piece 0 turns a quarter about z by frame 3
    for t in (1, 2, 3):
        instancer.GetPositionsAttr().Set(Vt.Vec3fArray([Gf.Vec3f(0.0, 0.0, -0.1 * (t - 1) * k) for k in range(n)]), t)
        q = [Gf.Quath(1.0, 0.0, 0.0, 0.0)] * n
        if t == 3:
            q[0] = Gf.Quath(turn.GetReal(), *turn.GetImaginary())
        instancer.GetOrientationsAttr().Set(Vt.QuathArray(q), t)
    stage.GetRootLayer().Save()
    got = read_usd_frames(path).frames
    assert len(got) == 3 and got[0].names == [n.replace(".", "_") for n in rest.names]
    for t in (0, 1):
        for k in range(n):
            X = got[t].V[got[t].piece_vertices(k)]
            want = rest.V[np.unique(np.concatenate(rest.polygons[k]))] + (0.0, 0.0, -0.1 * t * k)
            np.testing.assert_allclose(X, want, atol=1e-6)
    X = got[2].V[got[2].piece_vertices(0)]
    R = rest.V[np.unique(np.concatenate(rest.polygons[0]))]
    np.testing.assert_allclose(X, np.stack([-R[:, 1], R[:, 0], R[:, 2]], 1), atol=2e-3)  # half precision


def test_hidden_meshes_guides_and_proxies_are_not_pieces(tmp_path):
    """A stage exported whole: the object Cell Fracture hid (invisible, where all the pieces are), a proxy of
    a piece and a guide. None is a piece; the coarse stage says which were left out. Left in, the hidden
    object overlapped every piece and the run was refused."""
    from pxr import Usd, UsdGeom, Vt

    from conftest import SAMPLE
    from fracture.coarse.mesh_sequence import read_sequence
    from fracture.coarse.usd_input import read_usd_frames
    from fracture.pipeline import runner
    from fracture.pipeline.config import load_config

    frames = read_sequence(SAMPLE)[:6]
    path = tmp_path / "whole.usda"
    _write_points_usd(path, frames, frames[0].names)
    stage = Usd.Stage.Open(str(path))
    lo, hi = frames[0].V.min(axis=0), frames[0].V.max(axis=0)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    for where, how in (("/geo/Cube", "invisible"), ("/geo/Cube_proxy", "proxy"), ("/geo/helper", "guide")):
        mesh = UsdGeom.Mesh.Define(stage, where)
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(corners.astype(np.float32)))
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray([4] * 6))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([v for q in quads for v in q]))
        if how == "invisible":
            mesh.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
        else:
            mesh.CreatePurposeAttr(how)
    stage.GetRootLayer().Save()
    usd = read_usd_frames(path)
    assert usd.frames[0].names == [n.replace(".", "_") for n in frames[0].names]
    assert usd.hidden == ("/geo/Cube", "/geo/Cube_proxy", "/geo/helper")
    cfg_path = tmp_path / "c.yaml"
    cfg_path.write_text(f"input: {{kind: usd, usd: {path}}}\ngrid: {{resolution: 24}}\n")
    out = runner.run(load_config(cfg_path), tmp_path / "run", until="coarse", progress=False)
    notes = json.loads((out / "manifest.json").read_text())["notes"]
    assert notes[0] == "coarse: left out 3 invisible or guide or proxy meshes of the USD file: /geo/Cube, " \
                       "/geo/Cube_proxy, /geo/helper"


def test_one_mesh_holding_every_piece_is_split_into_its_parts(tmp_path):
    """All the pieces written as one mesh with time-sampled points (Houdini's geometry unpartitioned): its
    connected parts are the pieces, in every frame."""
    from pxr import Usd, UsdGeom, Vt

    from conftest import SAMPLE
    from fracture.coarse.mesh_sequence import read_sequence
    from fracture.coarse.usd_input import read_usd_frames

    frames = read_sequence(SAMPLE)[:4]
    path = tmp_path / "merged.usda"
    stage = Usd.Stage.CreateNew(str(path))
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(len(frames))
    mesh = UsdGeom.Mesh.Define(stage, "/geo/fractured")
    polys = [f for piece in frames[0].polygons for f in piece]
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([len(f) for f in polys]))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([int(v) for f in polys for v in f]))
    for t, fr in enumerate(frames, start=1):
        mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(fr.V.astype(np.float32)), t)
    stage.GetRootLayer().Save()
    got = read_usd_frames(path).frames
    assert got[0].names == [f"fractured_{i:03d}" for i in range(8)]
    for t in (0, 3):
        assert got[t].names == got[0].names
        for k in range(8):
            np.testing.assert_allclose(got[t].V[got[t].piece_vertices(k)],
                                       frames[t].V[frames[t].piece_vertices(k)], atol=1e-6)

def test_a_usd_of_time_sampled_points_imports_as_its_obj_frames_do(tmp_path):
    from conftest import SAMPLE
    from fracture.coarse.mesh_sequence import coarse_from_frames, read_sequence
    from fracture.coarse.usd_input import read_usd_frames

    frames = read_sequence(SAMPLE)
    _write_points_usd(tmp_path / "anim.usda", frames, frames[0].names)
    usd = read_usd_frames(tmp_path / "anim.usda")
    got, up = usd.frames, usd.up_axis
    assert up == "z" and len(got) == len(frames)
    assert [f.time for f in got] == list(range(1, len(frames) + 1)) and usd.fps == 24.0
    assert [n.replace("_", ".") for n in got[0].names] == [n.replace("_", ".") for n in frames[0].names]
    for t in (0, 20, len(frames) - 1):
        for p in range(len(frames[0].names)):
            a = got[t].V[np.unique(np.concatenate(got[t].polygons[p]))]
            b = frames[t].V[frames[t].piece_vertices(p)]
            np.testing.assert_allclose(np.sort(a, axis=0), np.sort(b, axis=0), atol=1e-5)
    cf, _ = coarse_from_frames(got)
    assert cf.n_components == 8 and cf.n_frames == 40 and cf.fit_residual.max() < 1e-4


def test_left_handed_meshes_import_as_the_same_pieces(tmp_path):
    """Houdini writes its meshes leftHanded (faces clockwise seen from outside): the import turns them, so
    the pieces are the same as those of the right-handed file (left as they were, every piece would be
    inside out, its winding number -1 inside)."""
    from conftest import SAMPLE
    from fracture.coarse.mesh_sequence import coarse_from_frames, read_sequence
    from fracture.coarse.usd_input import read_usd_frames

    frames = read_sequence(SAMPLE)[:3]
    _write_points_usd(tmp_path / "right.usda", frames, frames[0].names)
    _write_points_usd(tmp_path / "left.usda", frames, frames[0].names, left_handed=True)
    right, left = (read_usd_frames(tmp_path / f"{k}.usda").frames for k in ("right", "left"))
    for a, b in zip(right[0].polygons, left[0].polygons):
        assert all(np.array_equal(x, y) for x, y in zip(a, b))
    cf, _ = coarse_from_frames(left)
    assert cf.n_components == 8 and len(cf.F) == len(coarse_from_frames(right)[0].F)


def test_a_usd_in_centimetres_at_30_fps_from_frame_1001_comes_back_so(tmp_path):
    """The run's USD keeps the input's unit, frame rate and time codes (a studio's shot starts at 1001, its
    stage in centimetres): a DCC that reads it puts the pieces where the input's were, at its frames; the
    manifest says so, and `fracref export` writes the same."""
    from pxr import Usd, UsdGeom

    from conftest import SAMPLE
    from fracture.coarse.mesh_sequence import read_sequence
    from fracture.pipeline import runner
    from fracture.pipeline.config import load_config
    from fracture.errors import InputError
    from fracture.pipeline.export import export_run

    frames = read_sequence(SAMPLE)[:12]
    usd = tmp_path / "shot.usda"
    _write_points_usd(usd, frames, frames[0].names, start=1001, fps=30.0, meters_per_unit=0.01, scale=100.0)
    cfg_path = tmp_path / "c.yaml"
    cfg_path.write_text(f"input: {{kind: usd, usd: {usd}}}\ngrid: {{resolution: 24}}\n")
    cfg = load_config(cfg_path, ["refine.max_triangles=3000", "refine.iterations=2", "animate.check_samples=1000",
                                 "animate.obj_frames=true"])
    out = runner.run(cfg, tmp_path / "run", progress=False)
    coarse = json.loads((out / "manifest.json").read_text())["stats"]["coarse"]
    assert (coarse["first_frame"], coarse["frame_step"], coarse["fps"], coarse["meters_per_unit"]) == (
        1001, 1, 30, 0.01)
    # the OBJ frames carry the shot's numbers too
    assert sorted(p.name for p in (out / "frames").glob("*.obj")) == [f"frame_{k}.obj" for k in range(1001, 1013)]
    for path in (out / "animation/pieces.usdc", export_run(out, out=tmp_path / "again.usda")):
        stage = Usd.Stage.Open(str(path))
        assert UsdGeom.GetStageMetersPerUnit(stage) == 0.01 and stage.GetTimeCodesPerSecond() == 30
        assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (1001, 1012)
        # a piece at the last time code is where the input's was, in the input's unit (within 5 % of the
        # object's 2 m: its cut faces are refined)
        name = frames[0].names[3]
        vids = frames[0].piece_vertices(3)
        P = _stage_positions(stage, f"/Fracture/{prim_name(name, set())}", 1012)
        lo, hi = P.min(axis=0), P.max(axis=0)
        np.testing.assert_allclose(lo, 100.0 * frames[11].V[vids].min(axis=0), atol=10.0)
        np.testing.assert_allclose(hi, 100.0 * frames[11].V[vids].max(axis=0), atol=10.0)
    # an existing file elsewhere is replaced only when asked; the run's own file is written again from its outputs
    kept = (tmp_path / "again.usda").read_bytes()
    with pytest.raises(InputError, match="again.usda exists; choose another --out or pass --force to replace it"):
        export_run(out, out=tmp_path / "again.usda")
    assert (tmp_path / "again.usda").read_bytes() == kept
    assert export_run(out, out=tmp_path / "again.usda", force=True) == tmp_path / "again.usda"
    assert export_run(out) == out / "animation/pieces.usdc"
    # a frame rate in the config wins over the input's
    cfg24 = load_config(cfg_path, ["refine.max_triangles=3000", "refine.iterations=2", "animate.check_samples=1000",
                                   "animate.fps=24"])
    out24 = runner.run(cfg24, tmp_path / "run24", progress=False)
    assert Usd.Stage.Open(str(out24 / "animation/pieces.usdc")).GetTimeCodesPerSecond() == 24


def test_frames_written_at_a_step_keep_their_time_codes(tmp_path):
    from pxr import Usd

    faces, frames = _two_tetras_falling(4)
    out = write_pieces_usd(tmp_path / "p.usda", ["a", "b"], faces, [np.ones(4, bool)] * 2, frames,
                           start_frame=10, frame_step=2)
    stage = Usd.Stage.Open(str(out))
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (10, 16)
    for k, t in enumerate((10, 12, 14, 16)):
        np.testing.assert_allclose(_stage_positions(stage, "/Fracture/a", t), frames[k][0], atol=1e-6)


@pytest.mark.slow
def test_a_usd_written_by_blender_runs_end_to_end(tmp_path):
    """Blender 4.2 (bpy) simulates Cell Fracture pieces and writes them to USD with time-sampled transforms."""
    import tarfile

    from fracture.pipeline import runner
    from fracture.pipeline.config import load_config

    with tarfile.open(REPO / "examples" / "cellfracture" / "cube_rotated_8.tar.xz") as tar:
        tar.extractall(tmp_path, filter="data")
    usd = tmp_path / "cube_rotated_8.usdc"
    assert BLENDER_PYTHON.is_file(), "Blender's Python is missing: run `make install` (it creates .venv-blender)"
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    done = subprocess.run([str(BLENDER_PYTHON), str(REPO / "tools" / "make_usd_animation.py"),
                           str(tmp_path / "cube_rotated_8" / "sample" / "frame_0001.obj"), str(usd), "--frames", "24"],
                          capture_output=True, text=True, timeout=600, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    cfg_path = tmp_path / "c.yaml"
    cfg_path.write_text(f"input: {{kind: usd, usd: {usd}}}\n")
    cfg = load_config(cfg_path, ["refine.max_triangles=8000", "refine.iterations=6", "animate.check_samples=1000"])
    out = runner.run(cfg, tmp_path / "run", progress=False)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["counts"]["components"] == 8 and manifest["counts"]["frames"] == 24
    assert manifest["stats"]["coarse"]["up_axis"] == "z" and manifest["stats"]["coarse"]["fit_residual_max"] < 1e-4
    names = json.loads((out / "coarse/components.json").read_text())["names"]
    assert sorted(names) == sorted(["source_cell"] + [f"source_cell_{k:03d}" for k in range(1, 8)])
    # the pieces come back out as USD, under the same names
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(out / "animation/pieces.usdc"))
    meshes = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    assert sorted(p.GetParent().GetAttribute("fracref:sourceName").Get() for p in meshes) == sorted(names)
    assert sorted(UsdGeom.PrimvarsAPI(p).GetPrimvar("piecename").Get() for p in meshes) == sorted(names)
    assert stage.GetEndTimeCode() == 24


@pytest.mark.parametrize("content, words", [
    (None, "USD file not found"),
    ("this is not USD\n", "cannot open as USD"),
    ("#usda 1.0\n", "no Mesh prims"),
])
def test_bad_usd_input_is_refused_clearly(tmp_path, content, words):
    from fracture.errors import InputError
    from fracture.coarse.usd_input import read_usd_frames

    path = tmp_path / "x.usda"
    if content is not None:
        path.write_text(content)
    with pytest.raises(InputError, match=words):
        read_usd_frames(path)


def _damaged_usd(path, damage):
    """Two tetrahedra, points time-sampled at 1..3 (Houdini's way), with one kind of ``damage``."""
    from pxr import Usd, UsdGeom, Vt

    faces, frames = _two_tetras_falling(3)
    stage = Usd.Stage.CreateNew(str(path))
    if damage != "no range":
        stage.SetStartTimeCode(1)
        stage.SetEndTimeCode(1_000_000 if damage == "huge range" else 3)
    for k in range(2):
        mesh = UsdGeom.Mesh.Define(stage, f"/geo/t{k}")
        idx = faces[k].ravel().tolist()
        if damage == "negative index" and k == 1:
            idx[0] = -1
        if damage == "faces sampled":  # only as time samples, as Houdini may write them
            mesh.CreateFaceVertexCountsAttr().Set(Vt.IntArray([3] * len(faces[k])), 1)
            mesh.CreateFaceVertexIndicesAttr().Set(Vt.IntArray(idx), 1)
        elif not (damage == "no faces" and k == 1):
            mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(faces[k])))
            mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(idx))
        if damage == "no points" and k == 1:
            continue
        for t, P in enumerate(frames, start=1):
            points = P[k] if not (damage == "a point more" and k == 1 and t == 3) else np.r_[P[k], P[k][:1]]
            mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)), t)
    if damage == "negative rate":
        stage.SetTimeCodesPerSecond(-24)
    stage.GetRootLayer().Save()


@pytest.mark.parametrize("damage, words", [
    ("no points", "piece 't1' (/geo/t1) has no points at frame 1: expected time samples or a default value"),
    ("no faces", "piece 't1' (/geo/t1) has no faces or inconsistent face counts"),
    ("negative index", "piece 't1' (/geo/t1): a face uses point -1; expected point indices from 0"),
    ("huge range", "its time code range 1 to 1e+06 holds 1,000,000 frames; expected at most 10,000"),
    ("a point more", "piece 't1' has 5 points at frame 3, 4 at the first frame; expected the same points"),
    ("negative rate", "the stage's timeCodesPerSecond is -24; expected a positive number of time codes per second"),
])
def test_a_damaged_usd_is_refused_naming_the_piece_and_what_was_expected(tmp_path, damage, words):
    from fracture.errors import InputError
    from fracture.coarse.usd_input import read_usd_frames

    _damaged_usd(tmp_path / "x.usdc", damage)
    with pytest.raises(InputError) as error:
        read_usd_frames(tmp_path / "x.usdc")
    assert words in str(error.value)


@pytest.mark.parametrize("point, words", [("99", "a face uses point 99 of 4"),
                                          ("nan", "NaN or infinite coordinates")])
def test_a_damaged_usd_without_time_samples_names_the_default_time(tmp_path, point, words):
    from fracture.errors import InputError
    from fracture.coarse.usd_input import read_usd_frames

    last, corner = ("(0, 0, 1)", point) if point == "99" else (f"({point}, 0, 1)", "3")
    (tmp_path / "x.usda").write_text(f"""#usda 1.0
def Xform "World"
{{
    def Mesh "pieceA"
    {{
        int[] faceVertexCounts = [3, 3, 3, 3]
        int[] faceVertexIndices = [0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, {corner}]
        point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0), {last}]
    }}
}}
""")
    with pytest.raises(InputError) as error:
        read_usd_frames(tmp_path / "x.usda")
    assert f"piece 'pieceA' at the default time: {words}" in str(error.value)


def test_a_usd_with_time_samples_and_no_range_reads_every_sampled_frame(tmp_path):
    from fracture.coarse.usd_input import read_usd_frames

    _damaged_usd(tmp_path / "x.usdc", "no range")
    _, frames = _two_tetras_falling(3)
    read = read_usd_frames(tmp_path / "x.usdc").frames
    assert [f.time for f in read] == [1.0, 2.0, 3.0]
    assert np.allclose(read[2].V, np.concatenate(frames[2]), atol=1e-6)


@pytest.mark.parametrize("content, words", [
    (b"", "the file is empty; expected a USD file"),
    (b"Ogawa", "an Alembic file; this reads USD"),
    (b'#usda 1.0\ndef Mesh "a" {\n  point3f[] points = [(0,0,0), (1,\n}\n',
     "x.usda:4:1: parse error matching Sdf_TextFileFormatParser::TupleValueClose"),
])
def test_a_broken_usd_file_says_why_in_one_line(tmp_path, content, words):
    from fracture.errors import InputError
    from fracture.coarse.usd_input import read_usd_frames

    path = tmp_path / ("x.abc" if content == b"Ogawa" else "x.usda")
    path.write_bytes(content)
    with pytest.raises(InputError) as error:
        read_usd_frames(path)
    text = str(error.value)
    assert words in text and "\n" not in text and "pxrInternal" not in text and ".cpp" not in text


def test_a_usd_that_cannot_be_written_is_said_of_the_users_file(tmp_path, monkeypatch):
    """A full disk, or a folder one may not write in: USD's error, in one line, naming the file asked for
    (not the temporary one beside it), and nothing left behind."""
    from pxr import Sdf, Tf

    from fracture.io.atomic import OutputError

    def full(self, *args, **kwargs):
        raise Tf.ErrorException("\n\tError in 'pxrInternal_v0_26_11__pxrReserved__::SdfLayer::Save' at line 1 in "
                                "file /opt/USD/layer.cpp : 'No space left on device'")

    monkeypatch.setattr(Sdf.Layer, "Save", full)
    faces, frames = _two_tetras_falling(3)
    with pytest.raises(OutputError) as error:
        write_pieces_usd(tmp_path / "p.usdc", ["a", "b"], faces, [np.ones(4, bool)] * 2, frames)
    assert str(error.value) == f"{tmp_path / 'p.usdc'}: cannot write the USD file: No space left on device"
    assert list(tmp_path.iterdir()) == []


def test_what_a_killed_usd_writer_left_beside_the_file_goes_with_the_next_write(tmp_path):
    """A writer killed mid-file leaves ``.p.partial-PID.usdc``; the next write of ``p.usdc`` deletes it, and
    leaves a writer's that is still going."""
    import os
    import subprocess
    import sys

    dead = int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                              text=True).stdout)
    stale, live = tmp_path / f".p.partial-{dead}.usdc", tmp_path / f".p.partial-{os.getppid()}.usdc"
    stale.write_bytes(b"half")
    live.write_bytes(b"going")
    faces, frames = _two_tetras_falling(3)
    write_pieces_usd(tmp_path / "p.usdc", ["a", "b"], faces, [np.ones(4, bool)] * 2, frames)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([live.name, "p.usdc"])


@pytest.mark.parametrize("missing", ["sublayer", "reference"])
def test_a_usd_naming_a_layer_that_is_not_there_is_refused(tmp_path, missing):
    """USD skips a sublayer or a reference it cannot open and goes on: the pieces in it would be silently gone."""
    from pxr import Usd

    from fracture.coarse.usd_input import read_usd_frames
    from fracture.errors import InputError

    _damaged_usd(tmp_path / "x.usdc", None)
    stage = Usd.Stage.Open(str(tmp_path / "x.usdc"))
    if missing == "sublayer":
        stage.GetRootLayer().subLayerPaths.append("gone.usda")
    else:
        stage.DefinePrim("/more").GetReferences().AddReference("gone.usd")
    stage.GetRootLayer().Save()
    with pytest.raises(InputError) as error:
        read_usd_frames(tmp_path / "x.usdc")
    assert "gone.usd" in str(error.value) and str(error.value).endswith(
        "expected every layer and reference it names beside it (copy them with it, or flatten the stage: usdcat "
        "--flatten)")


def test_faces_given_only_as_time_samples_are_read():
    """Face counts and indices authored as time samples only (Houdini may write them so): read at the first
    frame, the same pieces as with default values."""
    import tempfile
    from pathlib import Path

    from fracture.coarse.usd_input import read_usd_frames

    with tempfile.TemporaryDirectory() as d:
        _damaged_usd(Path(d) / "plain.usdc", None)
        _damaged_usd(Path(d) / "sampled.usdc", "faces sampled")
        plain, sampled = (read_usd_frames(Path(d) / name) for name in ("plain.usdc", "sampled.usdc"))
    assert len(sampled.frames) == len(plain.frames) == 3
    for a, b in zip(sampled.frames, plain.frames):
        assert np.array_equal(a.V, b.V) and len(a.polygons) == len(b.polygons) == 2
        for x, y in zip(a.polygons, b.polygons):
            assert len(x) == len(y) and all(np.array_equal(p, q) for p, q in zip(x, y))
