"""The discrete gradient flow of Eq. 3 (Section 4.3) on a non-manifold triangle surface.

The energy is E(S) = integral of psi over S, discretised per triangle as
``A_j * mean(psi at its corners)``. Its derivative with respect to vertex
``i``, with grad psi taken at ``x_i`` inside each triangle (the paper's
assumption), is

    dE/dx_i = sum_j [ A_j / 3 * grad psi(x_i) + psibar_j * dA_j/dx_i ],
    dA_j/dx_i = 1/2 n_j x e_j^i,

where ``e_j^i`` is the edge of triangle ``j`` opposite ``i`` (counter-clockwise)
and ``n_j`` its unit normal. The velocity is ``-dE/dx_i / A_i`` with ``A_i``
the barycentric area (a third of the 1-ring area). This is Eq. 3 with its
constants made consistent: with psi = 1 it is exactly the mean-curvature-normal
flow of Meyer et al. 2002 with barycentric areas (``-L x / M`` for the
cotangent Laplacian ``L``), and for a planar 1-ring and a linear psi with an
in-plane gradient it vanishes, as the paper notes. The sum runs over every
triangle at a vertex, however many sheets meet there, so vertices on
non-manifold junctions move once and consistently for every component.
"""

from __future__ import annotations

import numpy as np

from fracture.topology import face_frames, scatter_add


def energy_gradient(V: np.ndarray, F: np.ndarray, psi: np.ndarray, grad: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """dE/dx_i and the barycentric vertex areas.

    Parameters
    ----------
    V, F : surface (any number of triangles per edge).
    psi : (n,) float
        psi at the vertices.
    grad : (n, 3) float
        grad psi at the vertices.

    Returns
    -------
    dE : (n, 3) float
    area : (n,) float
        Barycentric area of every vertex (0 for unused vertices).
    """
    n = len(V)
    A, N = face_frames(V, F)
    psibar = psi[F].mean(axis=1)
    area = np.bincount(F.ravel(), np.repeat(A / 3.0, 3), minlength=n)
    terms = []
    for k in range(3):
        e = V[F[:, (k + 2) % 3]] - V[F[:, (k + 1) % 3]]
        terms.append(0.5 * psibar[:, None] * np.cross(N, e))
    dA = scatter_add(F.T.ravel(), np.concatenate(terms), n)
    return area[:, None] * grad + dA, area


def velocity(V: np.ndarray, F: np.ndarray, psi: np.ndarray, grad: np.ndarray) -> np.ndarray:
    """Eq. 3: the velocity ``-dE/dx_i / A_i`` of every vertex, ``(n, 3)``."""
    dE, area = energy_gradient(V, F, psi, grad)
    return -dE / np.maximum(area, 1e-300)[:, None]


def energy(V: np.ndarray, F: np.ndarray, psi: np.ndarray) -> float:
    """E(S): psi integrated over the surface (linear in each triangle)."""
    A, _ = face_frames(V, F)
    return float((A * psi[F].mean(axis=1)).sum())


def sample_displacement(P: np.ndarray, T: np.ndarray, psi_p: np.ndarray, grad_p: np.ndarray,
                        psi_T: np.ndarray, dt: float) -> np.ndarray:
    """Displacement in one step of points inside triangles, each with its triangle as neighbourhood.

    The point ``p`` splits its triangle ``(a, b, c)`` into ``(p, b, c)``,
    ``(a, p, c)``, ``(a, b, p)``; Eq. 3 at ``p`` over these three (Section 4.4).

    Parameters
    ----------
    P : (k, 3) sample points; T : (k, 3, 3) corners of their triangles.
    psi_p, grad_p : psi and grad psi at the samples.
    psi_T : (k, 3) psi at the corners.
    """
    A = T[:, 0]
    nrm = np.cross(T[:, 1] - A, T[:, 2] - A)
    N = nrm / np.maximum(np.linalg.norm(nrm, axis=1), 1e-300)[:, None]
    dE = np.zeros_like(P)
    area = np.zeros(len(P))
    for k in range(3):  # sub-triangle with p in place of corner k; its edge opposite p is T's edge opposite k
        b, c = T[:, (k + 1) % 3], T[:, (k + 2) % 3]
        sub = 0.5 * np.linalg.norm(np.cross(b - P, c - P), axis=1)
        psibar = (psi_p + psi_T[:, (k + 1) % 3] + psi_T[:, (k + 2) % 3]) / 3.0
        dE += sub[:, None] / 3.0 * grad_p + 0.5 * psibar[:, None] * np.cross(N, c - b)
        area += sub / 3.0
    return -dt * dE / np.maximum(area, 1e-300)[:, None]
