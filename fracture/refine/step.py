"""Step control of the gradient flow: the implicit area term, the move limits and the step size.

Eq. 3's velocity is ``v = (L_w x) / A - grad psi``: an area term (the
cotangent Laplacian ``L_w`` whose triangles are weighted by their mean psi,
``w_j > 0``) and a gradient term. Taken explicitly the area term is stable
only for steps below about ``h_e^2 / w`` (``h_e`` the shortest edge): once the
surface is split into small triangles every step is tiny and the surface
freezes before it has reached the weak material. Here the area term is taken
at the end of the step (backward Euler), the gradient term at its start:

    (M - tau L_w) d = tau M v,        M = diag(A_i),

one sparse symmetric positive definite solve per step (the three coordinates
share the matrix and its factorisation; a step retried with a smaller ``tau``
reuses its order and symbolic analysis, :class:`ImplicitStep`).
It is unconditionally stable, agrees with the explicit step ``tau v`` to first
order in ``tau`` and has the same fixed points (``d = 0`` exactly where
``v = 0``), so a vertex moves on the order of a grid cell per step at any mesh
resolution.

The moves are then limited, per vertex: no move longer than ``cap`` (a grid
cell: the field has no finer detail, and a thin weak layer must not be
stepped over), and no two corners of a triangle moving relative to each
other by more than ``fold`` of its smallest altitude (so no corner crosses
its opposite edge and no triangle turns over within a step; a smooth move of
a whole neighbourhood by many edge lengths is allowed). Boundary vertices
move at most ``BOUNDARY_MOVE`` of their shortest edge: they slide on B, where
the boundary curves of two sheets can cross without their chords meeting in
space (continuous collision detection cannot see it), so no boundary vertex
may overtake a neighbour on B.

The step size ``tau`` starts every stage of the schedule at its nominal
value: a vertex where grad psi has its root mean square over the grid moves
``step`` grid cells (a scale of the field, not of the surface's current
speeds, which vanish as it settles). It grows by a quarter after an accepted
step (up to four times its start) and is halved when a step would raise the
minimised functional (the engine retries, then rejects the step), down to
1/64 of its start: a step that raises the functional even then means that
the surface is at a minimum of the discrete functional.
"""

from __future__ import annotations

import numba
import numpy as np
import qdldl
import scipy.sparse as sp
from fracture.tolerances import tol

# compiled code reads tolerances as module constants (fracture/tolerances.py says why each)
_TINY = tol.tiny

# Boundary vertices move at most this fraction of their shortest edge per step (module notes).
BOUNDARY_MOVE = 0.3


def weighted_cotangent_laplacian(V: np.ndarray, F: np.ndarray, w: np.ndarray) -> sp.csr_matrix:
    """``L_w = sum_j w_j L_j``: the cotangent Laplacian (negative semi-definite, libigl's sign) with
    triangle ``j`` weighted by ``w_j``; ``(L_w x)_i = -sum_j w_j dA_j/dx_i``.

    Written out rather than taken from ``igl.cotmatrix`` because of the
    per-triangle weights and because the surface is non-manifold (every
    triangle on an edge adds its cotangent, however many there are).
    """
    n = len(V)
    T = V[F]
    cots = np.empty((len(F), 3))
    for k in range(3):  # the angle at corner k is opposite edge (k+1, k+2)
        a = T[:, (k + 1) % 3] - T[:, k]
        b = T[:, (k + 2) % 3] - T[:, k]
        cross = np.linalg.norm(np.cross(a, b), axis=1)
        cots[:, k] = np.einsum("ij,ij->i", a, b) / np.maximum(cross, _TINY)
    c = 0.5 * cots * w[:, None]
    i = np.concatenate([F[:, 1], F[:, 2], F[:, 0]])
    j = np.concatenate([F[:, 2], F[:, 0], F[:, 1]])
    c = np.concatenate([c[:, 0], c[:, 1], c[:, 2]])
    off = sp.coo_matrix((np.r_[c, c], (np.r_[i, j], np.r_[j, i])), shape=(n, n)).tocsr()
    return off - sp.diags(np.asarray(off.sum(axis=1)).ravel())


class ImplicitStep:
    """Solves ``(M - tau L_w) d = tau M v`` (module notes) step after step, keeping its last
    factorisation.

    The matrix is symmetric positive definite (``M`` positive, ``L_w`` a sum
    of negative semi-definite triangle terms with positive weights), so it is
    factorised as ``L D L^T`` by QDLDL (an AMD fill-reducing order, then a
    simplicial factorisation; the three coordinates share it). A step tried
    again with a smaller ``tau`` after a rejected one, or any matrix of the
    same sparsity pattern, keeps the order and the symbolic analysis and is
    only factorised numerically again (a quarter of a fresh factorisation's
    cost on the branch; ``benchmarks/README.md`` compares the solvers).
    """

    def __init__(self):
        self._K = self._ldl = None
        self.factorisations = self.reuses = 0

    def __call__(self, L: sp.csr_matrix, area: np.ndarray, v: np.ndarray, tau: float) -> np.ndarray:
        """The displacement ``d``, ``(n, 3)``: ``L`` is :func:`weighted_cotangent_laplacian` (it does not
        depend on ``tau``), ``area`` the barycentric vertex area ``A_i`` (the diagonal of ``M``),
        ``v`` the explicit velocity of Eq. 3."""
        M = np.maximum(area, _TINY)
        K = sp.triu(sp.diags(M) - tau * L, format="csc")  # QDLDL reads the upper triangle
        K.sort_indices()
        if self._ldl is not None and self._same_pattern(K):
            self._ldl.update(K, upper=True)
            self.reuses += 1
        else:
            self._ldl = qdldl.Solver(K, upper=True)
            self.factorisations += 1
        self._K = K
        b = tau * M[:, None] * v
        return np.column_stack([self._ldl.solve(np.ascontiguousarray(b[:, k])) for k in range(3)])

    def _same_pattern(self, K: sp.csc_matrix) -> bool:
        old = self._K
        return (old.shape == K.shape and old.nnz == K.nnz and np.array_equal(old.indptr, K.indptr)
                and np.array_equal(old.indices, K.indices))


def implicit_step(L: sp.csr_matrix, area: np.ndarray, v: np.ndarray, tau: float) -> np.ndarray:
    """The displacement ``d`` of ``(M - tau L_w) d = tau M v`` (module notes), ``(n, 3)``, by a
    factorisation of its own (:class:`ImplicitStep` keeps one across steps)."""
    return ImplicitStep()(L, area, v, tau)


@numba.njit(cache=True)
def limit_moves(V, F, d, fold, cap):
    """Scale the moves ``d`` in place (module notes): each to at most ``cap``, and each vertex's so that on
    the edges of its triangles the two ends' moves differ by at most ``fold`` of the triangle's smallest
    altitude. Returns how many vertices were limited."""
    n = V.shape[0]
    scale = np.ones(n)
    for i in range(n):
        move = np.sqrt(d[i, 0] ** 2 + d[i, 1] ** 2 + d[i, 2] ** 2)
        if move > cap:
            scale[i] = cap / move
    for f in range(F.shape[0]):
        # the triangle's smallest altitude: a corner that moves this far relative to the others can
        # cross the opposite edge
        longest = 0.0
        for k in range(3):
            a, b = F[f, k], F[f, (k + 1) % 3]
            longest = max(longest, np.sqrt((V[b, 0] - V[a, 0]) ** 2 + (V[b, 1] - V[a, 1]) ** 2
                                           + (V[b, 2] - V[a, 2]) ** 2))
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        ux, uy, uz = V[b, 0] - V[a, 0], V[b, 1] - V[a, 1], V[b, 2] - V[a, 2]
        vx, vy, vz = V[c, 0] - V[a, 0], V[c, 1] - V[a, 1], V[c, 2] - V[a, 2]
        twice = np.sqrt((uy * vz - uz * vy) ** 2 + (uz * vx - ux * vz) ** 2 + (ux * vy - uy * vx) ** 2)
        altitude = twice / max(longest, _TINY)
        for k in range(3):
            a, b = F[f, k], F[f, (k + 1) % 3]
            rx, ry, rz = d[b, 0] - d[a, 0], d[b, 1] - d[a, 1], d[b, 2] - d[a, 2]
            rel = np.sqrt(rx * rx + ry * ry + rz * rz)
            if rel > fold * altitude:
                s = fold * altitude / rel
                scale[a] = min(scale[a], s)
                scale[b] = min(scale[b], s)
    limited = 0
    for i in range(n):
        if scale[i] < 1.0:
            limited += 1
            d[i, 0] *= scale[i]
            d[i, 1] *= scale[i]
            d[i, 2] *= scale[i]
    return limited


@numba.njit(cache=True)
def limit_by_shortest_edge(V, F, d, ids, fraction):
    """Scale the moves ``d[ids]`` in place to at most ``fraction`` of each vertex's shortest edge."""
    n = V.shape[0]
    mark = np.zeros(n, np.bool_)
    for i in ids:
        mark[i] = True
    shortest = np.full(n, np.inf)
    for f in range(F.shape[0]):
        for k in range(3):
            a, b = F[f, k], F[f, (k + 1) % 3]
            if mark[a] or mark[b]:
                length = np.sqrt((V[b, 0] - V[a, 0]) ** 2 + (V[b, 1] - V[a, 1]) ** 2 + (V[b, 2] - V[a, 2]) ** 2)
                shortest[a] = min(shortest[a], length)
                shortest[b] = min(shortest[b], length)
    for i in ids:
        move = np.sqrt(d[i, 0] ** 2 + d[i, 1] ** 2 + d[i, 2] ** 2)
        limit = fraction * shortest[i]
        if move > limit:
            s = limit / move
            d[i, 0] *= s
            d[i, 1] *= s
            d[i, 2] *= s


class StepSize:
    """``tau`` of the flow (module notes): set per stage from the field, grown after accepted steps,
    halved after rejected ones, never below 1/64 of its start."""

    GROW, SHRINK, MOST, LEAST = 1.25, 0.5, 4.0, 1.0 / 64.0

    def __init__(self, step_cells: float, h: float):
        self.step, self.h = step_cells, h
        self.tau = self.start = 0.0

    def begin(self, gradient_scale: float) -> float:
        """Start a stage: the nominal ``tau`` moves a vertex where grad psi is ``gradient_scale`` (the
        stage field's root mean square gradient) by ``step`` grid cells."""
        self.tau = self.start = self.step * self.h / max(gradient_scale, _TINY)
        return self.tau

    @property
    def at_least(self) -> bool:
        """``tau`` is as small as it gets: a rejected step now means the surface cannot descend."""
        return self.tau <= self.LEAST * self.start

    def accepted(self) -> None:
        self.tau = min(self.tau * self.GROW, self.MOST * self.start)

    def rejected(self) -> None:
        self.tau = max(self.tau * self.SHRINK, self.LEAST * self.start)
