"""Each piece keeps a share of its coarse volume (fracture.refine.volumes, refine.keep_volume)."""

from __future__ import annotations

import numpy as np
import pytest

from fields.pyramid import StrengthPyramid
from fracture.coarse.scenes.weak_sheets import weak_sheet_case
from fracture.mesh.exterior import Exterior
from fracture.mesh.fracture_surface import FractureSurface
from fracture.refine.engine import RefineParams, Refiner
from fracture.refine.volumes import PieceVolumes


def _case(offset: float):
    """A unit cube cut by the plane x = 0.5 + offset h (piece 0 behind it, toward x = 0), a weak sheet at
    x = 0.5: the flow and the search take the cut there, out of piece 0."""
    case = weak_sheet_case("flat", offset)
    return case, case.cut_V.copy(), case.cut_F.copy(), np.tile([0, 1], (len(case.cut_F), 1))


def test_the_volumes_of_a_cube_cut_by_a_plane_and_what_a_move_sweeps():
    case, V, F, sides = _case(8.0)
    x = float(V[0, 0])
    vol = PieceVolumes.measure(V, F, sides, Exterior(case.BV, case.BF), case.grid, 0.5)
    np.testing.assert_allclose(vol.coarse, [x, 1.0 - x], atol=0.01)
    np.testing.assert_allclose(vol.room, 0.5 * vol.coarse)
    # the sheet moved by 0.05 toward x = 1: piece 0 gains 0.05 (the sheet's area, 1, times the move)
    move = np.tile([0.05, 0.0, 0.0], (len(V), 1))
    np.testing.assert_allclose(vol.swept(V, F, sides, move), [0.05, -0.05], atol=1e-12)
    vol.moved(V, V + move, F, sides)
    np.testing.assert_allclose(vol.volume, vol.coarse + [0.05, -0.05], atol=1e-12)


def test_a_step_that_would_take_a_piece_below_its_share_does_not_move_into_it():
    case, V, F, sides = _case(8.0)
    vol = PieceVolumes.measure(V, F, sides, Exterior(case.BV, case.BF), case.grid, 0.9)
    into = np.tile([-0.2 * vol.coarse[0], 0.0, 0.0], (len(V), 1))  # a fifth of piece 0 away
    d = into.copy()
    held = vol.hold(V, F, sides, d)
    assert held.all() and not d.any() and vol.held == {0}
    out = np.tile([0.02, 0.0, 0.0], (len(V), 1))  # piece 0 grows, piece 1 loses 6 %: a free move
    d = out.copy()
    assert not vol.hold(V, F, sides, d).any() and np.array_equal(d, out)


def _refine(case, V, F, sides, **params):
    pyramid = StrengthPyramid(case.grid, case.zeta, levels=5, sigma=1.0)
    r = Refiner(FractureSurface.from_coarse(V, F, sides), pyramid, case.BV, case.BF,
                RefineParams(**{"max_triangles": 6000, **params}), np.random.default_rng(0))
    return r, r.run()


def _share_of_piece_0(r, x0: float) -> float:
    """Piece 0's volume over its coarse one, exactly: the cube's part behind a sheet across all of it is the
    sheet's area-weighted mean x (the coarse plane's: ``x0``)."""
    T = r.mesh.V[r.mesh.F]
    n = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])  # twice the area vector
    return float(0.5 * np.sum(n[:, 0] * T[:, :, 0].mean(axis=1))) / x0


@pytest.mark.parametrize("search", ["none", "graphcut"])
def test_the_refinement_keeps_each_piece_its_share_of_volume(search):
    """Without a limit the cut goes to the weak sheet, taking piece 0 to about 70 % of its volume; asked to
    keep 85 %, the flow stops there, and the search, whose cut would go further, cuts again with a price on
    piece 0's lost volume (across uniform strong material the priced cut goes back to the coarse plane, no
    lower than the coarse surface, which is kept) and says so."""
    case, V, F, sides = _case(8.0)
    free, _ = _refine(case, V, F, sides, search=search, keep_volume=0.0)
    assert free.volumes is None
    kept, log = _refine(case, V, F, sides, search=search, keep_volume=0.85)
    x0 = float(V[0, 0])
    share = _share_of_piece_0(kept, x0)
    assert kept.volumes.shares()[0] == pytest.approx(share, abs=0.02)  # followed through the steps
    assert share >= 0.83 and kept.volumes.held == {0}  # the floor, less the grid's error in the coarse volume
    assert _share_of_piece_0(free, x0) < 0.75  # unheld: at the weak sheet
    if search == "graphcut":
        assert any("with a price on the volume 0 lost it was cut again" in n and "piece 0 7" in n
                   for n in log.search.notes), log.search.notes


def test_a_run_says_which_pieces_the_flow_held():
    from fracture.pipeline.stages.refine import _volume_notes

    vol = PieceVolumes(np.array([1.0, 2.0, 4.0]), np.array([0.5, 2.5, 4.0]), 0.5, held={0})
    assert _volume_notes(vol, ["a", "b", "c"]) == [
        "refine: the flow held piece 'a' at 50 % of its coarse volume (refine.keep_volume), where the material "
        "would have shrunk it further; at the end 'a' 50 %"]
    assert _volume_notes(PieceVolumes(np.ones(2), np.ones(2), 0.5), ["a", "b"]) == []
    assert _volume_notes(None, ["a"]) == []


def test_a_search_with_a_price_on_the_volume_takes_a_piece_only_as_far_as_its_share():
    """Asked to keep 75 %, the priced cut stops short of the weak sheet (at 70 %) with piece 0 at its share, is
    accepted (lower than the coarse surface), and the flow then keeps it there."""
    case, V, F, sides = _case(8.0)
    r, log = _refine(case, V, F, sides, search="graphcut", keep_volume=0.75)
    assert not any("coarse surface is kept" in n for n in log.search.notes), log.search.notes
    grid_share = (r.volumes.coarse[0] + log.search.volume_change[0]) / r.volumes.coarse[0]
    assert 0.75 <= grid_share < 0.85, log.search.notes  # the cut's nodes: at the share, not back at the coarse cut
    assert _share_of_piece_0(r, float(V[0, 0])) >= 0.68  # the contour lies within a fraction of a cell of them


def test_a_cut_made_again_for_the_volume_finds_its_prices_on_the_coarse_level(monkeypatch):
    """Coarse to fine, a cut that leaves a piece short is made again with prices raised on the coarse level's
    cuts until that level keeps the piece its share, then the full grid is cut once at them, and the piece
    is at its share."""
    import fracture.refine.search as search

    full, coarse = [], []
    real_full, real_coarse = search._Cut.__call__, search._Cut.coarse_labels

    def full_cut(self, prices=None, coarse_labels=None):
        full.append(None if prices is None else prices.price.max())
        return real_full(self, prices, coarse_labels)

    def coarse_cut(self, prices=None):
        coarse.append(None if prices is None else prices.price.max())
        return real_coarse(self, prices)

    monkeypatch.setattr(search._Cut, "__call__", full_cut)
    monkeypatch.setattr(search._Cut, "coarse_labels", coarse_cut)
    case, V, F, sides = _case(8.0)
    r, log = _refine(case, V, F, sides, search="graphcut", keep_volume=0.8)
    assert full[0] is None and len(full) == 2  # the first cut, and one at the prices the coarse level found
    priced = [p for p in coarse if p is not None]
    assert len(priced) >= 3 and priced == sorted(priced)  # raised cut by cut on the coarse level
    assert full[1] == priced[-1]
    assert any("would leave piece 0 72 %" in n and f"cut again {len(priced)} times" in n for n in log.search.notes)
    assert log.search.volume_change[0] >= -0.2 * r.volumes.coarse[0], log.search.notes  # its share kept


def test_a_piece_the_coarse_level_leaves_clearly_short_is_priced_before_the_full_grid_is_cut(monkeypatch):
    """The coarse level's first cut leaves piece 0 about 72 % of its volume, asked to keep 95 %: more than a tenth
    below its share, so its price is raised on the coarse level before the full grid is cut: no cut of the full grid
    is made without prices (one per round of the search), and the piece keeps its share."""
    import fracture.refine.search as search

    full = []
    real_full = search._Cut.__call__

    def full_cut(self, prices=None, coarse_labels=None):
        full.append(None if prices is None else prices.price.max())
        return real_full(self, prices, coarse_labels)

    monkeypatch.setattr(search._Cut, "__call__", full_cut)
    case, V, F, sides = _case(8.0)
    r, log = _refine(case, V, F, sides, search="graphcut", keep_volume=0.95)
    assert full and all(p is not None for p in full), full
    assert any("the cut's coarse level would leave piece 0 7" in n and "every piece keeps its share" in n
               for n in log.search.notes), \
        log.search.notes
    assert log.search.volume_change[0] >= -0.05 * r.volumes.coarse[0], log.search.notes


def test_only_a_piece_the_coarse_level_leaves_well_below_its_share_and_not_empty_is_clearly_short():
    """Before the full grid is cut, the coarse level's volumes price a piece only when they leave it more than
    a tenth of its volume below its share and some volume at all (a piece the coarse level takes whole may be
    in lobes the full grid holds)."""
    from fracture.refine.search import _clearly_short

    volumes = PieceVolumes(np.ones(4), np.ones(4), 0.5)
    change = np.array([-0.45, -0.65, -1.02, 0.2])  # left: 55 %, 35 %, nothing, 120 %
    assert _clearly_short(volumes, change, 4).tolist() == [1]
    assert _clearly_short(None, change, 4).tolist() == []
