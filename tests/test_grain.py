"""Grain (fields/grain.py): the anisotropic cost g(n), the flow's exact gradient of the anisotropic
functional, the search's preference for cuts along the fibres, and the config's checks."""

from __future__ import annotations

import numpy as np
import pytest

from fields.grain import Grain
from fields.grid import Grid
from fields.pyramid import StrengthPyramid
from fields.strength import grain_of
from fields.errors import InputError
from fracture.mesh.exterior import Exterior
from fracture.mesh.fracture_surface import FractureSurface
from fracture.mesh.primitives import box, sheet
from fracture.refine.flow import energy, energy_gradient, sample_displacement
from fracture.refine.search import graph_cut_search


def test_g_is_one_along_the_fibres_and_the_ratio_across_them():
    g = Grain(4.0, "along", [0, 0, 3], [0, 0, 0])
    n = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [0, np.sqrt(0.5), np.sqrt(0.5)]])
    factor, m = g.metric(n, np.zeros((4, 3)))
    np.testing.assert_allclose(factor, [1.0, 1.0, 4.0, np.sqrt(1 + 15 * 0.5)])
    np.testing.assert_allclose(np.einsum("ij,ij->i", m, n), factor)  # m . n = g: G is 1-homogeneous
    around = Grain(2.0, "around", [0, 0, 1], [1.0, 1.0, 0])
    np.testing.assert_allclose(around.directions(np.array([[2.0, 1.0, 5.0], [1.0, 1.0, 3.0]])), [[0, 1, 0], [0, 0, 1]])


@pytest.mark.parametrize("axis, ratio, field, value", [([0, 0, 0], 2.0, "axis", "nonzero length"),
                                                        ([np.nan, 0, 1], 2.0, "axis", "nonzero length"),
                                                        ([0, 0, 1], 0.5, "ratio", ">= 1"),
                                                        ([0, 0, 1], np.nan, "ratio", ">= 1")])
def test_a_bad_grain_is_refused_with_what_was_expected(axis, ratio, field, value):
    with pytest.raises(ValueError, match=f"{field}.*{value}"):
        Grain(ratio, "along", axis, [0, 0, 0])


def test_two_grain_layers_are_refused_naming_the_second():
    layers = [{"kind": "grain"}, {"kind": "marble"}, {"kind": "grain", "axis": "x"}]
    with pytest.raises(InputError, match=r"strength.layers\[2\]: a second grain layer"):
        grain_of(layers, ([0, 0, 0], [1, 1, 1]))
    assert grain_of([{"kind": "marble"}], ([0, 0, 0], [1, 1, 1])) is None
    g = grain_of([{"kind": "grain", "axis": "x", "ratio": 5.0}], ([0, 0, 0], [2, 1, 1]))
    np.testing.assert_allclose(g.axis, [1, 0, 0]) and g.ratio == 5.0


def test_the_flow_gradient_is_the_exact_derivative_of_the_anisotropic_functional():
    rng = np.random.default_rng(1)
    V, F = sheet(lambda u, v: np.stack([u, v, 0.2 * np.sin(3 * u) * np.cos(2 * v)], 1), (0, 1), (0, 1), 5, 5)
    V = V + 0.02 * rng.standard_normal(V.shape)
    grain = Grain(3.0, "along", [0.3, 0.2, 1.0], [0, 0, 0])
    b = np.array([0.4, -0.3, 0.7])
    psi = lambda X: 1.0 + X @ b  # linear: grad psi is b at every vertex
    dE, _ = energy_gradient(V, F, psi(V), np.tile(b, (len(V), 1)), grain)
    eps = 1e-6
    for i in rng.choice(len(V), 6, replace=False):
        for c in range(3):
            Vp, Vm = V.copy(), V.copy()
            Vp[i, c] += eps
            Vm[i, c] -= eps
            fd = (energy(Vp, F, psi(Vp), grain) - energy(Vm, F, psi(Vm), grain)) / (2 * eps)
            assert abs(fd - dE[i, c]) < 1e-7 * max(1.0, abs(fd))
    assert energy(V, F, psi(V), grain) > energy(V, F, psi(V))  # g >= 1
    T = V[F[:3]]
    iso = sample_displacement(T.mean(axis=1), T, psi(T.mean(axis=1)), np.tile(b, (3, 1)), psi(T.reshape(-1, 3)).reshape(3, 3), 0.1)
    none = sample_displacement(T.mean(axis=1), T, psi(T.mean(axis=1)), np.tile(b, (3, 1)), psi(T.reshape(-1, 3)).reshape(3, 3), 0.1, Grain(1.0, "along", [0, 0, 1], [0, 0, 0]))
    np.testing.assert_allclose(iso, none, atol=1e-14)  # ratio 1: no grain


def test_the_search_turns_a_cut_across_the_fibres_along_them():
    """Fibres tilted 30 degrees from the plane of a flat cut x = 1/2 (strength varies only along z, which
    every cut spans): the flat cut, the least area, cuts across them (g = 2.18 with ratio 4); a plane
    turned 30 degrees to contain them costs 1.15. The search turns the cut; without the grain it keeps it."""
    h = 1.0 / 30
    grid = Grid.from_bounds([-h] * 3, [1 + h] * 3, (33, 33, 33))
    BV, BF = box([0, 0, 0], [1, 1, 1], (6, 6, 6))
    V, F = sheet(lambda u, v: np.stack([np.full_like(u, 0.5), u, v], 1), (0, 1), (0, 1), 7, 7)
    mesh = FractureSurface.from_coarse(V, F, np.tile([0, 1], (len(F), 1)))
    ramp = 1.0 + 0.1 * grid.points()[:, 2].reshape(grid.shape)
    pyramid = StrengthPyramid(grid, ramp, levels=2, sigma=1.0)
    d = np.array([np.sin(np.radians(30)), np.cos(np.radians(30)), 0.0])
    grain = Grain(4.0, "along", d, [0, 0, 0])
    res = graph_cut_search(mesh, pyramid, Exterior(BV, BF), band=12, tension=0.05, core=0.5, grain=grain)
    S = res.surface
    assert S is not None and res.functional[1] < 0.8 * res.functional[0]  # a piece keeps half its depth
    n = np.cross(S.V[S.F[:, 1]] - S.V[S.F[:, 0]], S.V[S.F[:, 2]] - S.V[S.F[:, 0]])
    area = np.linalg.norm(n, axis=1)
    across = np.abs(n @ d) / area  # |n . fibres| per triangle; the coarse cut's: sin 30 = 0.5
    assert np.average(across, weights=area) < 0.25  # more than halved (the core holds the far ends)
    plain = graph_cut_search(mesh, pyramid, Exterior(BV, BF), band=12, tension=0.05, core=0.5)
    assert plain.surface is None  # without the grain the flat cut is the least already


def test_a_cut_across_wood_splinters_along_its_bundles():
    """A block of wood (fibre bundles along z with weak interfaces, each bundle weak at its own heights)
    cut flat across the fibres: the search crosses each bundle nearer its weakest place and joins the
    crossings by walls along the fibres (the branch's splinters, Figure 9). The surface gains area,
    a good part of it in walls that contain the fibres, and lies in weaker material than the flat cut."""
    from fields.strength import strength_field

    lo, hi = np.zeros(3), np.array([0.5, 0.5, 1.0])
    grid = Grid.from_bounds(lo - 1 / 48, hi + 1 / 48, (26, 26, 50))
    layers = [{"kind": "fibres", "axis": "z", "bundle_size": 0.1, "interface_width": 0.015, "defect_length": 0.1,
               "defect_contrast": 5.0}]
    zeta = strength_field(grid.points(), (lo, hi), layers, seed=0).reshape(grid.shape)
    BV, BF = box(lo, hi, (6, 6, 10))
    V, F = sheet(lambda u, v: np.stack([u, v, np.full_like(u, 0.5)], 1), (0, 0.5), (0, 0.5), 7, 7)
    mesh = FractureSurface.from_coarse(V, F, np.tile([0, 1], (len(F), 1)))
    pyramid = StrengthPyramid(grid, zeta, levels=2, sigma=1.0)
    res = graph_cut_search(mesh, pyramid, Exterior(BV, BF), band=10, tension=0.05, core=0.25,
                           grain=Grain(10.0, "along", [0, 0, 1], [0, 0, 0]))
    S = res.surface
    assert S is not None and res.sampled[1] < 0.9 * res.sampled[0]
    n = np.cross(S.V[S.F[:, 1]] - S.V[S.F[:, 0]], S.V[S.F[:, 2]] - S.V[S.F[:, 0]])
    area = np.linalg.norm(n, axis=1)
    assert area.sum() / 2 > 1.3 * 0.25  # the flat cut's area is 0.25
    walls = np.abs(n[:, 2]) / area < 0.5  # normals more than 60 degrees off the fibres
    assert area[walls].sum() > 0.2 * area.sum()
    C = S.V[S.F].mean(axis=1)
    assert np.average(pyramid.value(C), weights=area) < 0.85 * pyramid.value(V[F].mean(axis=1)).mean()


def _write_directions(tmp_path, d):
    path = tmp_path / "fibres.npy"
    np.save(path, d)
    return path


def test_a_volume_of_directions_gives_the_fibres_it_holds_whatever_their_sign(tmp_path):
    """Fibres along z on every node (half of them written as -z, some longer) read as z everywhere, as
    fibres along the axis do; a field that turns from x to y between two nodes turns in between."""
    from fields.grain import Grain
    from fields.strength import grain_of

    d = np.zeros((3, 4, 5, 3))
    d[..., 2] = np.where(np.indices((3, 4, 5))[0] % 2, -2.0, 1.0)
    layers = [{"kind": "grain", "fibres": "volume", "path": str(_write_directions(tmp_path, d)), "ratio": 4.0}]
    g = grain_of(layers, ([0.0, 0.0, 0.0], [1.0, 2.0, 3.0]))
    P = np.random.default_rng(0).random((200, 3)) * [1.0, 2.0, 3.0]
    np.testing.assert_allclose(np.abs(g.directions(P)[:, 2]), 1.0, atol=1e-12)
    along = Grain(4.0, "along", np.array([0.0, 0.0, 1.0]), np.zeros(3))
    N = np.random.default_rng(1).normal(size=(200, 3))
    N /= np.linalg.norm(N, axis=1)[:, None]
    np.testing.assert_allclose(g.metric(N, P)[0], along.metric(N, P)[0], atol=1e-12)

    turn = np.zeros((2, 2, 2, 3))
    turn[0, ..., 0], turn[1, ..., 1] = 1.0, 1.0  # x on the low nodes, y on the high ones
    g = grain_of([{**layers[0], "path": str(_write_directions(tmp_path, turn))}], ([0, 0, 0], [1, 1, 1]))
    d = g.directions(np.array([[0.1, 0.5, 0.5], [0.9, 0.5, 0.5]]))
    assert abs(d[0, 0]) > 0.99 and abs(d[1, 1]) > 0.99


@pytest.mark.parametrize("bad, words", [
    (np.zeros((3, 3, 3)), "expected (nx, ny, nz, 3)"),
    (np.ones((1, 3, 3, 3)), "at least two nodes per axis"),
    ("nan", "node (1, 0, 2) is NaN or infinite"),
    ("zero", "node (0, 2, 1) is of zero length"),
])
def test_a_bad_volume_of_directions_is_refused_naming_the_key_and_the_node(tmp_path, bad, words):
    from fields.errors import InputError
    from fields.strength import grain_of

    if isinstance(bad, str):
        d = np.ones((3, 3, 3, 3))
        if bad == "nan":
            d[1, 0, 2, 1] = np.nan
        else:
            d[0, 2, 1] = 0.0
        bad = d
    layers = [{"kind": "radial"}, {"kind": "grain", "fibres": "volume", "path": str(_write_directions(tmp_path, bad))}]
    with pytest.raises(InputError) as err:
        grain_of(layers, ([0, 0, 0], [1, 1, 1]))
    assert str(err.value).startswith("strength.layers[1].path (") and words in str(err.value), str(err.value)
    with pytest.raises(InputError, match=r"strength.layers\[0\].path: fibres: volume needs"):
        grain_of([{"kind": "grain", "fibres": "volume"}], ([0, 0, 0], [1, 1, 1]))
