"""Coarse animations: per component and frame, a deformation of material space.

Every component carries a small lattice over its rest-pose bounding box; each
frame stores the deformed positions of the lattice nodes. A material point
moves by trilinear interpolation of its lattice (exact for rigid and affine
motion, which a 2 x 2 x 2 lattice represents), and its deformation gradient is
the interpolated finite-difference gradient of the node positions. This one
representation covers rigid pieces, embedded coarse lattices (elastic wobble,
twist, bending) and motions fitted to imported per-vertex data.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import lsqr

from fields.grid import Grid
from fields.interpolate import trilinear
from fracture.tolerances import tol

# Weight of the pull of the lattice nodes toward the best affine map in
# `fit_lattice`: small against the data term, large enough to pin nodes that
# no point constrains.
AFFINE_PRIOR_WEIGHT = 1e-3


@dataclass
class CoarseAnimation:
    """Lattice deformations of ``C`` components over ``T`` frames.

    Attributes
    ----------
    lo, hi : (C, 3) float
        Rest-pose box of each component's lattice.
    nodes : (T, C, n, n, n, 3) float
        Deformed node positions; frame 0 is the rest pose.
    """

    lo: np.ndarray
    hi: np.ndarray
    nodes: np.ndarray

    @property
    def n_frames(self) -> int:
        return self.nodes.shape[0]

    @property
    def n_components(self) -> int:
        return self.nodes.shape[1]

    def grid(self, c: int) -> Grid:
        return Grid.from_bounds(self.lo[c], self.hi[c], self.nodes.shape[2:5])

    def deform(self, c: int, t: int, X: np.ndarray) -> np.ndarray:
        """Positions at frame ``t`` of material points ``X (k, 3)`` moving with component ``c``."""
        return trilinear(self.grid(c), self.nodes[t, c], X)

    def gradient(self, c: int, t: int, X: np.ndarray) -> np.ndarray:
        """Deformation gradients ``(k, 3, 3)`` (``F[i, a, b] = d x_a / d X_b``)."""
        g = self.grid(c)
        N = self.nodes[t, c]
        D = np.stack(np.gradient(N, *g.spacing, axis=(0, 1, 2), edge_order=1), axis=-1)  # (n,n,n,3,3)
        return trilinear(g, D.reshape(D.shape[:3] + (9,)), X).reshape(-1, 3, 3)

    def trajectories(self, c: int, X: np.ndarray) -> np.ndarray:
        """Positions of ``X`` moving with component ``c`` in every frame, ``(T, k, 3)``."""
        g = self.grid(c)
        # one interpolation with the frames as channels
        N = np.moveaxis(self.nodes[:, c], 0, 3).reshape(self.nodes.shape[2:5] + (-1,))
        return trilinear(g, N, X).reshape(len(X), self.n_frames, 3).transpose(1, 0, 2)


def exterior_points(BV: np.ndarray, BF: np.ndarray, component: np.ndarray, n: int) -> list[np.ndarray]:
    """Corners of each component's exterior triangles (with repeats), one array per component."""
    return [BV[BF[component == c]].reshape(-1, 3) for c in range(n)]


def lattice_animation(points: list[np.ndarray], motion: Callable[[int, int, np.ndarray], np.ndarray],
                      frames: int, n: int = 2, shared: bool = False) -> CoarseAnimation:
    """Sample ``motion(c, t, X) -> x`` on an ``n^3`` lattice around each component's points.

    With ``shared``, every component's lattice spans the whole object, so
    components that follow the same smooth field are interpolated
    identically and do not drift apart before they break.
    """
    C = len(points)
    lo, hi = np.empty((C, 3)), np.empty((C, 3))
    nodes = np.empty((frames, C, n, n, n, 3))
    everything = lattice_box(np.concatenate(points))
    for c, X in enumerate(points):
        lo[c], hi[c] = everything if shared else lattice_box(X)
        rest = Grid.from_bounds(lo[c], hi[c], (n, n, n)).points()
        for t in range(frames):
            nodes[t, c] = motion(c, t, rest).reshape(n, n, n, 3)
    return CoarseAnimation(lo, hi, nodes)


def lattice_box(X: np.ndarray, margin: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """A rest-pose lattice box around points, grown by ``margin`` of its diagonal.

    Interpolation clamps outside the box, so the margin keeps points near a
    component (exterior vertices of triangles that straddle a cut) inside it.
    """
    lo, hi = X.min(axis=0), X.max(axis=0)
    pad = margin * float(np.linalg.norm(hi - lo)) + tol.zero
    return lo - pad, hi + pad


def rigid_fit(X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rotation and translation with ``Y ~ X R^T + t`` (Kabsch)."""
    cx, cy = X.mean(axis=0), Y.mean(axis=0)
    H = (X - cx).T @ (Y - cy)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, cy - cx @ R.T


def affine_fit(X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares affine map with ``Y ~ X A^T + b``."""
    H = np.concatenate([X, np.ones((len(X), 1))], axis=1)
    sol, *_ = np.linalg.lstsq(H, Y, rcond=None)
    return sol[:3].T, sol[3]


def _trilinear_weights(grid: Grid, X: np.ndarray) -> sp.csr_matrix:
    """Sparse ``(k, nodes)`` matrix of trilinear weights (rows sum to 1)."""
    shape = np.asarray(grid.shape)
    f = np.clip((X - grid.origin) / grid.spacing, 0, shape - 1)
    i = np.minimum(f.astype(np.int64), shape - 2)
    t = f - i
    rows, cols, vals = [], [], []
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                w = (t[:, 0] if dx else 1 - t[:, 0]) * (t[:, 1] if dy else 1 - t[:, 1]) * (t[:, 2] if dz else 1 - t[:, 2])
                idx = np.ravel_multi_index((i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz), grid.shape)
                rows.append(np.arange(len(X)))
                cols.append(idx)
                vals.append(w)
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(len(X), grid.size))


def fit_lattice(X: np.ndarray, Y: np.ndarray, lo, hi, n: int = 2, rigid_tolerance: float = 0.0):
    """Fit a lattice deformation taking rest points ``X`` to deformed points ``Y``.

    A rigid fit is used when its largest error is within ``rigid_tolerance``;
    otherwise the lattice nodes are fitted by least squares, regularised
    toward the best affine map (which pins nodes no point constrains).

    Returns
    -------
    nodes : (n, n, n, 3) float
    residual : float
        Largest distance between a fitted and a given point.
    rigid_residual : float
        Largest error of the rigid fit alone.
    """
    grid = Grid.from_bounds(lo, hi, (n, n, n))
    rest_nodes = grid.points()
    R, t = rigid_fit(X, Y)
    rigid_residual = float(np.linalg.norm(X @ R.T + t - Y, axis=1).max())
    if rigid_residual <= rigid_tolerance:
        return (rest_nodes @ R.T + t).reshape(n, n, n, 3), rigid_residual, rigid_residual
    A, b = affine_fit(X, Y)
    prior = rest_nodes @ A.T + b
    W = _trilinear_weights(grid, X)
    M = sp.vstack([W, AFFINE_PRIOR_WEIGHT * sp.identity(grid.size)]).tocsr()
    nodes = np.empty_like(prior)
    for k in range(3):
        rhs = np.concatenate([Y[:, k] - W @ prior[:, k], np.zeros(grid.size)])
        nodes[:, k] = prior[:, k] + lsqr(M, rhs, atol=tol.lsqr, btol=tol.lsqr)[0]
    residual = float(np.linalg.norm(W @ nodes - Y, axis=1).max())
    return nodes.reshape(n, n, n, 3), residual, rigid_residual
