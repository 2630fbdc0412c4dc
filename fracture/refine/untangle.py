"""The refined surface leaves the refinement uncrossed: triangles that cross each other are relaxed apart.

The collision step keeps the flow's moves from making triangles cross, and flips are tested against
their surroundings; a crossing can still come in where no step checks it (the global search's contour
between two close sheets, splits on B near a junction). Before the surface leaves the refinement, the
vertices of the crossing triangles and a ring around them are relaxed toward the mean of their
neighbours (the uniform Laplacian: it pulls a fold flat), more each round, the region growing by a ring,
until no pair crosses; vertices on B are put back on B after each pass. A surface that still crosses
itself after :data:`ROUNDS` rounds is refused (:func:`require_uncrossed`), naming where.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from fracture.errors import ResultError
from fracture.mesh.exterior import Exterior
from fracture.mesh.intersect import self_intersections
from fracture.mesh.topology import boundary_edges, unique_edges

# Rounds of relaxation; in round r the region is the crossing triangles' vertices and r + 1 rings around
# them, relaxed by 2 (r + 1) passes of the uniform Laplacian with factor _STEP.
ROUNDS = 8
_STEP = 0.5


def untangle(V: np.ndarray, F: np.ndarray, B: Exterior, rounds: int = ROUNDS) -> tuple[np.ndarray, int, int]:
    """Positions with the crossing pairs of ``(V, F)`` relaxed apart (module notes): ``(V, pairs before,
    pairs left)``; ``V`` is returned unchanged when nothing crosses."""
    count = self_intersections(V, F)
    if not count:
        return V, 0, 0
    _, pairs = self_intersections(V, F, report=count)
    E, _ = unique_edges(F)
    n = len(V)
    A = sp.coo_matrix((np.ones(2 * len(E)), (np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]])), shape=(n, n)).tocsr()
    degree = np.asarray(A.sum(axis=1)).ravel()
    on_b = np.zeros(n, bool)
    on_b[boundary_edges(F).ravel()] = True
    region = np.zeros(n, bool)
    region[F[pairs.ravel()].ravel()] = True
    X = V.copy()
    left = count
    for r in range(rounds):
        region |= (A @ region.astype(np.float64)) > 0  # one ring more
        ids = np.flatnonzero(region)
        for _ in range(2 * (r + 1)):
            mean = (A[ids] @ X) / np.maximum(degree[ids], 1)[:, None]
            X[ids] += _STEP * (mean - X[ids])
            rim = ids[on_b[ids]]
            if len(rim):
                X[rim] = B.closest(X[rim])[2]
        left = self_intersections(X, F)
        if not left:
            break
    return X, count, left


def require_uncrossed(V: np.ndarray, F: np.ndarray, B: Exterior, where: str = "refine",
                      rounds: int = ROUNDS) -> tuple[np.ndarray, int, int]:
    """:func:`untangle`, refusing a surface that still crosses itself (a :class:`~fracture.errors.ResultError`
    naming where); returns the positions, how many pairs crossed before and how many after (counted: 0)."""
    X, before, left = untangle(V, F, B, rounds)
    if left:
        _, pairs = self_intersections(X, F, report=1)
        at = np.round(X[F[pairs[0, 0]]].mean(axis=0), 6).tolist()
        raise ResultError(f"{where}: {left} pairs of refined fracture triangles cross each other (the first near "
                         f"{at}) and relaxing them did not part them; another refine.max_triangles or refine.draw "
                         "gives another refined surface")
    return X, before, left

