"""Alpha-expansion (Boykov, Veksler and Zabih, "Fast approximate energy minimization via graph cuts",
PAMI 2001) of a Potts energy with a weight per edge, on PyMaxflow's max-flow.

The energy of labels ``l`` on a graph with edges ``(p, q)`` of weight
``w_pq >= 0`` is ``E(l) = sum w_pq [l_p != l_q]``: the weighted area of the
boundaries between labels. Some nodes are fixed. An expansion move on label
``a`` lets every free node either keep its label or take ``a``; the best such
move is a minimum cut (the Potts term is a metric, so the move's binary
energy is submodular), and moves on every label in turn, until none lowers
the energy, reach a local minimum within twice the global one; with two
labels it is the global minimum.

PyMaxflow builds the graph from arrays (``add_edges``, ``add_grid_tedges``) and
solves it with Boykov and Kolmogorov's algorithm; gco-wrapper's expansion
would round the weights to integers and take dense per-label costs.
"""

from __future__ import annotations

from dataclasses import dataclass

import maxflow
import numpy as np


@dataclass(frozen=True)
class PottsGraph:
    """Edges ``(p, q)`` with weights ``w`` (the three arrays aligned) between nodes ``0..n-1``."""

    n: int
    p: np.ndarray
    q: np.ndarray
    w: np.ndarray

    def energy(self, labels: np.ndarray) -> float:
        return float(self.w[labels[self.p] != labels[self.q]].sum())


@dataclass
class ExpansionLog:
    energy: list  # after each cycle over the labels, entry 0 the start
    moves: int = 0  # expansions that changed labels


def expand(graph: PottsGraph, labels: np.ndarray, free: np.ndarray, reach: dict | None = None,
           cycles: int = 4) -> tuple[np.ndarray, ExpansionLog]:
    """Labels that lower ``graph``'s Potts energy by expansion moves from ``labels`` (free nodes only).

    ``reach[a]`` (optional) are the nodes that may take label ``a`` (default: every free node): a
    region with no energy of its own never grows an island of ``a`` away from ``a``'s nodes, so the
    caller may limit each move to the nodes near them. Cycles over the labels until one changes nothing
    or ``cycles`` are done.
    """
    labels = np.array(labels, np.int64, copy=True)
    free = np.asarray(free, bool)
    every = np.flatnonzero(free)
    log = ExpansionLog([graph.energy(labels)])
    for _ in range(cycles):
        changed = False
        for a in np.unique(labels):
            nodes = every if reach is None else np.asarray(reach.get(int(a), every))
            nodes = nodes[free[nodes] & (labels[nodes] != a)]
            if not len(nodes):
                continue
            switch = _move(graph, labels, nodes, int(a))
            if switch.any():
                labels[nodes[switch]] = a
                changed = True
                log.moves += 1
        log.energy.append(graph.energy(labels))
        if not changed:
            break
    return labels, log


def _move(graph: PottsGraph, labels: np.ndarray, nodes: np.ndarray, a: int) -> np.ndarray:
    """The best expansion of label ``a`` over ``nodes`` (the others keep their labels): which of them
    take ``a``.

    A node's binary variable x is 1 when it takes ``a``. An edge between two
    moving nodes costs ``A, B, C, D`` for ``(x_p, x_q) = (0,0), (0,1), (1,0),
    (1,1)``, which is ``A + (C - A) x_p + (D - C) x_q + (B + C - A - D)
    (1 - x_p) x_q``: two unary terms and an arc ``p -> q`` (cut when p keeps
    and q takes ``a``). An edge with one moving end is a unary term of it.
    """
    local = np.full(graph.n, -1, np.int64)
    local[nodes] = np.arange(len(nodes))
    lp, lq = local[graph.p], local[graph.q]
    touch = (lp >= 0) | (lq >= 0)
    P, Q, W = graph.p[touch], graph.q[touch], graph.w[touch]
    lp, lq = lp[touch], lq[touch]
    Lp, Lq = labels[P], labels[Q]
    A = W * (Lp != Lq)
    B = W * (Lp != a)
    C = W * (Lq != a)
    n = len(nodes)
    cost0 = np.zeros(n)  # energy of each node keeping its label (unary parts)
    cost1 = np.zeros(n)  # ... taking a
    both = (lp >= 0) & (lq >= 0)
    only_p = (lp >= 0) & ~both
    only_q = (lq >= 0) & ~both
    cost1 += np.bincount(lp[both], C[both] - A[both], n)
    cost1 -= np.bincount(lq[both], C[both], n)  # (D - C) x_q with D = 0
    cost0 += np.bincount(lp[only_p], A[only_p], n)
    cost1 += np.bincount(lp[only_p], C[only_p], n)  # p takes a, q keeps Lq: W [Lq != a]
    cost0 += np.bincount(lq[only_q], A[only_q], n)
    cost1 += np.bincount(lq[only_q], B[only_q], n)  # q takes a, p keeps Lp: W [Lp != a]
    K = B[both] + C[both] - A[both]
    g = maxflow.Graph[float](n, int(both.sum()))
    ids = g.add_nodes(n)
    arcs = K > 0
    if arcs.any():
        g.add_edges(lp[both][arcs], lq[both][arcs], K[arcs], np.zeros(int(arcs.sum())))
    low = np.minimum(cost0, cost1)
    # x = 1 is the sink's side: the arc from the source is cut then, so it carries cost1
    g.add_grid_tedges(ids, cost1 - low, cost0 - low)
    g.maxflow()
    return np.asarray(g.get_grid_segments(ids), bool)
