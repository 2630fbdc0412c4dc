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

Fibres run ``along`` an axis (a branch's wood), ``around`` it (circles about
the line through ``center`` along the axis), or as a ``volume`` of directions
gives them (:class:`DirectionField`: a direction per grid node; a fibre has no
sign, so the field is interpolated as the tensor ``d d^T`` and read as its
principal direction, where ``d`` and ``-d`` on two neighbouring nodes would
cancel as vectors).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fields.errors import InputError
from fields.npy import is_npy
from fields.grid import Grid
from fields.interpolate import trilinear
from fields.tolerances import tol

# The six entries of a symmetric 3 x 3 tensor (upper triangle), as the direction field stores them.
_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


class DirectionField:
    """Fibre directions given per node of a grid (module notes): ``directions`` ``(nx, ny, nz, 3)``,
    each finite and of nonzero length (its sign and length do not matter)."""

    def __init__(self, grid: Grid, directions: np.ndarray):
        d = np.asarray(directions, np.float64)
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        self.grid = grid
        self.tensor = np.stack([d[..., a] * d[..., b] for a, b in _UPPER], axis=-1)

    def __call__(self, P: np.ndarray) -> np.ndarray:
        """Unit fibre directions at points ``(k, 3)``: the principal direction of the interpolated tensor."""
        t = trilinear(self.grid, self.tensor, np.asarray(P, np.float64).reshape(-1, 3))
        T = np.empty((len(t), 3, 3))
        for k, (a, b) in enumerate(_UPPER):
            T[:, a, b] = T[:, b, a] = t[:, k]
        return np.linalg.eigh(T)[1][:, :, -1]


def load_directions(path: str | Path, key: str) -> np.ndarray:
    """A ``.npy`` array of fibre directions ``(nx, ny, nz, 3)`` (at least two nodes per axis), each finite and
    of nonzero length; refused naming ``key``, the file and the first bad node."""
    path = Path(path)
    where = f"{key} ({path})"
    if not path.is_file():
        raise InputError(f"{where}: file not found; expected a .npy file of fibre directions")
    if not is_npy(path):
        raise InputError(f"{where}: not a .npy file (NumPy's np.save writes one); expected an array (nx, ny, nz, 3)")
    try:
        d = np.load(path, allow_pickle=False)
    except Exception as exc:  # numpy raises several kinds for a damaged file
        raise InputError(f"{where}: cannot read as a .npy array ({exc})") from None
    if d.ndim != 4 or d.shape[3] != 3 or min(d.shape[:3]) < 2:
        raise InputError(f"{where}: fibre directions of shape {d.shape}; expected (nx, ny, nz, 3) with at least two "
                         "nodes per axis")
    if not np.issubdtype(d.dtype, np.number) or np.issubdtype(d.dtype, np.complexfloating):
        raise InputError(f"{where}: fibre directions of dtype {d.dtype}; expected real numbers")
    d = d.astype(np.float64)
    finite = np.all(np.isfinite(d), axis=-1)
    bad = ~finite | (np.linalg.norm(np.where(finite[..., None], d, 0.0), axis=-1) <= tol.zero)
    if bad.any():
        node = tuple(int(i) for i in np.argwhere(bad)[0])
        what = "NaN or infinite" if not finite[node] else "of zero length"
        raise InputError(f"{where}: the direction at node {node} is {what} ({int(bad.sum())} such nodes); expected "
                         "a direction of nonzero length at every node")
    return d


@dataclass(frozen=True)
class Grain:
    """Fibre directions and the ratio of the cost across them to the cost along them (module notes).

    Attributes
    ----------
    ratio : float
        ``r >= 1``.
    fibres : str
        ``along`` the axis, ``around`` it, or ``volume`` (``field`` gives them).
    axis : (3,) float
        Unit vector.
    center : (3,) float
        A material point on the axis line (for ``around``).
    """

    ratio: float
    fibres: str
    axis: np.ndarray
    center: np.ndarray
    field: DirectionField | None = None

    def __post_init__(self):
        if not np.isfinite(self.ratio) or self.ratio < 1.0:
            raise ValueError(f"a grain's ratio must be a number >= 1, got {self.ratio!r}")
        if self.fibres not in ("along", "around", "volume"):
            raise ValueError(f"a grain's fibres run 'along' or 'around' its axis or as a volume gives them, got "
                             f"{self.fibres!r}")
        if (self.fibres == "volume") != (self.field is not None):
            raise ValueError("a grain's fibres come from a direction field exactly when they are a 'volume'")
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
        if self.field is not None:
            return self.field(P)
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
