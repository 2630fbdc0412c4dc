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
the surface is at a minimum of what the step reaches (the stage has
settled; on a searched surface already when every attempt of one iteration
raises it: :mod:`fracture.refine.engine`).
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np
import qdldl
import scipy.sparse as sp

from fracture.mesh import vec
from fracture.mesh.edges import EdgeTable, edge_table
from fracture.tolerances import tol

# compiled code reads tolerances as module constants (fracture/tolerances.py says why each)
_TINY = tol.tiny

# Boundary vertices move at most this fraction of their shortest edge per step (module notes).
BOUNDARY_MOVE = 0.3


class CotangentWeights(NamedTuple):
    """The weighted cotangent Laplacian ``L_w`` of a surface by its edges: edge ``e`` joins vertices
    ``lo[e] < hi[e]``, ``L_w[lo, hi] = L_w[hi, lo] = weight[e]``, and each row sums to zero (libigl's
    sign: negative semi-definite)."""

    lo: np.ndarray
    hi: np.ndarray
    weight: np.ndarray
    n: int

    def matrix(self) -> sp.csr_matrix:
        """``L_w`` as a sparse matrix ``(n, n)``."""
        i, j, c = self.lo, self.hi, self.weight
        off = sp.coo_matrix((np.r_[c, c], (np.r_[i, j], np.r_[j, i])), shape=(self.n, self.n)).tocsr()
        return off - sp.diags(np.asarray(off.sum(axis=1)).ravel())


def cotangent_weights(V: np.ndarray, F: np.ndarray, w: np.ndarray, table: EdgeTable | None = None) -> CotangentWeights:
    """``L_w = sum_j w_j L_j``: the cotangent Laplacian with triangle ``j`` weighted by ``w_j``;
    ``(L_w x)_i = -sum_j w_j dA_j/dx_i``. ``table`` is the edge table of ``F``, if known.

    Written out rather than taken from ``igl.cotmatrix`` because of the
    per-triangle weights and because the surface is non-manifold (every
    triangle on an edge adds its cotangent, however many there are).
    """
    V = np.ascontiguousarray(V, np.float64)
    F = np.ascontiguousarray(F, np.int64)
    table = edge_table(F, len(V)) if table is None else table
    lo, hi, c = _edge_weights(V, F, np.ascontiguousarray(w, np.float64), table.eid, table.first)
    return CotangentWeights(lo, hi, c, len(V))


def weighted_cotangent_laplacian(V: np.ndarray, F: np.ndarray, w: np.ndarray) -> sp.csr_matrix:
    """:func:`cotangent_weights` as a sparse matrix."""
    return cotangent_weights(V, F, w).matrix()


@numba.njit(cache=True)
def _edge_weights(V, F, w, eid, first):
    """Per edge its two vertices (the lower first) and ``sum_j w_j cot(angle opposite it in j) / 2``."""
    ne = first.shape[0]
    lo = np.empty(ne, np.int64)
    hi = np.empty(ne, np.int64)
    for e in range(ne):
        f, k = first[e] // 3, first[e] % 3
        a, b = F[f, k], F[f, (k + 1) % 3]
        lo[e], hi[e] = min(a, b), max(a, b)
    c = np.zeros(ne)
    for f in range(F.shape[0]):
        for k in range(3):  # the angle at corner k is opposite edge (k+1, k+2), the directed edge 3 f + k + 1
            o = vec.point(V, F[f, k])
            a = vec.sub(vec.point(V, F[f, (k + 1) % 3]), o)
            b = vec.sub(vec.point(V, F[f, (k + 2) % 3]), o)
            c[eid[3 * f + (k + 1) % 3]] += 0.5 * w[f] * vec.dot(a, b) / max(vec.norm(vec.cross(a, b)), _TINY)
    return lo, hi, c


class _UpperPattern(NamedTuple):
    """The upper triangle of ``M - tau L_w`` by compressed columns (what QDLDL reads): per column its
    rows, ascending, the diagonal last; and where each edge's and each vertex's entry goes."""

    indptr: np.ndarray
    indices: np.ndarray
    edge_slot: np.ndarray
    diagonal_slot: np.ndarray


@numba.njit(cache=True)
def _upper_pattern(lo, hi, n):
    indptr = np.zeros(n + 1, np.int64)
    for e in range(lo.shape[0]):
        indptr[hi[e] + 1] += 1
    for j in range(n):
        indptr[j + 1] += indptr[j] + 1  # + 1: the diagonal
    fill = indptr[:-1].copy()
    indices = np.empty(indptr[n], np.int64)
    edge_slot = np.empty(lo.shape[0], np.int64)
    for e in np.argsort(lo, kind="mergesort"):  # each column's rows come in ascending
        p = fill[hi[e]]
        fill[hi[e]] += 1
        indices[p] = lo[e]
        edge_slot[e] = p
    diagonal_slot = indptr[1:] - 1
    for j in range(n):
        indices[diagonal_slot[j]] = j
    return _UpperPattern(indptr, indices, edge_slot, diagonal_slot)


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
    cost on the branch; ``docs/design-measurements.md`` compares the solvers).
    """

    def __init__(self):
        self._L = self._pattern = self._ldl = self._row_sums = None
        self.factorisations = self.reuses = 0

    def __call__(self, L: CotangentWeights, area: np.ndarray, v: np.ndarray, tau: float) -> np.ndarray:
        """The displacement ``d``, ``(n, 3)``: ``L`` is :func:`cotangent_weights` (it does not depend on
        ``tau``), ``area`` the barycentric vertex area ``A_i`` (the diagonal of ``M``), ``v`` the
        explicit velocity of Eq. 3. The matrix is written straight into QDLDL's form, the upper
        triangle by columns, whose pattern is kept while the edges stay the same."""
        if L is not self._L:  # a retried step passes the same weights: pattern and row sums as they were
            old = self._L
            if old is None or not (old.n == L.n and np.array_equal(old.lo, L.lo) and np.array_equal(old.hi, L.hi)):
                self._pattern, self._ldl = _upper_pattern(L.lo, L.hi, L.n), None
            self._L, self._row_sums = L, np.bincount(L.lo, L.weight, L.n) + np.bincount(L.hi, L.weight, L.n)
        pattern = self._pattern
        M = np.maximum(area, _TINY)
        data = np.empty(len(pattern.indices))
        data[pattern.edge_slot] = -tau * L.weight
        data[pattern.diagonal_slot] = M + tau * self._row_sums
        K = sp.csc_matrix((data, pattern.indices, pattern.indptr), shape=(L.n, L.n))
        if self._ldl is None:
            self._ldl = qdldl.Solver(K, upper=True)
            self.factorisations += 1
        else:
            self._ldl.update(K, upper=True)
            self.reuses += 1
        b = tau * M[:, None] * v
        return np.column_stack([self._ldl.solve(np.ascontiguousarray(b[:, k])) for k in range(3)])


def implicit_step(L: CotangentWeights, area: np.ndarray, v: np.ndarray, tau: float) -> np.ndarray:
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
        move = vec.norm(vec.point(d, i))
        if move > cap:
            scale[i] = cap / move
    for f in range(F.shape[0]):
        # the triangle's smallest altitude: a corner that moves this far relative to the others can
        # cross the opposite edge
        longest = 0.0
        for k in range(3):
            longest = max(longest, vec.norm(vec.sub(vec.point(V, F[f, (k + 1) % 3]), vec.point(V, F[f, k]))))
        A = vec.point(V, F[f, 0])
        twice = vec.norm(vec.cross(vec.sub(vec.point(V, F[f, 1]), A), vec.sub(vec.point(V, F[f, 2]), A)))
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
                length = vec.norm(vec.sub(vec.point(V, b), vec.point(V, a)))
                shortest[a] = min(shortest[a], length)
                shortest[b] = min(shortest[b], length)
    for i in ids:
        move = vec.norm(vec.point(d, i))
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
