"""Section 5: imprinting B, closed pieces, deformation transfer and the animate stage's files."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import BUDGETS, CONFIGS, SAMPLE, SCENE_CASES, scene_config

from fracture.refine.engine import SEARCH_STAGE
from fracture.pipeline import runner
from fracture.pipeline.config import load_config
from fracture.mesh.exterior import Exterior
from fracture.pieces.imprint import (BRIDGE_DEPTH, clip_tangent_triangles, imprint_boundary, split_bridge_edges,
                                     subdivide_boundary)
from fracture.io.meshes import read_obj_objects
from fracture.io.obj import ObjFrames
from fracture.pieces.assembly import Pieces, build_pieces, mesh_checks, overlap_and_gap
from fracture.io.ply import read_ply
from fracture.mesh.primitives import box, grid_faces
from fracture.mesh.fracture_surface import FractureSurface
from fracture.mesh.topology import face_frames, signed_volume
from fracture.coarse.components import label_components
from fracture.io.snapshots import load_snapshots
from fracture.mesh.edges import edge_table, row_edges
from fracture.mesh.intersect import self_intersections
from fracture.refine.crossings_on_b import crossing_pairs
from fracture.tolerances import tol


def slanted_cut(n: int = 7):
    """The unit cube (B, 10 cells a side) and the cut x = 0.37 + 0.1 y through it (S, n x n cells).

    S's grid is not aligned with B's, so its boundary vertices fall inside
    B's triangles and its boundary edges cross B's edges.
    """
    BV, BF = box((0, 0, 0), (1, 1, 1), (10, 10, 10))
    y, z = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    V = np.stack([0.37 + 0.1 * y.ravel(), y.ravel(), z.ravel()], 1)
    F = grid_faces(n + 1, n + 1)
    normal = np.cross(V[F[0, 1]] - V[F[0, 0]], V[F[0, 2]] - V[F[0, 0]])
    front = 1 if normal[0] > 0 else 0  # the normal points into component 1 (x larger)
    sides = np.tile([1 - front, front], (len(F), 1))
    return BV, BF, FractureSurface.from_coarse(V, F, sides)


def test_a_slanted_cut_makes_two_closed_pieces_with_the_exact_volumes():
    BV, BF, mesh = slanted_cut()
    im = imprint_boundary(BV, BF, mesh)
    assert len(im.cut_edges) > 4 * 7  # the traces crossed B's edges
    pieces = build_pieces(im, mesh, 2, lambda faces: np.zeros(len(faces), np.int64))
    volumes = []
    for c in range(2):
        _, V, F = pieces.piece(c)
        ch = mesh_checks(V, F)
        assert ch["closed_oriented"] and ch["vertex_manifold"] and ch["self_intersections"] == 0
        volumes.append(ch["volume"])
    # the piece x < 0.37 + 0.1 y has volume 0.37 + 0.05
    assert volumes[0] == pytest.approx(0.42, abs=1e-12) and volumes[1] == pytest.approx(0.58, abs=1e-12)
    assert sum(volumes) == pytest.approx(signed_volume(BV, BF), rel=1e-12)
    overlap, uncovered, _, _ = overlap_and_gap(pieces, BV, BF, 4000, np.random.default_rng(0))
    assert overlap == 0 and uncovered == 0
    assert pieces.patch_agreement == 1.0


def test_imprinting_keeps_the_tree_and_puts_the_boundary_on_b():
    BV, BF, mesh = slanted_cut()
    n0 = len(mesh.V)
    im = imprint_boundary(BV, BF, mesh)
    W = mesh.tree_matrix()
    assert W.shape == (len(mesh.V), n0) and len(mesh.V) > n0
    assert np.allclose(np.asarray(W.sum(axis=1)).ravel(), 1.0)
    # the cut is planar here, so the tree reproduces every new vertex exactly
    assert np.allclose(W @ mesh.V[:n0], mesh.V, atol=1e-12)
    on_cut = im.to_fracture >= 0
    assert np.array_equal(mesh.V[im.to_fracture[on_cut]], im.V[on_cut])
    # B's cut edges are exactly S's boundary edges
    from fracture.mesh.topology import boundary_edges
    s_edges = {tuple(sorted(e)) for e in boundary_edges(mesh.F).tolist()}
    b_edges = {tuple(sorted(e)) for e in im.to_fracture[im.cut_edges].tolist()}
    assert s_edges == b_edges


def test_a_boundary_vertex_off_b_whose_trace_fails_is_merged_into_its_neighbour(monkeypatch):
    """A boundary vertex of the slanted cut moved off B into the cube (as a collision leaves one) and the
    trace of its edge to a neighbour refused once (on a Blender cube such a vertex beside a crease had its
    closest point of B across the crease, and two cracks crossed there): the vertex is merged into the
    neighbour, B is cut again, and every piece closes. A refused trace between two vertices on B is the
    user's error as before."""
    from fracture.errors import InputError
    from fracture.mesh.topology import boundary_edges
    import fracture.pieces.imprint as imprint

    BV, BF, mesh = slanted_cut()
    E = boundary_edges(mesh.F)
    on_face = [v for v in np.unique(E) if 0.05 < mesh.V[v, 1] < 0.95 and mesh.V[v, 2] == 1.0]
    v = on_face[0]
    mesh.V[v, 2] -= 0.003  # 3 % of B's edge below the top face
    neighbour = int(next(e[1] if e[0] == v else e[0] for e in E.tolist() if v in e))
    embed = imprint._embed

    def refuse_while_there(BV, BF, E, *rest):  # every order, while v is on the boundary
        if (E == v).any():
            raise imprint._TraceFailed(InputError("animate: the trace folds"), (neighbour, v))
        return embed(BV, BF, E, *rest)

    monkeypatch.setattr(imprint, "_embed", refuse_while_there)
    im = imprint_boundary(BV, BF, mesh)
    assert im.merged_off_b == 1 and v not in mesh.F and neighbour in mesh.F
    pieces = build_pieces(im, mesh, 2, lambda faces: np.zeros(len(faces), np.int64))
    assert all(mesh_checks(V, F)["closed_oriented"] for _, V, F in pieces.parts)

    def refuse(BV, BF, E, *rest):  # an edge with an end off B if there is one
        X = mesh.V[E]
        off = np.flatnonzero(((X[..., 2] == 0.997) & (X[..., 1] > 0.0) & (X[..., 1] < 1.0)).any(axis=1))
        raise imprint._TraceFailed(InputError("animate: the trace folds"), tuple(E[off[0] if len(off) else 0]))

    collapse, merges = imprint._collapse, []

    def counted(*args):
        merges.append(collapse(*args))
        return merges[-1]

    monkeypatch.setattr(imprint, "_embed", refuse)
    monkeypatch.setattr(imprint, "_collapse", counted)
    BV, BF, mesh = slanted_cut()  # every boundary vertex on B: nothing to merge
    with pytest.raises(InputError, match="the trace folds"):
        imprint_boundary(BV, BF, mesh)
    assert merges == []
    BV, BF, mesh = slanted_cut()
    mesh.V[:, 2] = np.where(mesh.V[:, 2] == 1.0, 0.997, mesh.V[:, 2])  # the top rim off B: at most four merges
    with pytest.raises(InputError, match="the trace folds"):
        imprint_boundary(BV, BF, mesh)
    assert sum(merges) == imprint._REPAIRS


def _box_with_a_bump():
    """The unit cube with a tent of three vertices a hundredth of a triangle across raised 5e-4 over the
    middle of one top triangle (its edges far shorter than B's: a bump the import's contour can leave)."""
    BV, BF = box((0, 0, 0), (1, 1, 1), (4, 4, 4))
    _, n = face_frames(BV, BF)
    f = int(np.flatnonzero(n[:, 2] > 0.99)[0])
    A, B, C = BF[f]
    mid = BV[BF[f]].mean(axis=0)
    tent = mid + 0.01 * (BV[BF[f]] - mid) + [0.0, 0.0, 5e-4]
    a, b, c = len(BV), len(BV) + 1, len(BV) + 2
    faces = [[a, b, c], [A, B, b], [A, b, a], [B, C, c], [B, c, b], [C, A, a], [C, a, c]]
    return np.vstack([BV, tent]), np.vstack([np.delete(BF, f, axis=0), faces])


def test_short_edges_of_b_are_collapsed_and_its_solid_kept():
    from fracture.mesh.clean import collapse_short_edges
    from fracture.mesh.topology import closed_oriented, signed_volume

    BV, BF = _box_with_a_bump()
    h = float(np.median(np.linalg.norm(BV[BF[:, 1]] - BV[BF[:, 0]], axis=1)))
    V, F, joined = collapse_short_edges(BV, BF, 0.1 * h)
    assert joined == 2 and len(V) == len(BV) - 2 and len(F) == len(BF) - 4
    assert closed_oriented(F) and signed_volume(V, F) == pytest.approx(1.0, abs=1e-5)  # the tent flattened
    assert collapse_short_edges(V, F, 0.1 * h)[2] == 0  # nothing more to do
    V2, F2, none = collapse_short_edges(BV, BF, 10.0)  # every edge: no solid would be left
    assert none == 0 and V2 is BV and F2 is BF



def test_short_rim_edges_beside_a_refused_trace_are_collapsed_and_the_rest_of_the_rim_kept(monkeypatch):
    """Two boundary edges of the slanted cut split into short stretches (a rim that doubles back on itself
    near a crease of B leaves such stretches, and on a Blender cube with a margin of 0.02 the traces there
    were walked into each other), one on the top face and one on the bottom, and the trace of an edge
    beside the top one refused while a short edge is near it: the short edges within reach of the refused
    trace are collapsed, the bottom ones kept, B is cut again and the pieces close with their volumes."""
    from fracture.errors import InputError
    from fracture.mesh.topology import boundary_edges
    import fracture.pieces.imprint as imprint

    BV, BF, mesh = slanted_cut()
    h = imprint.median_edge(BV, BF)
    E = boundary_edges(mesh.F)

    def stretch(z):  # an edge of the rim on the face z, split at its middle and again just after
        a, b = next(e for e in E.tolist() if (mesh.V[e, 2] == z).all() and 0.2 < mesh.V[e, 1].min() < 0.6)
        m = mesh.split_edges([[a, b]], [0.5])[0]
        return a, m, mesh.split_edges([[m, b]], [0.05])[0]

    top, bottom = stretch(1.0), stretch(0.0)
    refused = (top[0], top[1])
    embed, refusals = imprint._embed, []

    def refuse_while_short(BV, BF, E, *rest):
        length = np.linalg.norm(mesh.V[E[:, 1]] - mesh.V[E[:, 0]], axis=1)
        near = np.linalg.norm(mesh.V[E].mean(axis=1) - mesh.V[list(refused)].mean(axis=0), axis=1) < 2 * h
        if (near & (length < imprint.RIM_EDGE * h)).any():
            refusals.append(1)
            raise imprint._TraceFailed(InputError("animate: two of its cracks cross"), refused)
        return embed(BV, BF, E, *rest)

    monkeypatch.setattr(imprint, "_embed", refuse_while_short)
    im = imprint_boundary(BV, BF, mesh)
    assert im.rim_collapsed >= 1 and im.merged_off_b == 0 and len(refusals) == 3  # one per order, then embedded
    assert top[2] not in mesh.F and bottom[2] in mesh.F  # the bottom's short edge is beyond reach
    pieces = build_pieces(im, mesh, 2, lambda faces: np.zeros(len(faces), np.int64))
    volumes = [mesh_checks(V, F) for _, V, F in pieces.parts]
    assert all(v["closed_oriented"] for v in volumes)
    assert [v["volume"] for v in volumes] == pytest.approx([0.42, 0.58], abs=1e-12)

def test_s_is_imprinted_again_on_b_without_its_short_edges_when_it_cannot_be_as_b_is(monkeypatch):
    """When S cannot be imprinted on B as it is (on random Blender PLY exports two cracks' traces crossed
    over bumps of B a few hundredths of a cell across), B's short edges are collapsed and S, as it was
    before the first try, imprinted on that B; if that fails too, or B has no short edge, the first refusal
    stands."""
    from fracture.errors import InputError
    import fracture.pieces.imprint as imprint

    imprint_as_is, calls = imprint._imprint, []

    def refuse_the_first(BV, BF, mesh, where):
        calls.append((len(BV), len(mesh.F)))
        if len(calls) == 1:
            mesh.F = mesh.F[:1]  # what a failed try leaves behind
            raise InputError("animate: two of its cracks cross each other")
        return imprint_as_is(BV, BF, mesh, where)

    monkeypatch.setattr(imprint, "_imprint", refuse_the_first)
    BV, BF = _box_with_a_bump()
    _, _, mesh = slanted_cut()
    faces = len(mesh.F)
    im = imprint_boundary(BV, BF, mesh)
    assert im.joined_b == 2 and calls == [(len(BV), faces), (len(BV) - 2, faces)]
    assert len(mesh.F) > faces  # the second try's surface, split along B

    calls.clear()
    monkeypatch.setattr(imprint, "_imprint", lambda BV, BF, mesh, where: (calls.append(1), (_ for _ in ()).throw(
        InputError(f"animate: refused on {len(BV)} vertices")))[1])
    with pytest.raises(InputError, match=f"refused on {len(BV)} vertices"):
        imprint_boundary(BV, BF, slanted_cut()[2])
    assert len(calls) == 2
    BV, BF, mesh = slanted_cut()  # no short edge: no second try
    calls.clear()
    with pytest.raises(InputError):
        imprint_boundary(BV, BF, mesh)
    assert len(calls) == 1


def bump_cut():
    """The unit cube (B) and the height field z = 0.7 + 0.4 b(x) b(y) (S, b a bump, 0 on the sides).

    S reaches z = 1.1 and leaves the cube through its top face; component 1 is above S.
    """
    BV, BF = box((0, 0, 0), (1, 1, 1), (10, 10, 10))
    n = 9
    x, y = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    x, y = x.ravel(), y.ravel()
    V = np.stack([x, y, 0.7 + 6.4 * x * (1 - x) * y * (1 - y)], 1)
    F = grid_faces(n + 1, n + 1)
    up = np.cross(V[F[0, 1]] - V[F[0, 0]], V[F[0, 2]] - V[F[0, 0]])[2] > 0
    sides = np.tile([0, 1] if up else [1, 0], (len(F), 1))
    return BV, BF, FractureSurface.from_coarse(V, F, sides)


def test_a_surface_leaving_b_makes_pieces_without_crossings():
    # S (bump_cut) leaves the unit cube through its top face. The piece
    # above S would enclose an inverted pocket: resolved, it is the
    # positive part of its winding number.
    import igl
    BV, BF, mesh = bump_cut()
    im = imprint_boundary(BV, BF, mesh)

    def labels(faces):
        return np.zeros(len(faces), np.int64)

    raw = build_pieces(im, mesh, 2, labels, resolve=False)
    pieces = build_pieces(im, mesh, 2, labels)
    assert mesh_checks(*raw.piece(1)[1:])["self_intersections"] > 0
    assert mesh_checks(*raw.piece(0)[1:])["self_intersections"] == 0
    assert pieces.resolved[0] == 0 and pieces.resolved[1] > 0 and pieces.unresolved == []
    for c in range(2):
        ch = mesh_checks(*pieces.piece(c)[1:])
        assert ch["closed_oriented"] and ch["vertex_manifold"] and ch["self_intersections"] == 0
    # the piece below S is untouched; the one above is where the raw piece winds positively
    assert np.array_equal(np.sort(pieces.piece(0)[1], axis=0), np.sort(raw.piece(0)[1], axis=0))
    P = np.random.default_rng(1).random((20000, 3)) * [1, 1, 1.3]
    _, RV, RF = raw.piece(1)
    _, QV, QF = pieces.piece(1)
    w_raw = igl.winding_number(RV, RF, P)
    w_new = igl.winding_number(QV, QF, P)
    assert (w_raw < -0.5).sum() > 50  # the pocket
    near = np.abs(np.abs(w_raw) - 0.5) < 0.45  # away from the surfaces
    assert np.allclose(np.round(w_new[near]), np.maximum(np.round(w_raw[near]), 0))
    # the new vertices lie on S's triangles, with barycentric weights over their corners
    ns, nf = pieces.n_surface, pieces.n_fracture
    assert nf > ns and np.allclose(pieces.derived @ pieces.V[:ns], pieces.V[ns:nf], atol=1e-12)
    assert np.allclose(np.asarray(pieces.derived.sum(axis=1)).ravel(), 1.0)
    W = pieces.fracture_tree(mesh.tree_matrix())
    assert W.shape == (nf, mesh.n_coarse) and np.allclose(W @ mesh.V[:mesh.n_coarse], pieces.V[:nf], atol=1e-9)


def test_a_pinch_vertex_is_split_into_one_copy_per_fan():
    from fracture.pieces.assembly import split_pinches
    # two tetrahedra touching at vertex 0: closed, oriented, but not vertex-manifold there
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, 0, 0], [0, -1, 0], [0, 0, -1]], float)
    tet = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    F = np.vstack([tet, (tet + 3 * (tet > 0))[:, ::-1]])  # the second is the first reflected through 0
    before = mesh_checks(V, F)
    assert before["closed_oriented"] and not before["vertex_manifold"]
    V2, F2 = split_pinches(V, F)
    after = mesh_checks(V2, F2)
    assert after["closed_oriented"] and after["vertex_manifold"] and after["self_intersections"] == 0
    assert len(V2) == 8 and np.array_equal(V2[:7], V)
    # one fan keeps vertex 0, the other its copy, moved 1e-3 of the way into one of its triangles
    fans = [set(np.flatnonzero((F2 == v).any(axis=1)).tolist()) for v in (0, 7)]
    assert sorted(map(sorted, fans)) == [[0, 1, 2], [4, 5, 6]]
    assert 0 < np.linalg.norm(V2[7]) < 1e-3
    assert before["volume"] == pytest.approx(2 / 6) and after["volume"] == pytest.approx(2 / 6, rel=1e-2)


def test_bridge_edges_along_b_are_split_into_the_material():
    # two triangles of S hinge on an edge lying in B's bottom face (both its
    # ends on S's boundary): the triangles would touch B along it
    BV, BF = box((0, 0, 0), (1, 1, 1), (4, 4, 4))
    V = np.array([[0.2, 0.5, 0.0], [0.8, 0.5, 0.0], [0.5, 0.2, 0.3], [0.5, 0.8, 0.3]])
    mesh = FractureSurface.from_coarse(V, np.array([[0, 1, 2], [1, 0, 3]]), np.array([[0, 1], [0, 1]]))
    assert split_bridge_edges(mesh, Exterior(BV, BF)) == 1
    # the new vertex is the bridge's midpoint lowered to BRIDGE_DEPTH x its length inside B
    assert np.allclose(mesh.V[4], [0.5, 0.5, BRIDGE_DEPTH * 0.6])
    assert len(mesh.F) == 4 and not any({0, 1} <= set(f) for f in mesh.F.tolist())
    W = mesh.tree_matrix()
    assert np.allclose(W[4].toarray(), [[0.5, 0.5, 0, 0]])
    # an interior bridge already deep enough stays at its midpoint
    V2 = np.array([[0.5, 0.0, 0.5], [0.5, 1.0, 0.5], [0.5, 0.5, 0.0], [0.5, 0.5, 1.0]])
    mesh2 = FractureSurface.from_coarse(V2, np.array([[0, 1, 2], [1, 0, 3]]), np.array([[0, 1], [0, 1]]))
    split_bridge_edges(mesh2, Exterior(BV, BF))
    assert np.allclose(mesh2.V[4], [0.5, 0.5, 0.5])


def test_boundary_splits_beside_a_vertex_off_b_put_no_two_vertices_in_one_place():
    """A boundary vertex a collision kept off B, outside the cube's corner, and one on the corner: every
    point of the edge between them has the corner as its closest point of B, so each split of the edge
    (its midpoint is off B) put a new vertex on the other one, round after round. Splits that take no
    new point of B are not made; the edges along B are split as before."""
    BV, BF = box((0, 0, 0), (1, 1, 1), (4, 4, 4))
    V = np.array([[1.05, 1.05, 1.05], [1.0, 1.0, 1.0], [0.8, 0.8, 0.9]])
    mesh = FractureSurface.from_coarse(V, np.array([[0, 1, 2]]), np.array([[0, 1]]))
    made = subdivide_boundary(mesh, Exterior(BV, BF), 0.01)
    assert made > 0
    gaps = np.linalg.norm(mesh.V[:, None] - mesh.V[None], axis=2) + np.eye(len(mesh.V))
    assert gaps.min() > 1e-6


def test_an_ear_that_turns_the_boundary_back_on_itself_is_clipped():
    """An ear of S over the cube's edge whose two boundary edges meet at 6 degrees (on a random Blender
    Suzanne export such a needle's two traces on B ran into each other): it goes, the ears beside it whose
    edges open wider stay."""
    BV, BF = box((0, 0, 0), (1, 1, 1), (4, 4, 4))
    a, t, b = [0.9, 0.5, 1.0], [1.0, 0.5, 0.9], [0.92, 0.5, 1.0]
    c, d, e = [0.91, 0.5, 0.8], [0.9, 0.45, 0.9], [0.92, 0.55, 0.9]
    V = np.array([a, t, b, c, d, e])
    F = np.array([[0, 1, 2], [2, 0, 3], [0, 4, 3], [2, 3, 5]])
    mesh = FractureSurface.from_coarse(V, F, np.tile([0, 1], (4, 1)))
    assert clip_tangent_triangles(mesh, Exterior(BV, BF)) == 1
    assert sorted(map(sorted, mesh.F.tolist())) == sorted(map(sorted, F[1:].tolist()))


def test_an_ear_whose_chord_would_cross_another_crack_on_b_is_kept():
    """An ear of S lying on the cube's top face (it would be clipped) whose third side, left as S's boundary
    without it, would cross another crack's rim on B (on Blender's suzanne_10 at 20,000 triangles an ear
    over a crease of the head went around the end of another crack, and the traces met): it stays; without
    the other crack it goes."""
    BV, BF = box((0, 0, 0), (1, 1, 1), (4, 4, 4))
    p, t, q, w = [0.3, 0.5, 1.0], [0.5, 0.8, 1.0], [0.7, 0.5, 1.0], [0.5, 0.5, 0.6]
    r, s, u = [0.5, 0.45, 1.0], [0.5, 0.6, 1.0], [0.5, 0.2, 0.7]
    V = np.array([p, t, q, w, r, s, u])
    F = np.array([[0, 1, 2], [2, 3, 0], [4, 5, 6]])
    sides = np.array([[0, 1], [0, 1], [1, 2]])
    alone = FractureSurface.from_coarse(V, F[:2], sides[:2])
    assert clip_tangent_triangles(alone, Exterior(BV, BF)) == 1
    crossed = FractureSurface.from_coarse(V, F, sides)
    assert clip_tangent_triangles(crossed, Exterior(BV, BF)) == 0 and len(crossed.F) == 3


def test_obj_frames_round_trip(tmp_path):
    V0, F0 = box((0, 0, 0), (1, 1, 1))
    V1, F1 = box((2, 0, 0), (3, 1, 1), (2, 1, 1))
    w = ObjFrames(["Cube_cell", "Cube_cell.001"], [F0, F1], [len(V0), len(V1)])
    w.write(tmp_path / "f.obj", [V0, V1])
    names, V, polys = read_obj_objects(tmp_path / "f.obj")
    assert names == ["Cube_cell", "Cube_cell.001"]
    assert np.allclose(V, np.concatenate([V0, V1]), atol=1e-6)
    assert np.array_equal(np.array(polys[1]) - len(V0), F1)
    with pytest.raises(ValueError, match="Cube_cell.001"):
        w.write(tmp_path / "g.obj", [V0, V1[:-1]])


@pytest.mark.slow
def test_the_example_run_writes_pieces_and_frames(tmp_path):
    cfg = load_config(CONFIGS / "example.yaml", ["animate.ply_frames=true", "animate.obj_frames=true"])
    out = runner.run(cfg, tmp_path / "run", progress=False)
    manifest = json.loads((out / "manifest.json").read_text())
    a = manifest["stats"]["animate"]
    n = manifest["counts"]["components"]
    assert manifest["counts"]["pieces"] == n
    assert manifest["stats"]["coarse"]["up_axis"] == "y"  # the config's: the wall stands
    for c in range(n):
        V, F, vdata, fdata = read_ply(out / "pieces" / f"piece_{c:03d}.ply")
        ch = mesh_checks(V, F, intersections=False)
        assert ch["closed_oriented"] and ch["vertex_manifold"] and ch["volume"] > 0
        assert set(np.unique(fdata["exterior"])) == {0, 1} and len(vdata["fracture_time"]) == len(V)
    assert a["volume_relative_error"] < 1e-9 and a["overlap_share"] == 0
    assert a["hausdorff_first_frame_relative"] < 1e-3 and a["early_gap_max"] == 0
    frames = sorted((out / "frames").glob("frame_*.obj"))
    assert len(frames) == manifest["counts"]["frames"] and frames[0].name == "frame_0001.obj"
    assert (out / "frames" / "frame_0001.ply").is_file()
    # the faces in two materials: the object's surface and the fracture
    text = frames[0].read_text()
    assert text.count("usemtl exterior") == n and text.count("usemtl interior") == n
    assert "mtllib materials.mtl" in text and "newmtl interior" in (out / "frames" / "materials.mtl").read_text()


@pytest.mark.slow
@pytest.mark.parametrize("name", SCENE_CASES)
def test_every_scene_refines_cleanly_and_animates_into_closed_pieces(name, tmp_path):
    """Each built-in scene and the Blender sample end to end at a small budget, one run for both halves:
    the refined surface is clean on B and separates the components; the pieces are closed and move."""
    cfg = scene_config(name, [f"refine.max_triangles={BUDGETS.get(name, 6000)}", "refine.iterations=8",
                              "animate.check_samples=4000", "animate.obj_frames=true"])
    out = runner.run(cfg, tmp_path / "run", progress=False)
    manifest = json.loads((out / "manifest.json").read_text())
    _refined_surface_is_clean(out, manifest, name)
    a, counts = manifest["stats"]["animate"], manifest["counts"]
    for p in a["pieces"]:
        assert p["closed_oriented"] and p["vertex_manifold"] and p["volume"] > 0
        assert p["self_intersections"] == 0
    assert a["volume_relative_error"] < 0.005 and a["overlap_share"] == 0
    assert a["hausdorff_first_frame_relative"] < 1e-3
    assert a["early_gap_max"] == 0
    frames = sorted((out / "frames").glob("frame_*.obj"))
    assert len(frames) == counts["frames"]
    # the pieces come back under the coarse pieces' names, with the pieces' vertex counts
    names, V, _ = read_obj_objects(frames[-1])
    assert len(names) == counts["pieces"] == counts["components"]
    assert len(V) == sum(len(read_ply(out / "pieces" / f"piece_{c:03d}.ply")[0]) for c in range(counts["pieces"]))
    if name == "blender_cube8":  # Blender's own object names, in and out
        assert names == read_obj_objects(SAMPLE / "frame_0001.obj")[0]
        assert len(frames) == 40


def _refined_surface_is_clean(out, manifest: dict, name: str) -> None:
    """The refine stage's checks of a run: its log, no crossings in space or on B, every component still
    separated from its neighbours, its snapshots."""
    stats, counts = manifest["stats"]["refine"], manifest["counts"]
    # (the branch's psi varies only across the axis, and its extended cut already follows B: in
    # eight iterations nothing of it is split)
    assert counts["refined_fracture_triangles"] > counts["coarse_fracture_triangles"] or name == "branch"
    assert counts["refined_fracture_triangles"] >= counts["coarse_fracture_triangles"]
    assert 1 <= counts["iterations"] <= 8 and len(stats["functional"]) == counts["iterations"] + 1
    assert len(stats["energy"]) == len(stats["area"]) == len(stats["stage"]) == counts["iterations"] + 1
    assert stats["self_intersecting_pairs"] == 0
    assert stats["max_boundary_distance"] < 1e-6
    assert "seconds" in manifest["stages"]["refine"]
    # no accepted step raises the functional the flow minimises (the search's entries are no flow steps: its
    # surface, or a polish given back for it, is chosen on dense samples)
    E, before = np.array(stats["functional"]), np.array(stats["functional_before_step"])
    step = np.array(stats["stage"]) != SEARCH_STAGE
    assert (E <= before + tol.functional_rise * np.abs(before))[step].all()
    assert stats["stopped_because"].startswith(("settled", "iterations", "stage iterations"))

    V, F, _, face = read_ply(out / "refined" / "fracture_surface.ply")
    assert self_intersections(V, F) == 0  # recounted from the file
    # no two boundary curves cross on B (the pieces could not be cut out of B along both)
    BV, BF = read_ply(out / "coarse" / "exterior.ply")[:2]
    B = Exterior(BV, BF)
    E = row_edges(F, edge_table(F, len(V)).boundary_rows)
    assert len(crossing_pairs(V, E, B.normal_at)) == 0
    sides = np.column_stack([face["side0"], face["side1"]])
    assert (sides[:, 0] != sides[:, 1]).all()
    # every component still separated from its neighbours: a volumetric flood
    # fill of B cut by the refined surface finds the same components
    resolution = 240  # finer than the closest sheets the refinement makes
    labels, _, n = label_components(BV, BF, V, F, resolution=resolution, strict=False)
    assert n == counts["components"]
    # a side is read a voxel off the triangle: only a triangle smaller than a voxel
    # inside a junction (every edge on three or more sheets) may read the same
    # component on both sides, and none of them may separate what the rest does not
    same = np.flatnonzero(labels[:, 0] == labels[:, 1])
    voxel = float(np.ptp(BV, axis=0).max()) / resolution
    T = V[F[same]]
    areas = 0.5 * np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1)
    junction = (edge_table(F, len(V)).row_count.reshape(-1, 3)[same] >= 3).all(axis=1)
    assert (areas < voxel ** 2).all() and junction.all() and len(same) <= 0.001 * len(F)

    snaps = load_snapshots(out)
    assert len(snaps) == counts["iterations"] + 1
    assert len(snaps[-1]["faces"]) == len(F) and snaps[0]["faces"].max() < len(snaps[0]["positions"])


def test_pieces_are_verified_before_a_run_succeeds():
    from fracture.errors import ResultError
    from fracture.pieces.checks import verify_pieces

    V, F = box((0, 0, 0), (1, 1, 1), (2, 2, 2))
    good = mesh_checks(V, F)
    checks = lambda *pieces, **kw: {"pieces": list(pieces), "volume_B": 2.0, "volume_pieces": 2.0,  # noqa: E731
                                    "volume_relative_error": 0.0, "overlap_share": 0.0, **kw}
    verify_pieces(checks(good, good), ["a", "b"])  # two unit cubes in a box of volume 2
    with pytest.raises(ResultError, match=r"piece 1 \(b\) is not closed"):
        verify_pieces(checks(good, mesh_checks(V, F[1:])), ["a", "b"])
    with pytest.raises(ResultError, match=r"piece 0 \(a\) has volume -1.*inside out"):
        verify_pieces(checks(mesh_checks(V, F[:, ::-1]), good), ["a", "b"])
    with pytest.raises(ResultError, match=r"piece 0 \(a\) crosses itself \(3 triangle"):
        verify_pieces(checks({**good, "self_intersections": 3}, good), ["a", "b"])
    # a piece whose surface wraps its space twice: its volume is twice what its winding number encloses
    twice = {**good, "volume": 2.0, "volume_sampled": 1.0}
    with pytest.raises(ResultError, match=r"piece 0 \(a\): its volume 2 disagrees with the 1"):
        verify_pieces(checks(twice, good, samples_inside=20000), ["a", "b"])
    verify_pieces(checks({**good, "volume_sampled": 1.01}, good, samples_inside=20000), ["a", "b"])
    with pytest.raises(ResultError, match="hold 1.9 of volume where the object has 2"):
        verify_pieces(checks(good, good, volume_pieces=1.9, volume_relative_error=0.05), ["a", "b"])
    with pytest.raises(ResultError, match="2 % of the object lies in two pieces"):
        verify_pieces(checks(good, good, overlap_share=0.02), ["a", "b"])


def test_welding_removes_the_slivers_a_boolean_rounds_into_crossings():
    from fracture.pieces.assembly import weld_rounded

    V, F = box((0, 0, 0), (1, 1, 1), (3, 3, 3))
    # a copy of vertex 0 within rounding of it, and a sliver triangle on the pair
    V = np.concatenate([V, V[:1] + 1e-17])
    F2 = np.concatenate([F, [[0, len(V) - 1, 5]]])
    F3 = np.where(F2 == 0, len(V) - 1, F2)  # the copy takes the place of 0 in every triangle but the sliver
    F3[-1] = [0, len(V) - 1, 5]
    J = np.arange(len(F3))
    FW, JW = weld_rounded(V, F3, J)
    assert len(FW) == len(F) and np.array_equal(JW, J[:-1])
    assert np.array_equal(FW, F)  # the group takes its lowest vertex, 0
    assert mesh_checks(V, FW)["closed_oriented"]


def _fan_and_flap(y_height: float):
    """S: a fan of three triangles around an inner vertex w, on B's bottom face, plus two flat triangles.

    T = (a, c, x) lies on B with one boundary edge (x, a); U = (x, c, y)
    is an ear (two boundary edges) standing ``y_height`` above B at y.
    """
    a, b, c = [0.3, 0.3, 0.0], [0.5, 0.2, 0.0], [0.6, 0.5, 0.0]
    w, x, y = [0.47, 0.33, 0.3], [0.4, 0.6, 0.0], [0.6, 0.75, y_height]
    V = np.array([a, b, c, w, x, y])
    F = np.array([[3, 0, 1], [3, 1, 2], [3, 2, 0], [0, 2, 4], [4, 2, 5]])
    return FractureSurface.from_coarse(V, F, np.tile([0, 1], (len(F), 1)))


def test_only_ears_along_b_are_clipped_so_s_keeps_its_fans():
    import igl

    from fracture.pieces.imprint import clip_tangent_triangles
    BV, BF = box((0, 0, 0), (1, 1, 1), (4, 4, 4))
    # T lies on B but is not an ear: removing it would split c's fan (a pinch
    # cutting the fan around w off S); its bridges are split instead
    standing = _fan_and_flap(0.3)
    assert clip_tangent_triangles(standing, Exterior(BV, BF)) == 0 and len(standing.F) == 5
    # with U lying on B too, U goes, which makes T an ear, and T goes next
    lying = _fan_and_flap(0.0)
    assert clip_tangent_triangles(lying, Exterior(BV, BF)) == 2
    assert sorted(map(sorted, lying.F.tolist())) == [[0, 1, 3], [0, 2, 3], [1, 2, 3]]
    assert np.asarray(igl.is_vertex_manifold(lying.F)).all()


def test_a_refused_resolution_is_retried_from_jittered_positions(monkeypatch):
    # the bump cut, with the first resolution refused (as the boolean's rounding can refuse one)
    import fracture.pieces.assembly as fp
    BV, BF, mesh = bump_cut()
    im = imprint_boundary(BV, BF, mesh)
    raw = build_pieces(im, mesh, 2, lambda faces: np.zeros(len(faces), np.int64), resolve=False)

    real, calls = fp.resolve_crossings, []

    def refuse_first(*args, **kwargs):
        calls.append(args[0])
        return None if len(calls) == 1 else real(*args, **kwargs)

    monkeypatch.setattr(fp, "resolve_crossings", refuse_first)
    pieces = fp._resolve_pieces(raw)
    assert pieces.jitter_seed == 1 and pieces.unresolved == [] and len(calls) == 2
    # every vertex moved by at most the jitter, the same for both pieces (one shared array)
    ns = raw.n_fracture
    moved = np.abs(pieces.V[:ns] - raw.V[:ns]).max()
    assert 0 < moved <= fp.JITTERS[0] * np.linalg.norm(np.ptp(raw.V, axis=0))  # the first, smallest jitter
    for c in range(2):
        ch = mesh_checks(*pieces.piece(c)[1:])
        assert ch["closed_oriented"] and ch["vertex_manifold"] and ch["self_intersections"] == 0
    overlap, uncovered, _, _ = overlap_and_gap(pieces, BV, BF, 4000, np.random.default_rng(0))
    assert overlap < 0.005
    # deterministic: the same seed, the same positions
    calls.clear()
    again = fp._resolve_pieces(raw)
    assert np.array_equal(again.V, pieces.V)


def test_vertices_made_on_s_follow_their_corners_or_else_their_own_piece():
    import scipy.sparse as sp

    from fracture.pieces.transfer import shared_components

    # S: vertices 0-3; made on S triangles: 4 (corners 0, 1, 2) and 5 (corners 2, 3, 0)
    # piece 0 holds 0, 1 and 4; piece 1 holds 1 and 5; 2 and 3 (outside B) belong to no piece
    V = np.zeros((8, 3))
    derived = sp.csr_matrix(np.array([[0.2, 0.3, 0.5, 0.0], [0.4, 0.0, 0.3, 0.3]]))
    # vertex 5's corners: 0 is held by piece 0 only, so it follows piece 0
    faces = [np.array([[0, 1, 4], [0, 4, 6]]), np.array([[1, 5, 7]])]
    pieces = Pieces(V=V, n_fracture=6, faces=faces, exterior=[np.zeros(2, bool), np.zeros(1, bool)],
                    patch_agreement=1.0, derived=derived)
    assert shared_components(pieces, 2).tolist() == [0, 0, 2, 2, 0, 0]
    # with no held corner, vertex 5 follows the one piece that holds it
    derived = sp.csr_matrix(np.array([[0.2, 0.3, 0.5, 0.0], [0.0, 0.0, 0.5, 0.5]]))
    pieces = Pieces(V=V, n_fracture=6, faces=faces, exterior=pieces.exterior, patch_agreement=1.0,
                    derived=derived)
    assert shared_components(pieces, 2).tolist() == [0, 0, 2, 2, 0, 1]
