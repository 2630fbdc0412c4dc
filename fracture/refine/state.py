"""Everything the refinement keeps per vertex, in one structure that is grown and renumbered as a whole.

The refinement splits (new vertices at the end) and renumbers (spatial order,
creation order at the end) its surface; every per-vertex array must follow.
Kept in one place, none can be left out of a renumbering.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np


@dataclass
class VertexState:
    """Per-vertex arrays of the refinement, all of length ``n``.

    Attributes
    ----------
    field_at : (n, 3) float
        The positions the cached field values below were taken at (NaN: not yet).
    psi : (n,) float
        psi (pyramid level 0, unshifted) at ``field_at``.
    psibar : (n,) float
        The stage's level average of psi (unshifted) at ``field_at``.
    grad : (n, 3) float
        Its gradient there.
    velocity : (n, 3) float
        Eq. 3's velocity of the last step.
    hold : (n,) int
        Steps a vertex stopped by a collision stays stopped.
    near_at : (n, 3) float
        The positions the closest points on B below were asked for (NaN: not yet).
    near_d2, near_tri, near_point : (n,), (n,), (n, 3)
        Squared distance to B, B's triangle and the closest point there.
    clear_at : (n, 3) float
        Inside points the vertex was proved clear of B at, by the answers of its neighbours (NaN: none).
    clear_d2 : (n,) float
        The square of the distance to B proved there (a lower bound: B was not asked).
    """

    field_at: np.ndarray
    psi: np.ndarray
    psibar: np.ndarray
    grad: np.ndarray
    velocity: np.ndarray
    hold: np.ndarray
    near_at: np.ndarray
    near_d2: np.ndarray
    near_tri: np.ndarray
    near_point: np.ndarray
    clear_at: np.ndarray
    clear_d2: np.ndarray

    # the arrays of points and vectors, (n, 3); the others are (n,)
    _POINTS = ("field_at", "grad", "velocity", "near_at", "near_point", "clear_at")
    # the value a new vertex starts with, per array
    _FRESH = dict(field_at=np.nan, psi=0.0, psibar=0.0, grad=0.0, velocity=0.0, hold=0, near_at=np.nan,
                  near_d2=np.inf, near_tri=-1, near_point=np.nan, clear_at=np.nan, clear_d2=np.inf)

    @classmethod
    def empty(cls, n: int) -> VertexState:
        state = cls(*(np.zeros((0, 3)) if f.name in cls._POINTS
                      else np.zeros(0, np.int64 if f.name in ("hold", "near_tri") else np.float64)
                      for f in fields(cls)))
        state.grow(n)
        return state

    def __len__(self) -> int:
        return len(self.psi)

    def arrays(self):
        return [(f.name, getattr(self, f.name)) for f in fields(self)]

    def grow(self, n: int) -> None:
        """Append fresh entries up to ``n`` vertices."""
        extra = n - len(self)
        if extra <= 0:
            return
        for name, a in self.arrays():
            tail = np.full((extra,) + a.shape[1:], self._FRESH[name], a.dtype)
            setattr(self, name, np.concatenate([a, tail]))

    def permute(self, order: np.ndarray) -> None:
        """Renumber: new vertex ``i`` is old vertex ``order[i]``."""
        for name, a in self.arrays():
            setattr(self, name, a[order])

    def forget_field(self) -> None:
        """The field changed (a new stage): every vertex is evaluated again."""
        self.field_at[:] = np.nan
