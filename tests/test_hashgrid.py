"""The hierarchical spatial hash lists every pair of overlapping boxes exactly once."""

from __future__ import annotations

import numpy as np
import pytest
from fracture.mesh import hashgrid


def _boxes(k, seed):
    """Boxes of sizes over four orders of magnitude (several levels), some of them flat or points."""
    rng = np.random.default_rng(seed)
    lo = rng.uniform(-1.0, 1.0, (k, 3))
    size = 10.0 ** rng.uniform(-3.0, 0.0, (k, 1)) * rng.uniform(0.0, 1.0, (k, 3))
    size[rng.random(k) < 0.1] = 0.0
    size[rng.random(k) < 0.2, 2] = 0.0
    return lo, lo + size


def _overlapping(lo, hi, a, b):
    return bool(np.all(lo[a] <= hi[b]) and np.all(lo[b] <= hi[a]))


@pytest.mark.parametrize("seed", [0, 1])
def test_all_pairs_match_a_brute_force_search(seed):
    lo, hi = _boxes(400, seed)
    grid = hashgrid.build(lo, hi, 1.0 / hashgrid.cell_size(lo, hi, 0.01))
    assert len(np.unique(grid[1])) >= 4  # the boxes do spread over levels
    found = hashgrid.pairs(grid)
    assert (found[:, 0] < found[:, 1]).all()
    assert len({tuple(p) for p in found.tolist()}) == len(found)  # none twice
    brute = {(a, b) for a in range(400) for b in range(a + 1, 400) if _overlapping(lo, hi, a, b)}
    assert {tuple(p) for p in found.tolist()} == brute


def test_queries_match_a_brute_force_search():
    lo, hi = _boxes(500, 2)
    grid = hashgrid.build(lo, hi, 1.0 / hashgrid.cell_size(lo, hi, 0.02))
    buf = np.empty(4, np.int64)  # grows as needed
    for q in range(0, 500, 7):
        buf, k = hashgrid.gather(grid, lo[q], hi[q], buf)
        assert sorted(buf[:k].tolist()) == [g for g in range(500) if _overlapping(lo, hi, q, g)]


def test_far_coordinates_do_not_overflow_the_packed_cells():
    lo = np.array([[0.0, 0.0, 0.0], [1e9, 0.0, 0.0], [1e9 + 0.5, 0.0, 0.0]])
    hi = lo + 1.0
    inv = 1.0 / hashgrid.cell_size(lo, hi, 1e-3)
    found = hashgrid.pairs(hashgrid.build(lo, hi, inv))
    assert found.tolist() == [[1, 2]]


def test_few_large_among_many_small_boxes_from_either_side():
    """A surface's many small triangles and its few long ones: the coarse levels look up the fine cells."""
    rng = np.random.default_rng(3)
    lo = rng.uniform(-1.0, 1.0, (3000, 3))
    size = np.full((3000, 3), 0.02) * rng.uniform(0.2, 1.0, (3000, 3))
    size[:15] *= rng.uniform(2.0, 12.0, (15, 1))
    hi = lo + size
    grid = hashgrid.build(lo, hi, 1.0 / hashgrid.cell_size(lo, hi, 0.03))
    counts = np.bincount(grid[1])
    assert hashgrid.look_down(counts[0], counts[1], 1)
    found = hashgrid.pairs(grid)
    i, j = np.triu_indices(3000, 1)
    hit = np.all(lo[i] <= hi[j], axis=1) & np.all(lo[j] <= hi[i], axis=1)
    assert sorted(map(tuple, found.tolist())) == sorted(zip(i[hit].tolist(), j[hit].tolist()))


def test_crowded_buckets_are_sorted_by_lower_x_and_miss_no_pair():
    """Many boxes in few cells (buckets of dozens of slots), and a copy of them far away whose cells
    share the first copy's buckets (hash collisions): every bucket is in order of lower x, on
    which the scans stop early, and the pairs are exactly the overlapping ones."""
    rng = np.random.default_rng(5)
    lo = rng.uniform(0.0, 3.0, (300, 3))
    lo[rng.random(300) < 0.2, 0] = 1.5  # ties in lower x
    hi = lo + rng.uniform(0.0, 0.9, (300, 3))
    inv = 1.0 / hashgrid.cell_size(lo, hi, 1.0)
    far = np.array([1024.0, 0.0, 0.0])  # a multiple of every table's period in x
    lo, hi = np.r_[lo, lo + far], np.r_[hi, hi + far]
    grid = hashgrid.build(lo, hi, inv)
    start, items, key = grid[4], grid[5], grid[6]
    sizes = np.diff(start)
    assert sizes.max() > 40  # crowded
    mixed = sum(len(np.unique(key[start[b]:start[b + 1]])) > 1 for b in range(len(sizes)))
    assert mixed > 0  # some buckets hold two cells
    for b in np.flatnonzero(sizes > 1):
        assert (np.diff(lo[items[start[b]:start[b + 1]], 0]) >= 0.0).all()
    found = {tuple(p) for p in hashgrid.pairs(grid).tolist()}
    expected = {(a, b) for a in range(600) for b in range(a + 1, 600) if _overlapping(lo, hi, a, b)}
    assert found == expected


def test_the_pairs_are_the_same_rows_in_the_same_order_on_any_number_of_threads():
    """The parallel search writes each chunk's pairs into rows of its own and appends them in order:
    one thread and two give the same array (the collision handling that reads it, the same result)."""
    import numba

    from fracture.mesh.intersect import triangle_grid
    from fracture.mesh.primitives import sheet

    V, F = sheet(lambda u, v: np.stack([u, v, 0.05 * np.sin(8 * u) * np.cos(6 * v)], 1), (0, 1), (0, 1), 60, 60)
    rng = np.random.default_rng(0)
    V = np.concatenate([V, rng.random((40, 3))])  # a few large triangles across it: pairs on two levels
    F = np.concatenate([F, rng.integers(len(V) - 40, len(V), (20, 3))])
    grid = triangle_grid(V, F)
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = hashgrid.pairs(grid)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        two = hashgrid.pairs(grid)
    finally:
        numba.set_num_threads(before)
    assert len(one) > 1000 and np.array_equal(one, two)
