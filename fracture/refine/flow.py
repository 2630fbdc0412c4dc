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

With a grain (:mod:`fields.grain`) a triangle's area ``A_j`` becomes its
anisotropic area ``A_j g(n_j)`` and ``n_j`` in ``dA_j/dx_i`` becomes
``m_j = M n_j / g(n_j)``, the gradient of the anisotropic area in the area
vector: the same sums with two per-triangle terms (:func:`face_terms`).

Section 4.4 moves a sample point ``p`` inside a triangle by the same Eq. 3
with the triangle as its neighbourhood: ``p`` splits it into three triangles
and the sum runs over them. One compiled helper, :func:`_corner_term`, gives a
triangle's contribution to a corner's ``dE/dx``; the vertex flow and the
sample displacement both sum it.
"""

from __future__ import annotations

import numba
import numpy as np

from fracture.mesh import vec
from fracture.mesh.faces import face_geometry
from fracture.tolerances import tol

# compiled code reads tolerances as module constants (fracture/tolerances.py says why each)
_TINY = tol.tiny


@numba.njit(cache=True, inline="always")
def _corner_term(area, pbar, nx, ny, nz, ex, ey, ez, gx, gy, gz):
    """One triangle's part of ``dE/dx_i`` for its corner ``i``: ``area / 3 * grad psi(x_i)`` plus
    ``pbar * 1/2 n x e`` (``n`` its unit normal, ``e`` its edge opposite ``i``, ``pbar`` the mean psi of
    its corners); returned as three components."""
    ne = vec.cross((nx, ny, nz), (ex, ey, ez))
    return (area / 3.0 * gx + 0.5 * pbar * ne[0],
            area / 3.0 * gy + 0.5 * pbar * ne[1],
            area / 3.0 * gz + 0.5 * pbar * ne[2])


@numba.njit(cache=True)
def _energy_gradient(V, F, psi, grad, A, G, N):
    # A: the triangles' areas (the vertices' masses), G their (anisotropic) areas in the energy, N the
    # gradients of those in the area vector (unit normals without a grain)
    n = V.shape[0]
    dE = np.zeros((n, 3))
    area = np.zeros(n)
    for f in range(F.shape[0]):
        pb = (psi[F[f, 0]] + psi[F[f, 1]] + psi[F[f, 2]]) / 3.0
        for k in range(3):
            i, j, l = F[f, k], F[f, (k + 1) % 3], F[f, (k + 2) % 3]
            x, y, z = _corner_term(G[f], pb, N[f, 0], N[f, 1], N[f, 2], V[l, 0] - V[j, 0], V[l, 1] - V[j, 1],
                                   V[l, 2] - V[j, 2], grad[i, 0], grad[i, 1], grad[i, 2])
            dE[i, 0] += x
            dE[i, 1] += y
            dE[i, 2] += z
            area[i] += A[f] / 3.0
    return dE, area


@numba.njit(cache=True)
def _energy(F, psi, A):
    total = 0.0
    for f in range(F.shape[0]):
        total += A[f] * (psi[F[f, 0]] + psi[F[f, 1]] + psi[F[f, 2]]) / 3.0
    return total


@numba.njit(cache=True)
def _sample_displacement(P, T, psi_p, grad_p, psi_T, dt, G, M):
    # G, M: per sample, its triangle's grain factor g(n) and the direction m (module notes); M zero: none
    k = P.shape[0]
    out = np.zeros((k, 3))
    for s in range(k):
        o = vec.point(T[s], 0)
        n = vec.cross(vec.sub(vec.point(T[s], 1), o), vec.sub(vec.point(T[s], 2), o))
        t = vec.norm(n)
        if t == 0.0:
            continue
        nx, ny, nz = n[0] / t, n[1] / t, n[2] / t
        if M[s, 0] != 0.0 or M[s, 1] != 0.0 or M[s, 2] != 0.0:
            nx, ny, nz = M[s, 0], M[s, 1], M[s, 2]
        gx = gy = gz = 0.0
        area = 0.0
        for c in range(3):  # sub-triangle with p in place of corner c; its edge opposite p is T's edge opposite c
            b, e = (c + 1) % 3, (c + 2) % 3
            p = vec.point(P, s)
            bb, cc = vec.sub(vec.point(T[s], b), p), vec.sub(vec.point(T[s], e), p)
            sub = 0.5 * vec.norm(vec.cross(bb, cc))
            pb = (psi_p[s] + psi_T[s, b] + psi_T[s, e]) / 3.0
            edge = vec.sub(cc, bb)
            x, y, z = _corner_term(sub * G[s], pb, nx, ny, nz, edge[0], edge[1], edge[2],
                                   grad_p[s, 0], grad_p[s, 1], grad_p[s, 2])
            gx += x
            gy += y
            gz += z
            area += sub / 3.0
        if area > 0.0:
            out[s, 0], out[s, 1], out[s, 2] = -dt * gx / area, -dt * gy / area, -dt * gz / area
    return out


def face_terms(V: np.ndarray, F: np.ndarray, grain=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per triangle: its area, its area in the energy (``A g(n)`` with a grain, else ``A``) and that
    area's gradient direction in the area vector (``m``, else the unit normal)."""
    A, N = face_geometry(*_prepare(V, F))
    if grain is None or not len(F):
        return A, A, N
    g, m = grain.metric(N, V[F].mean(axis=1))
    return A, A * g, np.ascontiguousarray(m)


def energy_gradient(V: np.ndarray, F: np.ndarray, psi: np.ndarray, grad: np.ndarray, grain=None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """dE/dx_i and the barycentric vertex areas.

    Parameters
    ----------
    V, F : surface (any number of triangles per edge).
    psi : (n,) float
        psi at the vertices.
    grad : (n, 3) float
        grad psi at the vertices.
    grain : :class:`fields.grain.Grain`, optional

    Returns
    -------
    dE : (n, 3) float
    area : (n,) float
        Barycentric area of every vertex (0 for unused vertices).
    """
    return _energy_gradient(*_prepare(V, F), _f64(psi), _f64(grad), *face_terms(V, F, grain))


def velocity(V: np.ndarray, F: np.ndarray, psi: np.ndarray, grad: np.ndarray, grain=None) -> np.ndarray:
    """Eq. 3: the velocity ``-dE/dx_i / A_i`` of every vertex, ``(n, 3)``."""
    dE, area = energy_gradient(V, F, psi, grad, grain)
    return -dE / np.maximum(area, _TINY)[:, None]


def energy(V: np.ndarray, F: np.ndarray, psi: np.ndarray, grain=None) -> float:
    """E(S): psi (times the grain's g(n), with one) integrated over the surface (linear in each triangle)."""
    return float(_energy(np.ascontiguousarray(F, np.int64), _f64(psi), face_terms(V, F, grain)[1]))


# The dense-sample quadrature of E(S) (sampled_energy): points per cell of area, at least and at most so many.
_SAMPLES_PER_CELL = 16.0
_SAMPLES_MIN, _SAMPLES_MAX = 20000, 1000000


def sampled_energy(V: np.ndarray, F: np.ndarray, psi_at, h: float, offset: float = 0.0, grain=None) -> float:
    """E(S) with ``psi_at(points) + offset`` (times g(n) with a grain) integrated from points spread over the
    surface with uniform density (16 per cell of area ``h^2``, a fixed seed: the same surface, the same
    estimate).

    :func:`energy` takes psi at the corners, linear in between: the flow's quadrature, which flatters a
    surface whose corners lie in a thin weak layer and whose triangles cross strong material between them,
    and differs between a coarse and a fine mesh of the same surface. This one compares surfaces meshed
    any way: the search's against the coarse one, the search's polish against the flow alone."""
    from fracture.mesh.sampling import area_barycentric

    A, G, _ = face_terms(V, F, grain)
    total = float(A.sum())
    if not total > 0.0:
        return 0.0
    count = int(np.clip(_SAMPLES_PER_CELL * total / (h * h), _SAMPLES_MIN, _SAMPLES_MAX))
    # the points of mesh.sampling.area_samples, from the areas at hand (its own gather and areas of every
    # triangle took 9 of the 15 ms of a call on the bunny's 80,000 triangles)
    f, bary = area_barycentric(A, count, np.random.default_rng(0))
    X = np.einsum("nk,nkc->nc", bary, V[F[f]])
    factor = G[f] / np.maximum(A[f], tol.tiny)
    return total * float(np.mean((psi_at(X) + offset) * factor))


def sample_displacement(P: np.ndarray, T: np.ndarray, psi_p: np.ndarray, grad_p: np.ndarray,
                        psi_T: np.ndarray, dt: float, grain=None) -> np.ndarray:
    """Displacement in one step of points inside triangles, each with its triangle as neighbourhood.

    The point ``p`` splits its triangle ``(a, b, c)`` into ``(p, b, c)``,
    ``(a, p, c)``, ``(a, b, p)``; Eq. 3 at ``p`` over these three (Section 4.4).

    Parameters
    ----------
    P : (k, 3) sample points; T : (k, 3, 3) corners of their triangles.
    psi_p, grad_p : psi and grad psi at the samples.
    psi_T : (k, 3) psi at the corners.
    grain : :class:`fields.grain.Grain`, optional
    """
    k = len(P)
    G, M = np.ones(k), np.zeros((k, 3))
    if grain is not None and k:
        n = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
        length = np.linalg.norm(n, axis=1)
        ok = length > 0.0
        G[ok], M[ok] = grain.metric(n[ok] / length[ok, None], T[ok].mean(axis=1))
    return _sample_displacement(_f64(P), _f64(T), _f64(psi_p), _f64(grad_p), _f64(psi_T), float(dt), G,
                                np.ascontiguousarray(M))


def _f64(a):
    return np.ascontiguousarray(a, np.float64)


def _prepare(V, F):
    return _f64(V), np.ascontiguousarray(F, np.int64)


class PsiFlow:
    """Eq. 3: the gradient flow of the integral of the stage's psibar, shifted positive (``offset``), times
    g(n) with a grain. What the refiner asks of a flow: the integrand per vertex and the field-gradient
    term of the velocity (the area term, the implicit step and the acceptance of a step follow from the
    integrand)."""


    def integrand(self, psibar: np.ndarray, offset: float) -> np.ndarray:
        return psibar + offset

    def gradient(self, grad: np.ndarray) -> np.ndarray:
        return grad

    def triangle_weights(self, V: np.ndarray, F: np.ndarray, w: np.ndarray, grain=None) -> np.ndarray:
        """The implicit area term's weight per triangle (:func:`~fracture.refine.step.cotangent_weights`):
        the mean integrand of its corners, times g(n) with a grain."""
        return _triangle_weights(V, F, w, grain)


def _triangle_weights(V, F, w, grain):
    wf = w[F].mean(axis=1)
    if grain is not None:  # each triangle's weight times its g(n)
        A, G, _ = face_terms(V, F, grain)
        wf = wf * G / np.maximum(A, tol.tiny)
    return wf


class AreaFlow:
    """Mean curvature flow: the integrand is 1 and there is no field term, so the surface only shortens (a
    second flow for the refiner, and a check that it composes any flow through :class:`PsiFlow`'s
    interface)."""


    def integrand(self, psibar: np.ndarray, offset: float) -> np.ndarray:
        return np.ones_like(psibar)

    def gradient(self, grad: np.ndarray) -> np.ndarray:
        return np.zeros_like(grad)

    def triangle_weights(self, V: np.ndarray, F: np.ndarray, w: np.ndarray, grain=None) -> np.ndarray:
        return _triangle_weights(V, F, w, grain)
