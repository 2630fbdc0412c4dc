"""Refinement on the built-in scenes (the refine stage end to end); every scene's run through all stages is
checked in ``test_animate.py``."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import CONFIGS

from fracture.pipeline import runner
from fracture.pipeline.config import load_config
from fracture.fidelity import run_figures
from fracture.io.ply import read_ply
from fracture.refine.engine import RefineParams, Refiner
from fracture.mesh.fracture_surface import FractureSurface
from fracture.refine.remesh import plan_splits
from fracture.coarse.scenes import build_scene
from fracture.pipeline.stages.fields import fields_from_config


@pytest.mark.parametrize("name", ["wall", "branch"])
def test_the_tree_reproduces_every_vertex_when_nothing_moves(name):
    cf = build_scene(name, 0, 8)
    cfg = load_config(CONFIGS / f"{name}.yaml", ["input.frames=8", "seed=0"])
    fs = fields_from_config(cfg, cf.exterior_V, cf.V, cf.F)
    mesh = FractureSurface.from_coarse(cf.V, cf.F, cf.sides)
    r = Refiner(mesh, fs.pyramid, cf.exterior_V, cf.exterior_F, RefineParams(max_triangles=8000),
                np.random.default_rng(0))
    r.begin_stage(*r.stages()[-1])  # the last stage: level 0
    for _ in range(4):  # splits only: the flow's moves are left out
        table = r.edges()
        flow = r._velocity(table)
        v, w = flow.v, flow.w
        plan_splits(mesh.V, mesh.F, table, v, w, r.step.start, r.field, r.rng, near=r.near, far=0.0,
                    budget=8000 - len(mesh.F), off_b=r.onb.off_b).apply(mesh)
        r.state.grow(len(mesh.V))
    assert len(mesh.F) > 4 * len(cf.F)
    W = mesh.tree_matrix()
    assert np.allclose(np.asarray(W.sum(axis=1)).ravel(), 1.0) and W.min() >= 0
    assert np.allclose(W @ mesh.V[: mesh.n_coarse], mesh.V)
    assert np.allclose(np.concatenate(mesh.created), mesh.V[mesh.n_coarse:])


@pytest.fixture(scope="module")
def example_runs(tmp_path_factory):
    """The example wall refined with stress weights 0.2, 1.5 and 4 (at 40K triangles, a fifth of the default
    budget: the crack has reached the joints by then): run directories by weight."""
    base = tmp_path_factory.mktemp("example")
    runs = {}
    for b in (0.2, 1.5, 4.0):
        cfg = load_config(CONFIGS / "example.yaml", [f"psi.stress_weight={b}", "refine.snapshots=false",
                                                     "refine.max_triangles=40000"])
        runs[b] = runner.run(cfg, base / f"b{b}", until="refine", progress=False)
    return runs


@pytest.mark.slow
def test_the_stress_weight_controls_how_far_the_crack_travels(example_runs):
    """Section 4.2: a larger stress weight keeps the result closer to the coarse surface. On the example
    wall the refined crack's mean distance to the coarse one falls monotonically with the weight, at
    least threefold from 0.2 to 4."""
    distances = [run_figures(example_runs[b])["refined"]["distance_mean"] for b in (0.2, 1.5, 4.0)]
    assert distances[0] > distances[1] > distances[2]
    assert distances[0] > 3.0 * distances[2]


@pytest.mark.slow
def test_the_example_crack_follows_the_brick_mortar_boundaries(example_runs):
    """The paper's effect (Figs. 4, 10): the coarse crack crosses bricks; the refined one runs in the weak
    layers between bricks and mortar. Measured as the share of its area in the weakest 20 % of zeta inside
    the wall: at least 48 % (the coarse crack: 13 %), and at least three times the coarse crack's."""
    figures = run_figures(example_runs[0.2])
    coarse, refined = figures["coarse"]["weak_share_20"], figures["refined"]["weak_share_20"]
    assert refined >= 0.48 and refined >= 3.0 * coarse


def coarse_and_refined(name: str, budget: int, tmp_path) -> tuple[dict, dict]:
    """The fidelity figures (:func:`run_figures`) of a built-in scene's coarse and refined surfaces, refined
    at a triangle budget."""
    cfg = load_config(CONFIGS / f"{name}.yaml", [f"refine.max_triangles={budget}", "refine.snapshots=false"])
    figures = run_figures(runner.run(cfg, tmp_path / "run", until="refine", progress=False))
    return figures["coarse"], figures["refined"]


@pytest.mark.slow
def test_the_collapsing_walls_network_follows_the_brick_mortar_boundaries(tmp_path):
    """Fig. 10: the wrecking ball's coarse fracture network crosses bricks; the refined network runs along
    the head and bed joints' weak layers. At 40K triangles at least 44 % of its area lies in the weakest
    20 % of zeta (the coarse network: 15 %), and the mean strength on it falls by a third."""
    coarse, refined = coarse_and_refined("wall", 40000, tmp_path)
    assert refined["weak_share_20"] >= 0.44 and refined["weak_share_20"] >= 2.5 * coarse["weak_share_20"]
    assert refined["mean_zeta"] <= 0.67 * coarse["mean_zeta"]


@pytest.mark.slow
def test_the_marble_bunny_cracks_follow_the_soft_veins(tmp_path):
    """Fig. 1: the marble bunny's coarse cracks cross the hard, grainy body; the refined ones run in the
    soft veins. The weakest 20 % of zeta inside the bunny lie in the veins (a quarter of the stone): at
    least 30 % of the refined area lies there (the coarse cracks: 16 %), at least twice the coarse share,
    and the mean strength on the cracks falls by a fifth (a preview budget of 30K triangles), while every
    piece keeps at least half its coarse volume (the flow would take one from 24 % of the stone to 1 %)."""
    from fracture.io import layout
    from fracture.io.ply import read_ply
    from fracture.mesh.exterior import Exterior
    from fracture.refine.volumes import measure_volumes

    coarse, refined = coarse_and_refined("bunny", 30000, tmp_path)
    assert refined["weak_share_20"] >= 0.30 and refined["weak_share_20"] >= 2.0 * coarse["weak_share_20"]
    assert refined["mean_zeta"] <= 0.8 * coarse["mean_zeta"]
    run = tmp_path / "run"
    B, grid = Exterior(*layout.read_surface(run, layout.EXTERIOR)), layout.read_grid(run)

    def volumes(rel):
        V, F, _, faces = read_ply(run / rel)
        return measure_volumes(V, F, np.stack([faces["side0"], faces["side1"]], 1).astype(np.int64), B, grid)

    shares = volumes(layout.REFINED_SURFACE) / volumes(layout.COARSE_SURFACE)
    assert shares.min() >= 0.47, shares  # half, less the grid's error in the coarse volume
    assert min(layout.read_manifest(run)["stats"]["refine"]["piece_volume_shares"]) >= 0.49


@pytest.mark.slow
def test_the_marble_bunnys_search_leaves_every_piece_whole(tmp_path):
    """Some of the marble bunny's pieces keep their cores in several lobes, and its search's first cut goes
    through two of them between the lobes, every part anchored in a kept node: the searched surface would
    enclose more regions than the coarse one's seven. The search cuts again with those pieces holding their coarse nodes:
    the searched and the refined surfaces separate the seven pieces, each one region (a flood fill of B)."""
    from fracture.coarse.components import label_components
    from fracture.io import layout
    from fracture.io.snapshots import load_snapshots

    cfg = load_config(CONFIGS / "bunny.yaml", ["refine.search=graphcut", "refine.max_triangles=20000"])
    run = runner.run(cfg, tmp_path / "run", until="refine", progress=False)
    notes = layout.read_manifest(run)["notes"]
    assert any("search: the cut would split piece" in n for n in notes), notes  # (which pieces: the libraries' rounding)
    BV, BF = read_ply(run / layout.EXTERIOR)[:2]
    V, F = read_ply(run / layout.REFINED_SURFACE)[:2]
    searched = load_snapshots(run)[1]  # the log: coarse, searched, polished
    assert label_components(BV, BF, searched["positions"], searched["faces"], resolution=240, strict=False)[2] == 7
    assert label_components(BV, BF, V, F, resolution=240, strict=False)[2] == 7


@pytest.mark.slow
def test_the_branch_splinters_along_its_fibre_bundles(tmp_path):
    """Fig. 9: the branch's wood is bundles of fibres along its axis, each weak at its own heights, split
    along the fibres ten times more easily than across them. Its oblique coarse cut (35 degrees from the
    cross-section) becomes splinters: crossings of the bundles joined by walls that contain the axis,
    more area, and more of it in the weakest wood (a preview budget of 20K triangles)."""
    cfg = load_config(CONFIGS / "branch.yaml", ["refine.max_triangles=20000", "refine.snapshots=false"])
    out = runner.run(cfg, tmp_path / "run", until="refine", progress=False)

    def walls_and_area(which: str) -> tuple[float, float]:
        """The share of the area whose normal is more than 60 degrees off the axis, and the area."""
        V, F = read_ply(out / which / "fracture_surface.ply")[:2]
        T = V.astype(np.float64)[F]
        n = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
        area = np.linalg.norm(n, axis=1)
        return float(area[np.abs(n[:, 2]) < 0.5 * area].sum() / area.sum()), float(area.sum() / 2)

    (coarse_walls, coarse_area), (walls, area) = walls_and_area("coarse"), walls_and_area("refined")
    assert coarse_walls == 0.0  # the coarse cut: 35 degrees off the cross-section everywhere
    assert walls > 0.2 and area > 1.25 * coarse_area
    figures = run_figures(out)
    assert figures["refined"]["weak_share_20"] > figures["coarse"]["weak_share_20"] + 0.1
