"""Edge bookkeeping of triangle meshes, vectorised.

Every module that asks "which edges, how many triangles on each, which
triangle has this directed edge" asks it here.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree


def directed_edges(F: np.ndarray) -> np.ndarray:
    """The three directed edges of every triangle, ``(3m, 2)``; row ``3 f + k`` is edge ``k`` of face ``f``."""
    return np.asarray(F)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)


def _keys(E: np.ndarray, n: int) -> np.ndarray:
    return E[:, 0].astype(np.int64) * n + E[:, 1]


def unique_edges(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Undirected edges (sorted vertex pairs, in lexicographic order) and the number of triangles on each."""
    E = np.sort(directed_edges(F), axis=1).astype(np.int64)
    if not len(E):
        return np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
    n = int(E.max()) + 1
    keys, counts = np.unique(E[:, 0] * n + E[:, 1], return_counts=True)  # 1-D: far faster than axis=0
    return np.stack([keys // n, keys % n], 1), counts


def directed_edge_face(F: np.ndarray, E: np.ndarray) -> np.ndarray:
    """For each directed edge ``E[i] = (a, b)``, a triangle of ``F`` that has it, or -1.

    (In an oriented manifold mesh the triangle is unique.)
    """
    D = directed_edges(F)
    E = np.asarray(E, np.int64).reshape(-1, 2)
    n = int(max(D.max(initial=0), E.max(initial=0))) + 1
    keys = _keys(D, n)
    order = np.argsort(keys, kind="stable")
    q = _keys(E, n)
    pos = np.minimum(np.searchsorted(keys[order], q), len(order) - 1)
    found = keys[order][pos] == q
    return np.where(found, order[pos] // 3, -1)


def signed_volume(V: np.ndarray, F: np.ndarray) -> float:
    """Volume enclosed by a closed, outward triangle mesh (negative if inward)."""
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", A, np.cross(B, C)).sum() / 6.0)


def fan(polygons: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Fan triangles of polygons ``(t, 3)`` and the polygon each came from ``(t,)``."""
    if not polygons:
        return np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
    tris, owner = [], []
    for i, f in enumerate(polygons):
        k = len(f)
        tris.append(np.stack([np.full(k - 2, f[0]), f[1:-1], f[2:]], 1))
        owner.append(np.full(k - 2, i))
    return np.concatenate(tris).astype(np.int64), np.concatenate(owner)


def weld(P: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Cluster points closer than ``radius`` (transitively); returns cluster means and each point's cluster."""
    pairs = cKDTree(P).query_pairs(radius, output_type="ndarray")
    n = len(P)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)) if len(pairs) else \
        coo_matrix((n, n))
    _, label = connected_components(graph, directed=False)
    G = np.zeros((label.max() + 1, 3))
    np.add.at(G, label, P)
    G /= np.bincount(label)[:, None]
    return G, label
