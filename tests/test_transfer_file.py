"""``animation/transfer.npz`` as the animate stage writes it: a component's maps once per frame where they
agree (rigid and affine motion), per slot where it deforms; what is read back gives the same positions."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from fracture.pieces.transfer import Transfer, load_transfer, transfer_arrays


def _transfer(rng, far: float = 0.0) -> Transfer:
    """Two components of 5 slots each over 4 frames: the first moves rigidly, the second deforms at frames 2
    and 3; 30 rows blending 3 slots of their component each."""
    T, S = 4, 10
    comp = np.repeat([0, 1], 5)
    maps = np.zeros((T, S, 3, 4))
    for t in range(T):
        c, s = np.cos(0.2 * t), np.sin(0.2 * t)
        maps[t, comp == 0, :, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
        maps[t, comp == 0, :, 3] = [0.1 * t, 0.0, -0.3 * t]
        maps[t, comp == 1, :, :3] = np.eye(3)
        if t >= 2:  # every slot its own stretch
            maps[t, comp == 1, :, :3] += 0.05 * rng.normal(size=(5, 3, 3))
        maps[t, comp == 1, :, 3] = [0.0, 0.2 * t, 0.0]
    rows = 30
    cols = np.array([rng.choice(np.flatnonzero(comp == (r >= 15)), 3, replace=False) for r in range(rows)])
    w = rng.random((rows, 3))
    w /= w.sum(axis=1, keepdims=True)
    own = sp.csr_matrix((w.ravel(), (np.repeat(np.arange(rows), 3), cols.ravel())), shape=(rows, S))
    shared = sp.csr_matrix((0, S))
    return Transfer(own=own, shared=shared, shared_rows=np.zeros(0, np.int64), shared_time=np.zeros(0),
                    maps=maps, offsets=np.array([0, 15, 30]), time=np.zeros(rows), vertex=np.arange(rows),
                    material=far + rng.random((rows, 3)), slot_component=comp)


def test_the_file_stores_rigid_maps_once_and_reads_back_the_same_positions(tmp_path):
    rng = np.random.default_rng(0)
    for far in (0.0, 1000.0):  # an object far from the origin keeps its precision
        tr = _transfer(rng, far)
        arrays = transfer_arrays(tr, size=np.sqrt(3.0))
        assert arrays["common_same"].tolist() == [[True, True], [True, True], [True, False], [True, False]]
        assert arrays["slot_maps"].shape == (2 * 5, 3, 4)  # the deforming component's two frames, per slot
        np.savez_compressed(tmp_path / "t.npz", **arrays)
        back = load_transfer(tmp_path / "t.npz")
        np.testing.assert_array_equal(back.maps, tr.maps)
        for t in range(tr.n_frames):
            np.testing.assert_allclose(back.positions(t), tr.positions(t), rtol=0, atol=1e-6 * np.sqrt(3.0))
