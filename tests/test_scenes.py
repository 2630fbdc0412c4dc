"""The built-in scenes: coarse fracture surfaces, components and animations."""

from __future__ import annotations

import igl
import numpy as np
import pytest

from fracture.coarse.components import label_components
from fracture.errors import InputError
from fracture.coarse.scenes import PAPER_TRIANGLES, SCENES, half_disk, build_scene
from fracture.mesh.primitives import cylinder
from fracture.mesh.topology import unique_edges

FRAMES = 30


@pytest.fixture(scope="module")
def scenes():
    return {}


def scene(cache, name):
    if name not in cache:
        cache[name] = build_scene(name, seed=0, frames=FRAMES)
    return cache[name]


@pytest.mark.parametrize("name", SCENES)
def test_scene_is_a_consistent_coarse_fracture(scenes, name):
    cf = scene(scenes, name)
    diag = np.linalg.norm(np.ptp(cf.exterior_V, axis=0))
    # exterior closed, every component owns a part of it
    _, count = unique_edges(cf.exterior_F)
    assert (count == 2).all()
    assert set(np.unique(cf.exterior_component)) == set(range(cf.n_components))
    # every fracture triangle separates two different components
    assert (cf.sides[:, 0] != cf.sides[:, 1]).all()
    assert cf.sides.min() >= 0 and cf.sides.max() < cf.n_components
    # the boundary of the coarse fracture surface lies on B
    sp = cf.special()
    d2, _, _ = igl.point_mesh_squared_distance(cf.V[sp.boundary_vertices], cf.exterior_V, cf.exterior_F)
    assert np.sqrt(d2).max() < 1e-9 * diag
    # about the paper's size
    real = int((~cf.virtual).sum())
    assert 0.6 * PAPER_TRIANGLES[name] <= real <= 1.6 * PAPER_TRIANGLES[name]


@pytest.mark.parametrize("name", SCENES)
def test_scene_components_agree_with_a_volumetric_flood_fill(scenes, name):
    cf = scene(scenes, name)
    sides, ext, n = label_components(cf.exterior_V, cf.exterior_F, cf.V, cf.F, resolution=128)
    assert n == cf.n_components
    mapping = {}
    for a, b in zip(sides.ravel(), cf.sides.ravel()):
        assert mapping.setdefault(a, b) == b
    assert len(set(mapping.values())) == n


@pytest.mark.parametrize("name", SCENES)
def test_scene_breaks_during_the_animation(scenes, name):
    cf = scene(scenes, name)
    anim = cf.animation
    assert anim.n_frames == FRAMES
    # frame 0 is the rest pose
    for c in range(cf.n_components):
        X = cf.exterior_V[np.unique(cf.exterior_F[cf.exterior_component == c])]
        assert np.allclose(anim.deform(c, 0, X), X, atol=1e-9)
    opened = cf.face_fracture_time[cf.face_fracture_time < FRAMES]
    assert len(opened) and opened.min() > 0
    assert (cf.face_fracture_time[cf.virtual] == FRAMES).all()


@pytest.mark.parametrize("name", ["bunny", "wall"])
def test_rigid_pieces_stay_above_the_ground(scenes, name):
    cf = scene(scenes, name)
    up = 1
    ground = {"bunny": cf.exterior_V[:, up].min() - 0.25, "wall": 0.0}[name]
    for c in range(cf.n_components):
        X = cf.exterior_V[np.unique(cf.exterior_F[cf.exterior_component == c])]
        Y = cf.animation.trajectories(c, X)
        assert Y[..., up].min() > ground - 1e-4  # contacts are resolved per substep
        # rigid: distances between points are kept in every frame
        d0 = np.linalg.norm(X[1:] - X[0], axis=1)
        dT = np.linalg.norm(Y[-1, 1:] - Y[-1, 0], axis=1)
        assert np.allclose(d0, dT, atol=1e-6)


def test_scenes_are_deterministic():
    a, b = build_scene("jello", seed=3, frames=8), build_scene("jello", seed=3, frames=8)
    assert np.array_equal(a.V, b.V) and np.array_equal(a.F, b.F)
    assert np.array_equal(a.animation.nodes, b.animation.nodes)
    c = build_scene("jello", seed=4, frames=8)
    assert not np.array_equal(a.V, c.V)


def test_virtual_fracture_separates_the_branch(scenes):
    cf = scene(scenes, "branch")
    assert cf.n_components == 2 and cf.virtual.any() and (~cf.virtual).any()
    # the points above and below the cut's plane are in different components
    top = cf.exterior_component[np.argmax(cf.exterior_V[cf.exterior_F].mean(axis=1)[:, 2])]
    bottom = cf.exterior_component[np.argmin(cf.exterior_V[cf.exterior_F].mean(axis=1)[:, 2])]
    assert top != bottom
    # the real cut opens as the branch bends, the extension does not
    assert (cf.face_fracture_time[~cf.virtual] < FRAMES).any()


def test_the_incomplete_cut_alone_does_not_separate_the_branch():
    BV, BF = cylinder(0.5, 2.0, segments=48, rings=33)
    BV[:, 2] -= 1.0
    V, F = half_disk(0.5, 0.16)
    with pytest.raises(InputError, match="does not split the object"):
        label_components(BV, BF, V, F)


def test_unknown_scene_is_named():
    with pytest.raises(InputError, match="unknown scene 'cake'"):
        build_scene("cake")


def test_until_coarse_writes_the_coarse_stage_of_a_scene(tmp_path):
    import json

    from conftest import CONFIGS
    from fracture.pipeline import runner
    from fracture.pipeline.config import load_config
    from fracture.io.ply import read_ply

    cfg = load_config(CONFIGS / "branch.yaml", ["input.frames=12"])
    out = runner.run(cfg, tmp_path / "run", until="coarse", progress=False)
    manifest = json.loads((out / "manifest.json").read_text())
    assert list(manifest["stages"]) == ["coarse"]
    assert manifest["counts"]["components"] == 2 and manifest["counts"]["frames"] == 12
    V, F, vdata, fdata = read_ply(out / "coarse/fracture_surface.ply")
    assert len(F) == manifest["counts"]["coarse_fracture_triangles"]
    assert (fdata["side0"] != fdata["side1"]).all() and fdata["virtual"].any()


def test_meshes_input_extends_an_incomplete_cut(tmp_path):
    from fracture.io.obj import write_obj
    from fracture.mesh.primitives import box, sheet
    from fracture.pipeline.stages.coarse import coarse_from_meshes

    V, F = box([0, 0, 0], [2, 1, 0.5], (8, 4, 2))
    # a cut at x = 1 through the lower 60 % of the slab only
    SV, SF = sheet(lambda u, v: np.stack([np.ones_like(u), u, v], 1), (0, 0.6), (0, 0.5), 4, 3)
    write_obj(tmp_path / "slab.obj", V, F)
    write_obj(tmp_path / "cut.obj", SV, SF)
    inp = {"exterior": str(tmp_path / "slab.obj"), "fracture": str(tmp_path / "cut.obj"), "separation": 1e-3}
    cf = coarse_from_meshes(inp)
    assert cf.n_components == 2 and cf.virtual.any()
    assert cf.n_frames == 1 and (cf.face_fracture_time == 1).all()  # a still object never separates
    left = cf.exterior_component[np.argmin(cf.exterior_V[cf.exterior_F].mean(axis=1)[:, 0])]
    right = cf.exterior_component[np.argmax(cf.exterior_V[cf.exterior_F].mean(axis=1)[:, 0])]
    assert left != right


def test_a_region_no_crack_bounds_joins_the_piece_beside_it_on_b():
    """Labels as the labelling grid once gave them (random cut case 99): a cut between pieces 0 and 2 only,
    and a region 1 of B that no crack bounds beside piece 0. It joins 0 (most shared edges); a region on a
    shell of its own (a second box) has no piece beside it and stays."""
    from fracture.coarse.components import join_uncut
    from fracture.mesh.primitives import box

    V, F = box(np.zeros(3), np.ones(3), (4, 4, 4))
    centres = V[F].mean(axis=1)
    ext = np.where(centres[:, 0] > 0.75, 2, np.where(centres[:, 1] > 0.75, 1, 0))
    sides = np.array([[0, 2]] * 5)
    out_sides, out_ext, n, joined = join_uncut(F, sides, ext, 3)
    assert (n, joined) == (2, 1)
    assert (out_sides == [0, 1]).all()
    assert np.array_equal(out_ext, np.where(ext == 2, 1, 0))
    # a second shell, all region 3: nothing beside it on B
    V2, F2 = box(np.full(3, 2.0), np.full(3, 3.0))
    both = np.concatenate([F, F2 + len(V)])
    out_sides, out_ext, n, joined = join_uncut(both, sides, np.r_[ext, np.full(len(F2), 3)], 4)
    assert (n, joined) == (3, 1) and (out_ext[len(F):] == 2).all() and (out_sides == [0, 1]).all()
