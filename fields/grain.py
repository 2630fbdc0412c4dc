"""Grain: anisotropic strength, the limitation the paper names (wood splits along its fibres).

A fibre direction ``d(x)`` and a ratio ``r >= 1`` make the cost of a
surface element depend on its unit normal ``n``:

    g(n) = sqrt(1 + (r^2 - 1) (n . d)^2),

1 where the surface contains the fibres (it splits along them), ``r`` where
it cuts across them. The functional becomes ``E(S) = integral of psi g(n)``.
Per triangle with area vector ``a = A n`` the anisotropic area is
``G(a) = sqrt(a . M a)`` with ``M = I + (r^2 - 1) d d^T``, homogeneous of
degree one, so its gradient in ``a`` is ``m = M n / g(n)``: the flow's
derivative of a triangle's area with respect to a corner, ``1/2 n x e``,
becomes ``1/2 m x e`` (:mod:`fracture.refine.flow`), and the search charges
an edge of the grid graph the weights that measure ``g`` (``fracture.refine.cut_weights``, which
reads the directions and the ratio from here).

Fibres run ``along`` an axis (a branch's wood) or ``around`` it (circles about
the line through ``center`` along the axis).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fields.tolerances import tol


@dataclass(frozen=True)
class Grain:
    """Fibre directions and the ratio of the cost across them to the cost along them (module notes).

    Attributes
    ----------
    ratio : float
        ``r >= 1``.
    fibres : str
        ``along`` the axis or ``around`` it.
    axis : (3,) float
        Unit vector.
    center : (3,) float
        A material point on the axis line (for ``around``).
    """

    ratio: float
    fibres: str
    axis: np.ndarray
    center: np.ndarray

    def __post_init__(self):
        if not np.isfinite(self.ratio) or self.ratio < 1.0:
            raise ValueError(f"a grain's ratio must be a number >= 1, got {self.ratio!r}")
        if self.fibres not in ("along", "around"):
            raise ValueError(f"a grain's fibres run 'along' or 'around' its axis, got {self.fibres!r}")
        a = np.asarray(self.axis, np.float64)
        length = float(np.linalg.norm(a)) if np.all(np.isfinite(a)) else 0.0
        if length <= tol.zero:
            raise ValueError(f"a grain's axis must be a direction of nonzero length, got {self.axis!r}")
        object.__setattr__(self, "axis", a / length)
        object.__setattr__(self, "center", np.asarray(self.center, np.float64))

    def directions(self, P: np.ndarray) -> np.ndarray:
        """Unit fibre directions at points ``(k, 3)``. Around the axis, on the axis itself (no circle), the
        axis."""
        P = np.asarray(P, np.float64).reshape(-1, 3)
        if self.fibres == "along":
            return np.broadcast_to(self.axis, P.shape).copy()
        r = P - self.center
        r -= (r @ self.axis)[:, None] * self.axis
        t = np.cross(self.axis, r)
        length = np.linalg.norm(t, axis=1)
        out = np.broadcast_to(self.axis, P.shape).copy()
        ok = length > tol.zero
        out[ok] = t[ok] / length[ok, None]
        return out

    def metric(self, normals: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``g(n)`` and ``m = M n / g(n)`` of unit normals at points (module notes)."""
        d = self.directions(P)
        c = np.einsum("ij,ij->i", normals, d)
        k = self.ratio * self.ratio - 1.0
        g = np.sqrt(1.0 + k * c * c)
        m = (normals + (k * c)[:, None] * d) / g[:, None]
        return g, m
