"""The global search (fracture/refine/search.py): turned weak sheets that the flow cannot walk to are
reached, pieces stay whole, the tree carries the coarse vertices to the new surface, bad bands are said."""

from __future__ import annotations

import numpy as np
import pytest

from fields.grid import Grid
from fields.pyramid import StrengthPyramid
from fracture.coarse.scenes.weak_sheets import TURNED, weak_sheet_case
from fracture.fidelity import area_samples
from fracture.mesh.exterior import Exterior
from fracture.mesh.fracture_surface import FractureSurface
from fracture.mesh.intersect import self_intersections
from fracture.refine.engine import SEARCH_STAGE, RefineParams, Refiner
from fracture.mesh.primitives import box, sheet
from fracture.refine.search import _BoxGrid, _mend, _parts, _unanchored, graph_cut_search


def _coarse(case):
    return FractureSurface.from_coarse(case.cut_V, case.cut_F, np.tile([0, 1], (len(case.cut_F), 1)))


def _refine(case, **params):
    pyramid = StrengthPyramid(case.grid, case.zeta, levels=5, sigma=1.0)
    params = {"search": "graphcut", "max_triangles": 40000, **params}
    r = Refiner(_coarse(case), pyramid, case.BV, case.BF, RefineParams(**params),
                np.random.default_rng(0))
    return r, r.run()


@pytest.mark.slow
@pytest.mark.parametrize("angle, band", [(30, 16), (45, 24), (60, 40)])
def test_a_turned_weak_sheet_is_found_whole(angle, band):
    case = weak_sheet_case(TURNED, 4.0, angle=angle)
    r, log = _refine(case, band=band, core=0.5)  # the box holds half of each piece's depth beyond the sheet
    d = case.distance_to_sheet(area_samples(r.mesh.V, r.mesh.F))
    assert np.mean(d < 1.0) >= 0.9
    assert log.stage[1] == SEARCH_STAGE and log.search.surface is not None
    assert log.energy[-1] < 0.5 * log.energy[0]  # E(S) = integral of psi
    assert self_intersections(r.mesh.V, r.mesh.F) == 0
    if angle >= 45:  # the flow alone stays across the strong material for most of it
        alone, _ = _refine(case, search="none")
        assert np.mean(case.distance_to_sheet(area_samples(alone.mesh.V, alone.mesh.F)) < 1.0) < 0.8


def test_the_search_lowers_the_functional_and_hangs_every_vertex_on_the_coarse_surface():
    case = weak_sheet_case("curved", 6.0)
    pyramid = StrengthPyramid(case.grid, case.zeta, levels=5, sigma=1.0)
    mesh = _coarse(case)
    res = graph_cut_search(mesh, pyramid, Exterior(case.BV, case.BF), band=10, tension=0.05, core=0.5)
    S = res.surface
    assert S is not None and res.functional[1] < 0.5 * res.functional[0]
    assert res.cut_energy[1] < res.cut_energy[0]
    assert np.unique(S.F).size == len(S.V)  # every vertex in a triangle (the coarsening's leftovers gone)
    W = S.tree_matrix()
    assert W.shape == (len(S.V), len(case.cut_V))
    np.testing.assert_allclose(np.asarray(W.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    # every new vertex's tree position is its closest point on the coarse cut (the plane x = const)
    np.testing.assert_allclose((W @ case.cut_V)[:, 0], case.cut_V[0, 0], atol=1e-12)
    d = case.distance_to_sheet(area_samples(S.V, S.F))
    assert np.mean(d < 1.0) > 0.95
    assert (np.sort(S.sides, axis=1) == [0, 1]).all()


@pytest.mark.parametrize("kind", ["flat", "curved"])
def test_the_polished_search_ends_no_higher_than_the_flow_alone(kind):
    """The flat sheet lies on a plane of grid nodes: the cut's surface starts a seventh of a cell off it,
    where the moves are small from the first iteration, and the polish must not stop before it is on it."""
    case = weak_sheet_case(kind, 4.0)
    _, searched = _refine(case, max_triangles=12000)
    _, alone = _refine(case, max_triangles=12000, search="none")
    assert searched.search.surface is not None
    assert searched.sampled[1] <= alone.sampled[1]


def test_a_polish_that_raises_the_functional_on_dense_samples_gives_the_searched_surface_back():
    """A weak sheet turned 20 degrees from the cut: the search's surface (on the floor of psi's valley, with
    triangles of two cells) lies below the flow alone's on dense samples; the polish's flips across its
    creases raised it above. The searched surface is the result then, the log's last entry says so, and the
    refinement ends no higher than the flow alone."""
    case = weak_sheet_case(TURNED, 4.0, angle=20.0)
    r, searched = _refine(case, max_triangles=20000, band=14.0, core=0.5)
    _, alone = _refine(case, max_triangles=20000, band=14.0, core=0.5, search="none")
    assert searched.stage[-1] == SEARCH_STAGE and "the search's surface is kept" in searched.stop
    assert searched.sampled[1] == searched.search.sampled[1] <= alone.sampled[1]
    assert len(r.mesh.F) == len(searched.search.surface.F) == searched.triangles[-1]
    assert len(searched.functional) == len(searched.stage) == len(searched.triangles)


def test_the_log_keeps_the_searched_surface_as_the_search_made_it():
    """The polish edits the mesh's arrays in place; the log's search result keeps its own surface whole: its
    triangles name only its own vertices, as many as the log's search entry counts."""
    case = weak_sheet_case("flat", 4.0)
    r, log = _refine(case, max_triangles=12000)
    s = log.search.surface
    assert log.stage[1] == SEARCH_STAGE and len(r.mesh.F) != len(s.F)  # the polish changed the mesh
    assert s.F.max() < len(s.V) and len(s.F) == len(s.sides) == log.triangles[1]


@pytest.mark.parametrize("kind", ["flat", "curved"])
def test_the_searched_and_polished_surface_does_not_cross_itself(kind):
    case = weak_sheet_case(kind, 4.0)
    pyramid = StrengthPyramid(case.grid, case.zeta, levels=5, sigma=1.0)
    r = Refiner(_coarse(case), pyramid, case.BV, case.BF, RefineParams(max_triangles=12000, search="graphcut"),
                np.random.default_rng(0))
    r.run()
    assert self_intersections(r.mesh.V, r.mesh.F) == 0


def test_a_band_with_no_grid_node_keeps_the_coarse_surface_and_says_so():
    case = weak_sheet_case("flat", 4.0)
    far = Grid.from_bounds([5, 5, 5], [6, 6, 6], (8, 8, 8))  # nowhere near the object
    pyramid = StrengthPyramid(far, np.ones(far.shape), levels=2, sigma=1.0)
    res = graph_cut_search(_coarse(case), pyramid, Exterior(case.BV, case.BF), band=3, tension=0.05)
    assert res.surface is None
    assert len(res.notes) == 1 and "refine.band" in res.notes[0] and "no grid node" in res.notes[0]


def test_an_island_cut_off_from_its_piece_joins_the_piece_around_it():
    sub = _BoxGrid(Grid.from_bounds([0, 0, 0], [1, 1, 1], (6, 6, 6)), (slice(0, 6),) * 3)
    near = np.arange(sub.size)
    ijk = np.stack(np.unravel_index(near, sub.shape), 1)
    coarse = (ijk[:, 0] >= 3).astype(np.int64)
    keep = (ijk[:, 0] == 0) | (ijk[:, 0] == 5)
    labels = coarse.copy()
    island = np.all(ijk == [4, 2, 2], axis=1) | np.all(ijk == [4, 2, 3], axis=1)
    labels[island] = 0  # two nodes of piece 0 inside piece 1, apart from piece 0's kept nodes
    out, count = _mend(sub, near, labels, keep)
    assert count == 2 and (out == coarse).all()
    grown = coarse.copy()
    grown[(ijk[:, 0] == 3) & (ijk[:, 1] < 3)] = 0  # piece 0 grows: still one region with its kept nodes
    out, count = _mend(sub, near, grown, keep)
    assert count == 0 and (out == grown).all()


def test_a_part_of_the_band_that_no_kept_node_reaches_is_unanchored():
    sub = _BoxGrid(Grid.from_bounds([0, 0, 0], [1, 1, 1], (6, 6, 6)), (slice(0, 6),) * 3)
    ijk = np.stack(np.unravel_index(np.arange(sub.size), sub.shape), 1)
    tip = np.all(ijk == [4, 2, 2], axis=1) | np.all(ijk == [4, 2, 3], axis=1)  # two nodes, apart from the slab
    near = np.flatnonzero((ijk[:, 0] <= 2) | tip)
    keep = ijk[near, 0] == 0
    assert (_unanchored(sub, near, keep) == tip[near]).all()
    keep |= tip[near] & (ijk[near, 2] == 3)  # a kept node in the tip: nothing is unanchored
    assert not _unanchored(sub, near, keep).any()


def test_a_part_of_the_object_apart_from_every_kept_node_keeps_its_piece_and_the_rest_is_searched():
    """B in two parts, the cut through the large one, the small one a few cells above it and within the band:
    none of its nodes is kept (all nearer the cut than the band and the piece's core), so no labelling of it
    is tied to a kept node of its piece and every cut counted it an island (the search kept the coarse
    surface: 'the cut leaves a piece in parts'). Its nodes keep their piece, and the rest is searched."""
    case = weak_sheet_case("flat", 4.0)
    x = 0.5 + 4.0 * case.h
    V1, F1 = box([0, 0, 0], [1, 1, 0.8], (8, 8, 8))
    V2, F2 = box([0.45, 0.3, 0.86], [0.58, 0.45, 0.96], (2, 2, 2))
    B = Exterior(np.vstack([V1, V2]), np.vstack([F1, F2 + len(V1)]))
    V, F = sheet(lambda u, v: np.stack([np.full_like(u, x), u, v], 1), (0, 1), (0, 0.8), 9, 9)
    coarse = FractureSurface.from_coarse(V, F, np.tile([0, 1], (len(F), 1)))
    pyramid = StrengthPyramid(case.grid, case.zeta, levels=5, sigma=1.0)
    res = graph_cut_search(coarse, pyramid, B, band=14, tension=0.05)
    assert res.surface is not None, res.notes
    assert res.surface.V[:, 2].max() <= 0.8 + 1e-9  # no crack in the small part, which lies in one piece
    assert res.sampled[1] < res.sampled[0]


def test_the_parts_of_a_piece_are_its_6_connected_regions():
    sub = _BoxGrid(Grid.from_bounds([0, 0, 0], [1, 1, 1], (6, 6, 6)), (slice(0, 6),) * 3)
    near = np.arange(sub.size)
    ijk = np.stack(np.unravel_index(near, sub.shape), 1)
    labels = (ijk[:, 0] >= 3).astype(np.int64)
    assert _parts(sub, near, labels, 3).tolist() == [1, 1, 0]
    labels[ijk[:, 1] == 2] = 2  # a slab of piece 2 across both: each cut in two
    assert _parts(sub, near, labels, 3).tolist() == [2, 2, 1]
    diagonal = labels.copy()
    diagonal[:] = 0
    diagonal[np.all(ijk == [1, 1, 1], axis=1) | np.all(ijk == [2, 2, 2], axis=1)] = 1  # touching at a corner only
    assert _parts(sub, near, diagonal, 2).tolist() == [1, 2]


def _splitting_cuts(monkeypatch, cuts: int) -> list:
    """The search's first ``cuts`` cuts put a slab of piece 0 through piece 1, across its kept nodes (a core in
    two lobes, cut between them); returns the prices of every cut made, as it is made."""
    import fracture.refine.search as search

    real = search._Cut.__call__
    calls = []

    def splitting(self, prices=None, coarse_labels=None):
        labels, graph, log = real(self, prices, coarse_labels)
        calls.append(prices)
        if len(calls) <= cuts:
            ijk = np.stack(np.unravel_index(self.near, self.sub.shape), 1)
            labels = labels.copy()
            labels[ijk[:, 1] == self.sub.shape[1] // 2] = 0
        return labels, graph, log

    monkeypatch.setattr(search._Cut, "__call__", splitting)
    return calls


def _flat_sheet_search():
    case = weak_sheet_case("flat", 4.0)
    pyramid = StrengthPyramid(case.grid, case.zeta, levels=5, sigma=1.0)
    return graph_cut_search(_coarse(case), pyramid, Exterior(case.BV, case.BF), band=8, tension=0.05)


def test_a_cut_that_splits_a_piece_is_made_again_with_the_piece_whole(monkeypatch):
    """A piece whose kept nodes lie in two lobes may be cut through between them with both parts anchored (no
    island to join back): the search cuts again with that piece holding its coarse nodes and says so."""
    calls = _splitting_cuts(monkeypatch, 1)
    res = _flat_sheet_search()
    assert len(calls) == 2 and calls[0] is None
    held = calls[1].home == 1  # piece 1's nodes: each lost costs more than the whole coarse cut
    assert held.any() and calls[1].price[held].min() > res.cut_energy[0] and (calls[1].price[~held] == 0).all()
    assert any("would split piece 1 in parts" in n and "holding its coarse nodes" in n for n in res.notes)
    assert res.surface is not None  # the second cut, made whole, found the sheet
    assert res.sampled[1] < res.sampled[0]


def test_a_piece_still_in_parts_while_it_holds_its_nodes_keeps_the_coarse_surface(monkeypatch):
    """Should a cut leave a piece in parts even while it holds its coarse nodes, no further cut helps: the coarse
    surface is kept, and the note names the piece."""
    calls = _splitting_cuts(monkeypatch, 2)
    res = _flat_sheet_search()
    assert len(calls) == 2 and res.surface is None
    assert res.notes == ["search: the cut leaves piece 1 in parts; the coarse surface is kept"]


def test_the_viewer_names_the_searched_step():
    from types import SimpleNamespace

    from viewer.looks import iteration_caption

    faces = {"faces": np.zeros((4, 3), int)}
    run = SimpleNamespace(energy=[1.0, 0.5, 0.4], stages=[3, -1, 0], iterations=[faces] * 3)
    assert [iteration_caption(run, k).split(",")[0] for k in range(3)] == [
        "iteration 0 / 2 (coarse)", "iteration 1 / 2 (searched)", "iteration 2 / 2 (polished)"]
    flow = SimpleNamespace(energy=[1.0, 0.5], stages=[3, 3], iterations=[faces] * 2)
    assert iteration_caption(flow, 1).startswith("iteration 1 / 1, 4 triangles")


def test_moved_vertices_that_meet_another_go_back():
    from fracture.refine.label_surface import _apart

    V = np.array([[0.0, 0, 0], [1.0, 0, 0], [0.0, 1, 0], [5.0, 5, 5]])
    X = V.copy()
    X[0] = [1.0, 0, 0]  # moved onto vertex 1 (two rims put on one point of a crease of B)
    X[3] = [4.0, 5, 5]  # moved, apart from every other
    out = _apart(V, X, h=0.1)
    np.testing.assert_array_equal(out[0], V[0])
    np.testing.assert_array_equal(out[3], X[3])


def test_band_nodes_take_the_piece_on_their_side_of_a_junction():
    """A T of two planes (x = 0 between piece 0 and the rest; y = 0 between pieces 1 and 2 where x > 0):
    every node off the planes gets the piece it lies in, also those whose closest point is on the
    junction line or a rim."""
    from fracture.refine.search import _SideOf, _sides

    def piece(X):
        return np.where(X[:, 0] < 0, 0, np.where(X[:, 1] < 0, 1, 2))

    def quad(corners):
        return np.array(corners, float), np.array([[0, 1, 2], [0, 2, 3]])

    parts = [quad([[0, -1, -1], [0, 0, -1], [0, 0, 1], [0, -1, 1]]),  # x = 0, y < 0: pieces 0 and 1
             quad([[0, 0, -1], [0, 1, -1], [0, 1, 1], [0, 0, 1]]),  # x = 0, y > 0: pieces 0 and 2
             quad([[0, 0, -1], [0, 0, 1], [1, 0, 1], [1, 0, -1]])]  # y = 0, x > 0: pieces 1 and 2
    V = np.concatenate([v for v, _ in parts])
    F = np.concatenate([f + 4 * k for k, (_, f) in enumerate(parts)])
    T = V[F]
    n = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    n /= np.linalg.norm(n, axis=1)[:, None]
    c = T.mean(axis=1)
    S = np.stack([piece(c - 1e-3 * n), piece(c + 1e-3 * n)], 1)
    P = np.random.default_rng(0).uniform([-1, -1, -1.2], [1.3, 1, 1.2], (4000, 3))
    P = P[(np.abs(P[:, 0]) > 0.03) & ((P[:, 0] < 0) | (np.abs(P[:, 1]) > 0.03))]
    got = _sides(P, V, F, S, _SideOf(V, F, S, 0.05))
    np.testing.assert_array_equal(got, piece(P))


def test_the_coarse_to_fine_cut_costs_within_a_percent_of_the_full_grids(monkeypatch):
    import fracture.refine.search as search

    case = weak_sheet_case(TURNED, 4.0, angle=45.0)
    pyramid = StrengthPyramid(case.grid, case.zeta, levels=5, sigma=1.0)
    B = Exterior(case.BV, case.BF)
    banded = graph_cut_search(_coarse(case), pyramid, B, band=24, tension=0.05, core=0.5)
    assert banded.free_nodes > search._COARSE_MIN
    monkeypatch.setattr(search, "_COARSE_MIN", 10 ** 9)  # the whole band at full resolution at once
    full = graph_cut_search(_coarse(case), pyramid, B, band=24, tension=0.05, core=0.5)
    assert banded.free_nodes == full.free_nodes
    assert banded.cut_energy[0] == pytest.approx(full.cut_energy[0])
    assert full.cut_energy[1] <= banded.cut_energy[1] + 1e-9 <= 1.01 * full.cut_energy[1] + 1e-9
    assert banded.cut_energy[1] < 0.3 * banded.cut_energy[0]


def test_the_nodes_near_a_label_are_those_of_its_grid_dilation():
    from scipy import ndimage

    from fracture.refine.reach import near_label

    rng = np.random.default_rng(3)
    shape = (14, 11, 9)
    labels = np.full(shape, -1, np.int64)
    band = rng.random(shape) < 0.7  # the band: some of the box's nodes carry a piece
    labels[band] = 1
    labels[:4][band[:4]] = 0  # a slab of piece 0
    labels[band & (rng.random(shape) < 0.01)] = 2  # a few scattered nodes of piece 2
    nodes = np.flatnonzero(band.ravel())
    for label in (0, 2):
        for cells in (1, 3):
            expected = ndimage.binary_dilation(labels == label, np.ones((3, 3, 3), bool), cells).ravel()[nodes]
            assert (near_label(labels, nodes, label, cells) == expected).all()
            assert expected.any() and not expected.all()
    assert not near_label(labels, nodes, 5, 2).any()


def test_the_polish_runs_on_the_stages_asked_for_after_the_search():
    case = weak_sheet_case("curved", 4.0)
    for stages, expect in ((0, [0]), (1, [1, 0]), (2, [2, 1, 0])):
        r, log = _refine(case, polish_stages=stages)
        assert log.stage[1] == SEARCH_STAGE and log.search.surface is not None
        # the stages the flow ran after the search, in order (the search's surface may come back at the end)
        after = list(dict.fromkeys(stage for stage in log.stage[2:] if stage != SEARCH_STAGE))
        assert after == expect, (stages, log.stage)


def test_sheets_move_into_a_thin_valley_of_psi_only_where_their_integral_falls():
    from conftest import grid_sheet

    from fracture.mesh.topology import unique_edges
    from fracture.refine.label_surface import _to_valley, _where_lower

    h, width = 0.05, 0.5  # a weak layer half a cell wide on the plane z = 0.5
    def psi(X):
        return 1.0 - 0.9 * np.exp(-0.5 * ((X[:, 2] - 0.5) / (width * h)) ** 2)

    V1, F1 = grid_sheet(9, 0.5 + 0.2 * h)  # a sheet a fifth of a cell off the layer
    V2, F2 = grid_sheet(9, 0.5 - 0.15 * h)
    V2[:, 0] += 2.0  # a second sheet beside it, between two other pieces
    V, F = np.vstack([V1, V2]), np.vstack([F1, F2 + len(V1)])
    sides = np.vstack([np.tile([0, 1], (len(F1), 1)), np.tile([1, 2], (len(F2), 1))])
    X = _to_valley(V, F, psi, h, 0.9, unique_edges(F))
    rim = np.zeros(len(V), bool)
    for start in (0, len(V1)):  # each sheet's boundary stays where it is
        ij = np.stack(np.unravel_index(np.arange(81), (9, 9)), 1)
        rim[start + np.flatnonzero((ij == 0).any(axis=1) | (ij == 8).any(axis=1))] = True
    np.testing.assert_array_equal(X[rim], V[rim])
    assert np.abs(X[~rim, 2] - 0.5).max() < 0.02 * h
    # the move is kept on a sheet whose integral of psi it lowers, not on one it raises
    away = X.copy()
    away[len(V1):][~rim[len(V1):], 2] = 0.5 - 0.6 * h  # the second sheet pushed farther off instead
    out = _where_lower(V, away, F, sides, psi, h, offset=0.0)
    np.testing.assert_array_equal(out[:len(V1)], X[:len(V1)])
    np.testing.assert_array_equal(out[len(V1):], V[len(V1):])


def test_a_coarsened_sheet_keeps_its_rim_vertices_by_their_ids_and_appends_its_new_ones():
    """Two curved sheets meeting along a junction, coarsened: fewer triangles, every kept vertex (the rims
    and the junction among them) under its own id at its own point, the new inner vertices after the old
    ones, none of them where an old one is."""
    from fracture.mesh.primitives import sheet
    from fracture.mesh.sheets import coarsen_sheets
    from fracture.mesh.topology import unique_edges

    bump = sheet(lambda u, v: np.stack([u, v, 0.1 * np.sin(3 * u) * np.cos(2 * v)], -1), (0, 1), (0, 1), 25, 25)
    wing = sheet(lambda u, v: np.stack([u, 0 * u + 1, v], -1), (0, 1), (0, 1), 25, 25)
    V = np.concatenate([bump[0], wing[0]])
    F = np.concatenate([bump[1], wing[1] + len(bump[0])])
    V, weld = np.unique(np.round(V, 12), axis=0, return_inverse=True)  # the sheets share the edge y = 1
    F = weld.ravel()[F]
    sides = np.concatenate([np.tile([0, 1], (len(bump[1]), 1)), np.tile([1, 2], (len(wing[1]), 1))])
    X, out, out_sides = coarsen_sheets(V, F, sides, cell=0.1)
    assert len(out) < len(F) / 3 and len(out_sides) == len(out)
    np.testing.assert_array_equal(X[:len(V)], V)
    e, c = unique_edges(F)
    kept = np.unique(e[c != 2])
    assert np.isin(kept, out).all()
    fresh = np.unique(out[out >= len(V)])
    assert len(fresh) and fresh.max() == len(X) - 1
    assert not (np.abs(X[fresh][:, None] - V[None]).max(axis=2) == 0).any(axis=1).any()


def test_a_coarsened_sheet_that_folds_two_triangles_together_keeps_its_triangles(monkeypatch):
    import fracture.mesh.sheets as sheets
    from conftest import grid_sheet

    assert list(sheets._same_corners(np.array([[0, 1, 2], [1, 3, 2], [2, 1, 0], [3, 4, 5]]))) == [0, 2]
    # ... with ids too large to pack three into one integer, the same answer by the rows themselves
    big = 1 << 22
    assert list(sheets._same_corners(np.array([[0, 1, big], [1, 3, big], [big, 1, 0], [3, 4, 5]]))) == [0, 2]
    V, F = grid_sheet(6, 0.0)
    sides = np.tile([0, 1], (len(F), 1))
    # a collapse that leaves a fold: its last triangle twice, once each way
    monkeypatch.setattr(sheets, "_collapse_curved", lambda X, T, target: (X, np.vstack([T[:-2], T[-1:], T[-1:, ::-1]])))
    X, out, out_sides = sheets.coarsen_sheets(V, F, sides, cell=0.5)
    assert len(sheets._same_corners(out)) == 0 and len(out) == len(F)


def test_a_coarsened_sheet_that_folds_is_coarsened_again_with_twice_the_triangles(monkeypatch):
    """A collapse that folds is tried once more with twice the triangles before the sheet keeps its own (a
    sheet turned 80 degrees from the cut kept 66,224 grid-fine triangles, three times a preview's budget,
    where the second collapse gave 7,834 and no fold)."""
    import fracture.mesh.sheets as sheets
    from conftest import grid_sheet

    V, F = grid_sheet(13, 0.0)  # 288 triangles, 48 on the rim
    sides = np.tile([0, 1], (len(F), 1))
    real, targets = sheets._collapse_curved, []

    def first_folds(X, T, target):
        targets.append(target)
        VD, FD = real(X, T, target)
        return (VD, np.vstack([FD[:-1], FD[-1:], FD[-1:, ::-1]])) if len(targets) == 1 else (VD, FD)

    monkeypatch.setattr(sheets, "_collapse_curved", first_folds)
    X, out, _ = sheets.coarsen_sheets(V, F, sides, cell=0.07)
    assert len(targets) == 2 and targets[1] in (2 * targets[0], 2 * targets[0] + 1)
    assert len(sheets._same_corners(out)) == 0 and len(F) > len(out) > len(F) // 3


def test_a_coarsened_sheet_joined_to_itself_along_an_edge_keeps_its_triangles(monkeypatch):
    """A collapse that puts four triangles of one sheet on an edge (two parts of the sheet joined there:
    the pieces either side would pinch, and one of Blender's Suzanne exports was not closed) is not
    taken; three sheets meeting at a junction edge, one triangle each, are no pinch."""
    import fracture.mesh.sheets as sheets
    from conftest import grid_sheet

    junction = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    assert len(sheets._sheet_pinches(junction, np.array([[0, 1], [1, 2], [0, 2]]))) == 0
    V, F = grid_sheet(6, 0.0)
    sides = np.tile([0, 1], (len(F), 1))
    a, b = F[12, 0], F[12, 1]  # an inner edge of the grid: two triangles on it

    def pinched(X, T, target):
        mid = 0.5 * (X[a] + X[b])
        X2 = np.vstack([X, mid + [0.0, 0.0, 0.3], mid + [0.05, 0.05, 0.6]])
        return X2, np.vstack([T, [[a, b, len(X)], [b, a, len(X) + 1]]])

    X2, F2 = pinched(V, F, 0)
    assert len(sheets._sheet_pinches(F2, np.tile([0, 1], (len(F2), 1)))) == 4
    monkeypatch.setattr(sheets, "_collapse_curved", pinched)
    X, out, out_sides = sheets.coarsen_sheets(V, F, sides, cell=0.5)
    assert len(sheets._sheet_pinches(out, out_sides)) == 0 and len(out) == len(F)


def test_moves_that_make_triangles_cross_are_taken_back_and_the_others_kept():
    """Two parallel sheets a tenth apart, the upper one over half of the lower: a vertex of the lower one
    lifted through the upper one goes back (with its neighbours); one lifted where nothing is above it
    stays. A crossing the surface had before stays and counts as one it had; a new one beside it goes."""
    from fracture.mesh.intersect import meeting_pairs, self_intersections
    from fracture.mesh.primitives import sheet
    from fracture.refine.label_surface import _uncrossed

    lower = sheet(lambda u, v: np.stack([u, v, 0 * u], -1), (0, 1), (0, 1), 11, 11)
    upper = sheet(lambda u, v: np.stack([u, v, 0 * u + 0.1], -1), (0, 0.5), (0, 1), 6, 11)
    V = np.concatenate([lower[0], upper[0]])
    F = np.concatenate([lower[1], upper[1] + len(lower[0])])
    below = int(np.flatnonzero(np.all(np.isclose(lower[0], [0.2, 0.5, 0]), axis=1))[0])
    free = int(np.flatnonzero(np.all(np.isclose(lower[0], [0.8, 0.5, 0]), axis=1))[0])
    X = V.copy()
    X[[below, free], 2] = 0.3
    assert self_intersections(X, F) > 0
    out, pairs = _uncrossed(V, X, F, np.zeros((0, 2), np.int64))
    assert len(pairs) == 0 and self_intersections(out, F) == 0
    np.testing.assert_array_equal(out[below], V[below])
    np.testing.assert_array_equal(out[free], X[free])

    # a triangle through the upper sheet before the move: its crossing stays, counted, and the free move too
    spike = np.array([[0.25, 0.05, -0.05], [0.3, 0.05, 0.3], [0.25, 0.1, 0.3]])
    V2 = np.concatenate([V, spike])
    F2 = np.concatenate([F, [[len(V), len(V) + 1, len(V) + 2]]])
    before = meeting_pairs(V2, F2)
    assert len(before) > 0
    X2 = V2.copy()
    X2[[below, free], 2] = 0.3
    out, pairs = _uncrossed(V2, X2, F2, before)
    assert len(pairs) == len(before) == self_intersections(out, F2)
    assert sorted(map(tuple, pairs.tolist())) == sorted(map(tuple, meeting_pairs(out, F2).tolist()))
    np.testing.assert_array_equal(out[below], V2[below])
    np.testing.assert_array_equal(out[free], X2[free])


@pytest.mark.slow
def test_a_cut_pressed_on_a_quarter_of_its_weight_is_searched_again(monkeypatch):
    """A weak sheet turned 50 degrees from the cut, searched with a band of 20 cells: one search leaves the
    sheet's far ends in the pieces' cores, its cut lying against them on under half but over a quarter of its
    weight; a second search runs by itself from its surface, finds the sheet whole and ends lower."""
    import fracture.refine.search as search

    case = weak_sheet_case(TURNED, 4.0, angle=50.0)

    def within(r):
        return np.mean(np.abs(case.distance_to_sheet(area_samples(r.mesh.V, r.mesh.F))) < 1.0)

    r, auto = _refine(case, band=20.0, core=0.5, max_triangles=20000)
    monkeypatch.setattr(search, "_PRESSED", 2.0)  # no round by itself
    r1, once = _refine(case, band=20.0, core=0.5, max_triangles=20000)
    assert 0.25 <= once.search.pressed < 0.5
    assert within(r1) < 0.97 and within(r) > 0.995
    assert any("2 rounds" in note for note in auto.search.notes)
    assert auto.sampled[1] < once.sampled[1]


def test_a_second_round_reaches_a_tilted_sheet_beyond_the_first_rounds_cores(monkeypatch):
    """A weak sheet tilted up to 14.6 cells from a flat cut: one search leaves its far end beyond the pieces'
    cores (above the flow alone), its cut lying against them on over half its weight; so a second search
    runs from the first one's surface by itself, reaches it and ends below the flow alone (as two rounds
    asked for do); the new vertices still hang from the coarse triangles. A search whose cut lies free of
    its limits (the sheet parallel to the cut) stays one round."""
    import fracture.refine.search as search

    case = weak_sheet_case("tilted", 8.0)
    r, auto = _refine(case, max_triangles=12000)
    _, twice = _refine(case, max_triangles=12000, search_rounds=2)
    _, alone = _refine(case, max_triangles=12000, search="none")
    monkeypatch.setattr(search, "_PRESSED", 2.0)  # no round by itself
    _, once = _refine(case, max_triangles=12000)
    assert once.search.pressed >= 0.5 and once.sampled[1] > alone.sampled[1]
    for rounds in (auto, twice):
        assert rounds.sampled[1] < alone.sampled[1] and rounds.search.sampled[1] < once.search.sampled[1]
        assert any("2 rounds" in note for note in rounds.search.notes)
    base = auto.search.surface.base
    assert base.shape == (len(auto.search.surface.V), len(case.cut_V))
    np.testing.assert_allclose(np.asarray(base.sum(axis=1)).ravel(), 1.0)
    d = case.distance_to_sheet(area_samples(r.mesh.V, r.mesh.F))
    assert np.mean(np.abs(d) <= 1.0) > 0.995
    monkeypatch.undo()
    _, flat = _refine(weak_sheet_case("flat", 8.0), max_triangles=12000)
    assert flat.search.pressed < 0.5 and not any("rounds" in note for note in flat.search.notes)


def test_a_piece_a_cell_thin_over_its_whole_crack_is_not_searched_away():
    """A weak sheet a cell under B's face, the cut 4 cells inside it: the first search moves the crack onto the
    sheet and leaves the piece beyond it a cell thin; from that surface the piece holds a node or two (its
    nodes lie on the sheet's other side or on B), and a search from there took it away with its whole crack
    (0.6 % of the area left). That round is not kept: the crack stays on the sheet, whole."""
    case = weak_sheet_case("flat", 0.0)
    x = case.grid.points()[:, 0]
    face = case.BV[:, 0].max()
    sheet = face - 0.95 * case.h
    case.zeta = (1.0 - 0.9 * np.exp(-0.5 * ((x - sheet) / case.h) ** 2)).reshape(case.grid.shape)
    case.cut_V = case.cut_V.copy()
    case.cut_V[:, 0] = sheet - 4.0 * case.h
    r, log = _refine(case, max_triangles=12000)

    def area(V, F):
        return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum()

    assert area(r.mesh.V, r.mesh.F) > 0.95 * area(case.cut_V, case.cut_F)
    assert np.mean(np.abs(area_samples(r.mesh.V, r.mesh.F)[:, 0] - sheet) < case.h) > 0.99
    assert any("thinner than a cell over most of it" in note and "round 2's surface is kept" in note
               for note in log.search.notes), log.search.notes


def test_rim_moves_that_make_rims_cross_on_b_are_taken_back_and_the_others_kept():
    """Rim edges on the plane z = 0 (B's normal there is z): two vertices of one curve moved past each other
    make its edges cross on B, and go back; a move elsewhere that crosses nothing stays. A pair that crossed
    before stays, and a move of one of its edges too."""
    from fracture.refine.crossings_on_b import close_pairs
    from fracture.refine.label_surface import _rims_uncrossed

    def normal_at(P):
        return np.tile([0.0, 0.0, 1.0], (len(P), 1))

    x = np.linspace(0.0, 1.0, 11)
    V = np.stack([x, 0.5 + 0 * x, 0 * x], 1)
    E = np.stack([np.arange(10), np.arange(1, 11)], 1)
    X = V.copy()
    X[3] = [0.45, 0.52, 0.0]  # b past c, c back past b: the edges (2, 3) and (4, 5) cross
    X[4] = [0.25, 0.54, 0.0]
    X[8] = [0.8, 0.55, 0.0]  # a bend: crosses nothing
    assert close_pairs(X, E, normal_at)[1].sum() > 0
    out = _rims_uncrossed(V, X, E, normal_at)
    assert close_pairs(out, E, normal_at)[1].sum() == 0
    np.testing.assert_array_equal(out[[3, 4]], V[[3, 4]])
    np.testing.assert_array_equal(out[8], X[8])

    # a second curve across the first before any move (at the bend): that crossing stays, and the bend too
    V2 = np.concatenate([V, [[0.75, 0.3, 0.0], [0.75, 0.7, 0.0]]])
    E2 = np.concatenate([E, [[11, 12]]])
    X2 = np.concatenate([X, V2[11:]])
    before = int(close_pairs(V2, E2, normal_at)[1].sum())
    assert before == 1
    out = _rims_uncrossed(V2, X2, E2, normal_at)
    assert close_pairs(out, E2, normal_at)[1].sum() == before
    np.testing.assert_array_equal(out[[3, 4]], V2[[3, 4]])
    np.testing.assert_array_equal(out[8], X2[8])


@pytest.mark.parametrize("seed", range(3))
def test_each_node_takes_the_label_its_coarse_corners_agree_on(seed):
    """The coarse-to-fine cut's start on the full grid: a node takes the label of the labelled corners of
    the coarse cell it lies in when they agree, -1 when they disagree, -2 when none is labelled (against
    the corners looked up one by one)."""
    from fracture.refine.search import _agreed

    rng = np.random.default_rng(seed)
    shape = (7, 6, 5)
    lattice = rng.integers(-1, 3, tuple((n + 1) // 2 for n in shape))
    lattice[0] = 1  # a slab where every corner agrees
    lattice[1, :, :] = -1  # and one where none is labelled
    ijk = np.stack(np.unravel_index(np.arange(np.prod(shape)), shape), 1)
    expected = []
    for node in ijk:
        labels = {int(lattice[tuple(np.minimum((node + c) // 2, np.array(lattice.shape) - 1))])
                  for c in np.ndindex(2, 2, 2)} - {-1}
        expected.append(-2 if not labels else labels.pop() if len(labels) == 1 else -1)
    got = _agreed(ijk, lattice)
    assert np.array_equal(got, expected)
    assert {-2, -1, 1} <= set(got.tolist())
