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

from fracture.refine import kernels


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
    return kernels.energy_gradient(*_prepare(V, F), np.ascontiguousarray(psi, np.float64),
                                   np.ascontiguousarray(grad, np.float64))


def velocity(V: np.ndarray, F: np.ndarray, psi: np.ndarray, grad: np.ndarray) -> np.ndarray:
    """Eq. 3: the velocity ``-dE/dx_i / A_i`` of every vertex, ``(n, 3)``."""
    dE, area = energy_gradient(V, F, psi, grad)
    return -dE / np.maximum(area, 1e-300)[:, None]


def energy(V: np.ndarray, F: np.ndarray, psi: np.ndarray) -> float:
    """E(S): psi integrated over the surface (linear in each triangle)."""
    return float(kernels.energy(*_prepare(V, F), np.ascontiguousarray(psi, np.float64)))


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
    f64 = np.float64
    return kernels.sample_displacement(
        np.ascontiguousarray(P, f64), np.ascontiguousarray(T, f64), np.ascontiguousarray(psi_p, f64),
        np.ascontiguousarray(grad_p, f64), np.ascontiguousarray(psi_T, f64), float(dt))


def _prepare(V, F):
    return np.ascontiguousarray(V, np.float64), np.ascontiguousarray(F, np.int64)
