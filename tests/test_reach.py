"""Where a piece may grow in the search: the nodes near its sheets, against libigl's distances."""

import igl
import numpy as np
import pytest

from fracture.refine.reach import nodes_near_sheets


@pytest.mark.parametrize("seed,pieces_at_once", [(0, 4), (1, 4), (2, 4), (3, 1), (4, 3)])
def test_the_nodes_near_a_pieces_sheets_are_those_within_the_radius(seed, pieces_at_once, monkeypatch):
    """Random triangles between random pairs of four pieces (large and small, some beyond the grid), a
    grid of unequal spacing and a random half of its nodes asked: each piece's nodes are exactly those
    asked within the radius of one of its triangles (two of them of no area), also when the pieces' masks
    are made a few pieces at a time."""
    from fracture.refine import reach

    rng = np.random.default_rng(seed)
    origin, spacing, shape = np.array([-0.2, 0.1, 0.0]), np.array([0.1, 0.12, 0.09]), (14, 11, 12)
    F = np.arange(60).reshape(-1, 3)
    V = rng.uniform(-0.3, 1.5, (60, 3))
    V[30:] = V[30:60:3].repeat(3, axis=0) + rng.normal(0, 0.05, (30, 3))  # ten small triangles
    V[3:6] = [V[3], V[3], V[5]]  # a triangle of no area: two corners in one place
    V[6:9] = [V[6], 0.5 * (V[6] + V[8]), V[8]]  # ... and three on a line
    sides = np.stack([rng.integers(0, 2, 20), rng.integers(2, 4, 20)], 1)
    asked = np.flatnonzero(rng.random(int(np.prod(shape))) < 0.5)
    where = np.full(shape, -1, np.int64)
    where.flat[asked] = np.arange(len(asked))
    P = origin + np.stack(np.unravel_index(asked, shape), 1) * spacing
    radius = 0.25
    monkeypatch.setattr(reach, "_MASK_BYTES", pieces_at_once * len(asked))
    found = nodes_near_sheets(where, origin, spacing, V, F, sides, radius, len(asked))
    assert sorted(found) == [0, 1, 2, 3]
    for c in range(4):
        mine = np.flatnonzero((sides == c).any(axis=1))
        d2 = igl.point_mesh_squared_distance(P, V, F[mine])[0]
        expected = np.flatnonzero(d2 <= radius * radius)
        assert 0 < len(expected) < len(asked)
        assert found[c].tolist() == expected.tolist()
