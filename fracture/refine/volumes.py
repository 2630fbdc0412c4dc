"""Each piece keeps a share of its coarse volume (``refine.keep_volume``).

The coarse animation moves each piece as a rigid body of that piece's mass, and the refined pieces follow it
(Section 5): a refined piece that lost most of its volume to its neighbours leaves that material moving with
the wrong bodies. Nothing in the paper's functional keeps the volumes: it is a weighted area, and a gradient
flow of a network of sheets shrinks a piece whose sheets can slide to make less area (the multi-phase mean
curvature flow's behaviour), while a minimum cut favours small regions. On the marble bunny the flow alone
took a piece from 24.4 % of the object to 1.1 %, almost all of it in the first, coarsest stage (a blurred
field, moves of a cell per iteration); with other materials the search took pieces to nothing
(`docs/design-measurements.md`).

- The pieces' volumes are measured once, by the divergence theorem: a third of the flux of the position out
  of each piece through its sheets and its part of B (B's triangles split to two cells, each given the piece
  on its inner side: :func:`fracture.refine.search.node_pieces`, the search's band's rule).
- A step sweeps volume from piece to piece: each triangle its area times its corners' mean move along its
  normal, which the piece behind it gains and the piece in front loses. The volumes follow the steps taken.
- A step that would leave a piece below ``keep_volume`` of its coarse volume moves no vertex of that piece's
  sheets further into it (its sheets may still move out of it).
- A search's cut that would leave a piece below it (its labels give the change, node by node) is cut again
  with a rising price on every node that piece loses; if one is still short after a few cuts, the coarse
  surface is kept (:func:`fracture.refine.search.graph_cut_search`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numba
import numpy as np

from fracture.mesh.exterior import Exterior
from fracture.mesh.topology import face_frames, split_while
from fracture.refine.search import node_pieces
from fracture.tolerances import tol

# B's triangles are split to edges of at most this many cells to be given to the pieces ...
_CELLS = 2.0
# ... each the piece of the point this many cells inside B from its middle.
_INNER = 0.25


@dataclass
class PieceVolumes:
    """The pieces' volumes, from the coarse surface's (``coarse``) on, and the least each may keep."""

    coarse: np.ndarray  # (n_pieces,) at the coarse surface
    volume: np.ndarray  # (n_pieces,) now
    keep: float  # the share of ``coarse`` each piece keeps at least
    held: set = field(default_factory=set)  # the pieces a step was held for

    @classmethod
    def measure(cls, V: np.ndarray, F: np.ndarray, sides: np.ndarray, B: Exterior, grid, keep: float
                ) -> PieceVolumes:
        """The volumes of the pieces the surface ``(V, F, sides)`` cuts B into, kept at ``keep`` of them."""
        return cls.of(measure_volumes(V, F, sides, B, grid), keep)

    @classmethod
    def of(cls, coarse: np.ndarray, keep: float) -> PieceVolumes:
        """The pieces at their coarse volumes ``coarse`` (:func:`measure_volumes` of the coarse surface), kept at
        ``keep`` of them."""
        coarse = np.array(coarse, np.float64)
        return cls(coarse, coarse.copy(), float(keep))

    def copy(self, volume: np.ndarray | None = None) -> PieceVolumes:
        """A copy of its own (the volumes and the pieces held so far), with the volumes ``volume`` if given."""
        return replace(self, volume=np.array(self.volume if volume is None else volume, np.float64),
                       held=set(self.held))

    @property
    def room(self) -> np.ndarray:
        """How much volume each piece may still lose."""
        return self.volume - self.keep * self.coarse

    def swept(self, V: np.ndarray, F: np.ndarray, sides: np.ndarray, D: np.ndarray) -> np.ndarray:
        """Per piece, the volume it gains when the vertices ``V`` move by ``D`` (module notes)."""
        return _swept(np.ascontiguousarray(V, np.float64), np.ascontiguousarray(F, np.int64),
                      np.ascontiguousarray(sides, np.int64), np.ascontiguousarray(D, np.float64), len(self.volume))

    def hold(self, V: np.ndarray, F: np.ndarray, sides: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Zero (in ``d``) the moves of the vertices of the sheets of every piece the step ``d`` would leave
        below its share, where they move into it (along the gradient of its volume); returns the vertices
        held. (Removing only their part into the piece, so that they still slide along the sheet, ended the
        marble bunny a point lower in the weakest fifth and 1.2 % higher on the functional.)"""
        change = self.swept(V, F, sides, d)
        low = np.flatnonzero((change < 0.0) & (self.volume + change < self.keep * self.coarse))
        held = np.zeros(len(V), bool)
        if not len(low):
            return held
        area, normal = face_frames(V, F)
        self.held.update(int(p) for p in low)
        for p in low:
            # per vertex, the gradient of the piece's volume (times three): its triangles' area vectors,
            # pointing out of the piece
            sign = (sides[:, 0] == p).astype(np.float64) - (sides[:, 1] == p)
            outward = (sign * area)[:, None] * normal
            g = np.stack([np.bincount(F.ravel(), np.repeat(outward[:, c], 3), len(V)) for c in range(3)], 1)
            held |= np.einsum("ij,ij->i", d, g) < 0.0
        d[held] = 0.0
        return held

    def moved(self, V: np.ndarray, X: np.ndarray, F: np.ndarray, sides: np.ndarray) -> None:
        """Follow the step of the vertices from ``V`` to ``X``."""
        self.volume = self.volume + self.swept(V, F, sides, X - V)

    def shares(self) -> np.ndarray:
        """Each piece's volume now as a share of its coarse volume (1 where it had none)."""
        return np.where(self.coarse > 0.0, self.volume / np.where(self.coarse > 0.0, self.coarse, 1.0), 1.0)


def measure_volumes(V: np.ndarray, F: np.ndarray, sides: np.ndarray, B: Exterior, grid) -> np.ndarray:
    """The volumes of the pieces the surface ``(V, F, sides)`` cuts B into (module notes): by the divergence
    theorem, a third of the flux of ``x`` out of each piece, through its sheets and its part of B (B's
    triangles split to at most two cells, each given the piece on the inner side of its middle)."""
    n = int(sides.max()) + 1 if len(sides) else 0
    h = float(np.min(grid.spacing))
    centre = 0.5 * (B.V.min(axis=0) + B.V.max(axis=0))  # about B's middle: no digits lost far from the origin
    T = split_while(B.V[B.F] - centre,
                    lambda T: np.linalg.norm(T - np.roll(T, 1, axis=1), axis=2).max(axis=1) > _CELLS * h)
    middle, normal, flux = _flux(T)
    length = np.maximum(np.linalg.norm(normal, axis=1), tol.tiny)
    inner = middle - (_INNER * h / length)[:, None] * normal + centre
    volume = np.bincount(node_pieces(inner, V, F, sides, h), flux, n)[:n]
    if len(F):  # a sheet's normal points from the piece behind it (sides[:, 0]) to the one in front
        flux = _flux(V[F] - centre)[2]
        volume += np.bincount(sides[:, 0], flux, n)[:n] - np.bincount(sides[:, 1], flux, n)[:n]
    return volume


def _flux(T: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per triangle (corners ``T``): its middle, twice its area vector, and a third of the flux of the
    position through it."""
    middle = T.mean(axis=1)
    normal = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    return middle, normal, np.einsum("ij,ij->i", middle, normal) / 6.0


@numba.njit(cache=True)
def _swept(V, F, sides, D, n):
    # each triangle's area vector times its corners' mean move, gained behind it and lost in front, in one pass
    # (NumPy's gathers of the corners' moves took three times as long on the Jell-O's steps)
    out = np.zeros(n)
    for t in range(F.shape[0]):
        a, b, c = F[t, 0], F[t, 1], F[t, 2]
        flux = 0.0
        for k in range(3):
            k1, k2 = (k + 1) % 3, (k + 2) % 3
            area = 0.5 * ((V[b, k1] - V[a, k1]) * (V[c, k2] - V[a, k2]) - (V[b, k2] - V[a, k2]) * (V[c, k1] - V[a, k1]))
            flux += area * (D[a, k] + D[b, k] + D[c, k]) / 3.0
        out[sides[t, 0]] += flux
        out[sides[t, 1]] -= flux
    return out
