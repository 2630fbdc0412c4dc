"""Edge tables of triangle lists (numba): every undirected edge's id, its triangle count and its first
two directed edges, built in O(m) by bucketing directed edges by their lower vertex (a counting sort)
instead of sorting keys. Every module that asks which edges a surface has, and how many triangles
are on each, asks this one table."""

from __future__ import annotations

from functools import cached_property
from typing import NamedTuple

import numba
import numpy as np


class EdgeArrays(NamedTuple):
    """The arrays of an edge table, as compiled code takes them (:class:`EdgeTable` names them for
    Python): per directed triangle edge its edge id, per edge its triangle count and first two
    directed edges, and the directed edges bucketed by their lower vertex (``start`` CSR ranges
    over ``hi``, the upper vertex, and ``row``, the directed edge ``3 f + k``)."""

    eid: np.ndarray
    count: np.ndarray
    first: np.ndarray
    second: np.ndarray
    start: np.ndarray
    hi: np.ndarray
    row: np.ndarray


@numba.njit(cache=True)
def _edge_table(F, n):
    m = F.shape[0]
    start = np.zeros(n + 1, np.int64)
    for f in range(m):
        for k in range(3):
            a, b = F[f, k], F[f, (k + 1) % 3]
            start[min(a, b) + 1] += 1
    for v in range(n):
        start[v + 1] += start[v]
    fill = start[:-1].copy()
    hi = np.empty(3 * m, np.int64)
    row = np.empty(3 * m, np.int64)
    for f in range(m):
        for k in range(3):
            a, b = F[f, k], F[f, (k + 1) % 3]
            lo = min(a, b)
            p = fill[lo]
            fill[lo] += 1
            hi[p] = max(a, b)
            row[p] = 3 * f + k
    eid = np.full(3 * m, -1, np.int64)
    ne = 0
    for v in range(n):
        for p in range(start[v], start[v + 1]):
            if eid[row[p]] >= 0:
                continue
            eid[row[p]] = ne
            for q in range(p + 1, start[v + 1]):
                if hi[q] == hi[p]:
                    eid[row[q]] = ne
            ne += 1
    count = np.zeros(ne, np.int64)
    first = np.full(ne, -1, np.int64)
    second = np.full(ne, -1, np.int64)
    for d in range(3 * m):
        e = eid[d]
        if count[e] == 0:
            first[e] = d
        elif count[e] == 1:
            second[e] = d
        count[e] += 1
    return EdgeArrays(eid, count, first, second, start, hi, row)


@numba.njit(cache=True, inline="always")
def find_edge(start, hi, row, eid, a, b):
    lo, up = min(a, b), max(a, b)
    if lo + 1 >= start.shape[0]:
        return -1
    for p in range(start[lo], start[lo + 1]):
        if hi[p] == up:
            return eid[row[p]]
    return -1


@numba.njit(cache=True)
def _find_edges(start, hi, row, eid, E):
    out = np.empty(E.shape[0], np.int64)
    for i in range(E.shape[0]):
        out[i] = find_edge(start, hi, row, eid, E[i, 0], E[i, 1])
    return out


class EdgeTable(EdgeArrays):
    """The undirected edges of a triangle list: :class:`EdgeArrays` with the questions asked of them.

    Attributes
    ----------
    eid : (3m,) int
        Edge id of directed triangle edge ``3 f + k`` (``F[f, k] -> F[f, k+1]``).
    count : (ne,) int
        Number of triangles on each edge.
    first, second : (ne,) int
        The first two directed edges (rows ``3 f + k``) of each edge; -1 if none.
    start, hi, row
        The directed edges bucketed by their lower vertex.
    """

    def arrays(self) -> EdgeArrays:
        """The table's arrays as a plain :class:`EdgeArrays`, for compiled code."""
        return EdgeArrays(*self)

    @cached_property
    def row_count(self) -> np.ndarray:
        """Triangle count of the edge of every directed triangle edge, ``(3m,)`` (the table is not
        edited once built: computed once, like the next one)."""
        return self.count[self.eid]

    @cached_property
    def boundary_rows(self) -> np.ndarray:
        """Directed triangle edges ``3 f + k`` on edges with one triangle, in row order."""
        return np.flatnonzero(self.row_count == 1)

    def find(self, E: np.ndarray) -> np.ndarray:
        """Edge ids of vertex pairs ``E (k, 2)`` (-1 where there is no such edge)."""
        E = np.ascontiguousarray(E, np.int64).reshape(-1, 2)
        return _find_edges(self.start, self.hi, self.row, self.eid, E)

    def rows_of(self, eids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The directed triangle edges (rows ``3 f + k``) on the edges ``eids``, and each row's index into ``eids``."""
        slot = np.full(len(self.count), -1)
        slot[eids] = np.arange(len(eids))
        which = slot[self.eid]
        rows = np.flatnonzero(which >= 0)
        return rows, which[rows]

    def independent(self, eids: np.ndarray) -> np.ndarray:
        """Mask over the edges ``eids`` (in order of priority) of those that come first on every triangle
        they are on: a set of edges no triangle carries two of, as :meth:`FractureSurface.split_edges` needs."""
        rows, which = self.rows_of(eids)
        first = first_per_group(rows // 3, which)
        keep = np.ones(len(eids), bool)
        keep[which[~first]] = False
        return keep


def first_per_group(key: np.ndarray, rank: np.ndarray) -> np.ndarray:
    """Mask of the lowest-``rank`` entry of each ``key`` group."""
    if not len(key):
        return np.zeros(0, bool)
    order = np.lexsort((rank, key))
    first = np.r_[True, key[order][1:] != key[order][:-1]]
    mask = np.zeros(len(key), bool)
    mask[order[first]] = True
    return mask


def row_edges(F: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Vertex pairs ``(k, 2)`` of directed triangle edges ``rows`` (``3 f + k``), as directed in their triangle."""
    f, k = rows // 3, rows % 3
    return np.stack([F[f, k], F[f, (k + 1) % 3]], 1)


def edge_table(F: np.ndarray, n: int) -> EdgeTable:
    """Build the :class:`EdgeTable` of triangles ``F`` over ``n`` vertices, in O(m)."""
    return EdgeTable(*_edge_table(np.ascontiguousarray(F, np.int64), int(n)))
