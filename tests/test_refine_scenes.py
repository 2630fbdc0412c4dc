"""Refinement on the five built-in scenes and the Blender sample (the refine stage end to end)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import CONFIGS, SCENE_CASES, scene_config

from fracture import runner
from fracture.components import label_components
from fracture.config import load_config
from fracture.plyio import read_ply
from fracture.refine.collide import self_intersections
from fracture.refine.engine import RefineParams, Refiner
from fracture.refine.mesh import RefineMesh
from fracture.scenes import build_scene
from fracture.stages.fields import fields_from_config
from fracture.stages.refine import load_snapshots

@pytest.mark.parametrize("name", SCENE_CASES)
def test_refined_surface_is_clean_on_b_and_separates_the_components(name, tmp_path):
    cfg = scene_config(name, ["refine.max_triangles=6000", "refine.iterations=8"])
    out = runner.run(cfg, tmp_path / "run", until="refine", progress=False)
    manifest = json.loads((out / "manifest.json").read_text())
    stats, counts = manifest["stats"]["refine"], manifest["counts"]
    assert counts["refined_fracture_triangles"] > counts["coarse_fracture_triangles"]
    assert 1 <= counts["iterations"] <= 8 and len(stats["energy"]) == counts["iterations"]
    assert stats["self_intersecting_pairs"] == 0
    assert stats["max_boundary_distance"] < 1e-6
    assert "seconds" in manifest["stages"]["refine"]
    # the loop ends when the moves are small, or once the budget is spent and the energy rises
    if stats["stopped_because"] == "moves below tolerance":
        assert stats["mean_move_cells"][-1] < cfg["refine"]["tolerance"]
    elif stats["stopped_because"].startswith("triangle budget spent"):
        assert stats["triangles"][-1] > 0.9 * 6000 and stats["energy"][-1] > stats["energy"][-2]
    else:
        assert stats["stopped_because"] == "iterations" and counts["iterations"] == 8

    V, F, _, face = read_ply(out / "refined" / "fracture_surface.ply")
    assert self_intersections(V, F) == 0  # recounted from the file
    sides = np.column_stack([face["side0"], face["side1"]])
    assert (sides[:, 0] != sides[:, 1]).all()
    # every component still separated from its neighbours: a volumetric flood
    # fill of B cut by the refined surface finds the same components
    BV, BF = read_ply(out / "coarse" / "exterior.ply")[:2]
    _, _, n = label_components(BV, BF, V, F, resolution=160)
    assert n == counts["components"]

    snaps = load_snapshots(out)
    assert len(snaps) == counts["iterations"] + 1
    assert len(snaps[-1]["faces"]) == len(F) and snaps[0]["faces"].max() < len(snaps[0]["positions"])


@pytest.mark.parametrize("name", ["wall", "branch"])
def test_the_tree_reproduces_every_vertex_when_nothing_moves(name):
    cf = build_scene(name, 0, 8)
    cfg = load_config(CONFIGS / f"{name}.yaml", ["input.frames=8", "seed=0"])
    fs = fields_from_config(cfg, cf.exterior_V, cf.V, cf.F)
    mesh = RefineMesh.from_coarse(cf.V, cf.F, cf.sides)
    r = Refiner(mesh, fs.pyramid, cf.exterior_V, cf.exterior_F, RefineParams(max_triangles=8000),
                np.random.default_rng(0))
    for _ in range(4):  # splits only: the flow's moves are left out
        table = r.edges()
        v, psi, _ = r._velocity(table)
        r.remesh(table, v, psi, r._step_size(v, np.ones(len(mesh.V), bool)))
    assert len(mesh.F) > 4 * len(cf.F)
    W = mesh.tree_matrix()
    assert np.allclose(np.asarray(W.sum(axis=1)).ravel(), 1.0) and W.min() >= 0
    assert np.allclose(W @ mesh.V[: mesh.n_coarse], mesh.V)
    assert np.allclose(np.concatenate(mesh.created), mesh.V[mesh.n_coarse:])
