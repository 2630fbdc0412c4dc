"""Alpha-expansion on small graphs against brute force, and the lattice's area weights on planes."""

import itertools

import numpy as np
import pytest

from fracture.refine.cut_weights import area_weights, cut_cost, grain_cost, grain_weight_table, sphere_directions
from fracture.refine.expansion import PottsGraph, Prices, _move, expand


def _graph(rng, n=9, density=0.5):
    """A random graph whose edges point either way, some of them twice (both ways or the same way)."""
    pairs = [(i, j) if rng.random() < 0.5 else (j, i) for i in range(n) for j in range(i + 1, n)
             if rng.random() < density]
    pairs += [pairs[k][::-1] if k % 2 else pairs[k] for k in rng.choice(len(pairs), 3, replace=False)]
    p, q = np.array(pairs).T
    return PottsGraph(n, p, q, rng.random(len(p)))


def test_the_potts_energy_is_the_weight_of_the_edges_between_labels():
    rng = np.random.default_rng(5)
    g = _graph(rng, n=40)
    for _ in range(5):
        labels = rng.integers(0, 4, g.n)
        assert g.energy(labels) == pytest.approx(sum(w for p, q, w in zip(g.p, g.q, g.w) if labels[p] != labels[q]),
                                                 rel=1e-12)
    assert g.energy(np.zeros(g.n, np.int64)) == 0.0


@pytest.mark.parametrize("seed", range(6))
def test_an_expansion_move_is_the_best_move_of_its_label(seed):
    rng = np.random.default_rng(seed)
    g = _graph(rng)
    labels = rng.integers(0, 3, g.n)
    free = rng.random(g.n) < 0.8
    for a in range(3):
        nodes = np.flatnonzero(free & (labels != a))
        switch = _move(g, labels, nodes, a)
        moved = labels.copy()
        moved[nodes[switch]] = a
        best = min(g.energy(np.where(np.isin(np.arange(g.n), nodes[list(s)]), a, labels))
                   for k in range(len(nodes) + 1) for s in itertools.combinations(range(len(nodes)), k))
        assert g.energy(moved) == pytest.approx(best, abs=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_two_labels_reach_the_global_minimum_and_three_within_twice_it(seed):
    rng = np.random.default_rng(10 + seed)
    g = _graph(rng, n=10)
    for k in (2, 3):
        labels = rng.integers(0, k, g.n)
        free = np.ones(g.n, bool)
        free[:k] = False  # one fixed node of each label: the empty cut is not allowed
        labels[:k] = np.arange(k)
        out, log = expand(g, labels, free)
        assert (out[~free] == labels[~free]).all()
        assert all(b <= a + 1e-12 for a, b in zip(log.energy, log.energy[1:]))
        best = min(g.energy(np.r_[np.arange(k), rest]) for rest in itertools.product(range(k), repeat=g.n - k))
        if k == 2:
            assert g.energy(out) == pytest.approx(best, abs=1e-12)
        else:
            assert g.energy(out) <= 2 * best + 1e-12


@pytest.mark.parametrize("seed", range(4))
def test_a_move_with_prices_is_the_best_move_of_the_potts_energy_plus_the_prices(seed):
    rng = np.random.default_rng(20 + seed)
    g = _graph(rng)
    labels = rng.integers(0, 3, g.n)
    prices = Prices(rng.integers(0, 3, g.n), rng.random(g.n) * (rng.random(g.n) < 0.7))

    def energy(labels):
        return g.energy(labels) + prices.energy(labels)

    for a in range(3):
        nodes = np.flatnonzero(labels != a)
        switch = _move(g, labels, nodes, a, prices)
        moved = labels.copy()
        moved[nodes[switch]] = a
        best = min(energy(np.where(np.isin(np.arange(g.n), nodes[list(s)]), a, labels))
                   for k in range(len(nodes) + 1) for s in itertools.combinations(range(len(nodes)), k))
        assert energy(moved) == pytest.approx(best, abs=1e-12)


@pytest.mark.parametrize("price", [0.0, 0.05, 0.2, 1.0])
def test_a_price_on_leaving_home_holds_a_two_label_boundary_where_the_saving_pays_for_it(price):
    """A chain 0..n-1 labelled 0 up to its home boundary k and 1 after, its ends fixed: the cut of one edge
    j (between j and j + 1) costs w_j plus the price of every node between j and k, so the minimum is
    w_j + price |j - k| over j, the analytic answer."""
    rng = np.random.default_rng(3)
    n, k = 30, 14
    w = 1.0 + rng.random(n - 1)
    w[4] = 0.2  # a weak edge ten nodes from home: worth the walk only while the price is low
    g = PottsGraph(n, np.arange(n - 1), np.arange(1, n), w)
    home = (np.arange(n) > k).astype(np.int64)
    free = np.ones(n, bool)
    free[[0, -1]] = False
    out, _ = expand(g, home, free, prices=Prices(home, np.full(n, price)))
    j = int(np.argmin(w + price * np.abs(np.arange(n - 1) - k)))
    assert out.tolist() == (np.arange(n) > j).astype(int).tolist()
    assert (j == 4) == (price * 10 < w[k] - w[4])


def test_a_label_the_reach_does_not_name_is_taken_by_no_node():
    """Three fixed nodes of labels 0, 1, 2 and three free ones (label 0) tied five times as strongly to the
    label-2 node as to the label-0 one: free to, they take label 2; with a reach that names only labels
    0 and 1 they keep theirs, and with one that lets label 2 reach node 3 only, node 3 alone takes it."""
    p = np.array([3, 4, 5, 3, 4, 5])
    q = np.array([2, 2, 2, 0, 0, 0])
    g = PottsGraph(6, p, q, np.array([5.0, 5.0, 5.0, 1.0, 1.0, 1.0]))
    labels = np.array([0, 1, 2, 0, 0, 0])
    free = np.array([False, False, False, True, True, True])
    assert expand(g, labels, free)[0].tolist() == [0, 1, 2, 2, 2, 2]
    some = {0: np.array([3, 4, 5]), 1: np.array([3, 4, 5])}
    assert expand(g, labels, free, some)[0].tolist() == [0, 1, 2, 0, 0, 0]
    assert expand(g, labels, free, {**some, 2: np.array([3])})[0].tolist() == [0, 1, 2, 2, 0, 0]


@pytest.mark.parametrize("spacing", [(1, 1, 1), (0.5, 0.5, 0.5), (1, 1, 0.7)])
def test_the_weights_measure_the_area_of_planes_at_every_orientation(spacing):
    w = area_weights(spacing)
    N = np.random.default_rng(0).normal(size=(500, 3))
    N /= np.linalg.norm(N, axis=1)[:, None]
    cost = cut_cost(spacing, w, N)
    assert np.all(np.abs(cost - 1.0) < 0.08)
    assert (w >= 0).all()
    six = np.zeros(13)
    six[:3] = np.prod(spacing) / np.asarray(spacing, float)  # the staircase's weights: exact on axis planes
    assert cut_cost(spacing, six, np.array([[1, 1, 0]]) / np.sqrt(2))[0] > 1.35


def test_grain_weights_make_cuts_across_the_grain_dear():
    d = np.array([0.0, 0.0, 1.0])
    T = grain_weight_table((1, 1, 1), 3.0, d[None])[0]
    along = cut_cost((1, 1, 1), T, np.array([[1.0, 0, 0], [0, 1.0, 0]]))
    across = cut_cost((1, 1, 1), T, d[None])[0]
    assert np.all(np.abs(along - 1.0) < 0.12) and abs(across - 3.0) < 0.35
    N = sphere_directions(200)
    assert np.abs(cut_cost((1, 1, 1), T, N) / grain_cost(N, d, 3.0) - 1).max() < 0.12
