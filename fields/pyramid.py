"""The Gaussian strength pyramid of Section 4.3."""

from __future__ import annotations

import numba
import numpy as np
from scipy import ndimage

from fields.grid import Grid
from fields.interpolate import trilinear

# Gaussian kernels are cut at this many standard deviations (scipy's default).
_TRUNCATE = 4.0


def level_sigmas(grid: Grid, levels: int, sigma: float) -> np.ndarray:
    """Per-axis Gaussian widths, in voxels, of each pyramid level.

    Level 0 is the field itself; level ``k >= 1`` is smoothed with a Gaussian
    of world-space standard deviation ``sigma * 2**(k-1) * min(spacing)``, so
    anisotropic grids are smoothed isotropically in material space.

    Returns
    -------
    (levels, 3) float
    """
    h = grid.spacing
    world = np.array([0.0] + [sigma * 2.0 ** (k - 1) * h.min() for k in range(1, levels)])
    return world[:, None] / h[None, :]


def gaussian_level(values: np.ndarray, sigma_voxels: np.ndarray) -> np.ndarray:
    """Gaussian smoothing with odd (point) reflection at the grid boundary.

    Odd reflection ``f(-x) = 2 f(0) - f(x)`` extends a linear field linearly,
    so smoothing leaves linear fields unchanged up to the boundary. Plain
    ``nearest``/``reflect`` padding would flatten the field near the box
    faces and plant false minima of psi on the object's exterior.
    """
    if not np.any(sigma_voxels > 0):
        return np.array(values, np.float64, copy=True)
    pad = [int(np.ceil(_TRUNCATE * s)) + 1 for s in sigma_voxels]
    padded = np.pad(values.astype(np.float64), [(p, p) for p in pad], mode="reflect", reflect_type="odd")
    smooth = ndimage.gaussian_filter(padded, sigma=sigma_voxels, mode="nearest", truncate=_TRUNCATE)
    return smooth[tuple(slice(p, p + n) for p, n in zip(pad, values.shape))]


class StrengthPyramid:
    """Multi-level psi with its level-averaged finite-difference gradient.

    Parameters
    ----------
    grid : Grid
    psi : (nx, ny, nz) float
        The modified strength field on ``grid``.
    levels : int
        Number of levels (the paper uses 4 to 6); level 0 is ``psi`` itself.
    sigma : float
        Width of level 1 in units of the smallest grid spacing; it doubles
        from level to level.

    Notes
    -----
    Section 4.3: the gradient of a vertex is the average of its gradients at
    all pyramid levels, each obtained by finite differences on the level and
    trilinear interpolation. Finite differences, trilinear interpolation and
    the average are all linear, so the average of the interpolated level
    gradients equals the interpolation of the averaged gradient grid. The
    constructor therefore stores one ``(nx, ny, nz, 4)`` table
    ``[psi, mean d/dx, mean d/dy, mean d/dz]`` and every query is a single
    interpolation, independent of the number of levels: exact, not an
    approximation.
    """

    def __init__(self, grid: Grid, psi: np.ndarray, levels: int = 5, sigma: float = 1.0):
        psi = np.asarray(psi, np.float64)
        if psi.shape != tuple(grid.shape):
            raise ValueError(f"psi has shape {psi.shape}, expected the grid shape {tuple(grid.shape)}")
        if levels < 1:
            raise ValueError(f"levels must be >= 1, got {levels}")
        if not np.all(np.isfinite(psi)):
            raise ValueError("psi has NaN or infinite values")
        self.grid = grid
        self.sigmas = level_sigmas(grid, levels, sigma)
        self.levels = np.stack([gaussian_level(psi, s) for s in self.sigmas])
        mean_gradient = np.zeros(psi.shape + (3,))
        for k in range(levels):
            mean_gradient += self.level_gradient_grid(k)
        mean_gradient /= levels
        self._table = np.ascontiguousarray(np.concatenate([psi[..., None], mean_gradient], axis=3))
        self._coarse = ((-1, -1), None)  # the last table of a window of levels asked for (see coarse_table)

    def __getstate__(self) -> dict:
        """Pickled without the last window's table (:meth:`coarse_table` makes it again when asked)."""
        return {**self.__dict__, "_coarse": ((-1, -1), None)}

    @classmethod
    def combine(cls, terms: list[tuple[float, "StrengthPyramid"]]) -> "StrengthPyramid":
        """The pyramid of ``sum w_i psi_i`` from the pyramids of the ``psi_i`` (one grid, levels and widths).

        Smoothing, finite differences and the level average are linear, so
        this is the pyramid of the sum, built with a few array sums instead of
        the Gaussian filters: psi = a zeta - b xi gets its pyramid from those of
        zeta and xi, which a change of the weights a and b leaves as they are.
        """
        (w0, first), rest = terms[0], terms[1:]
        for _, p in rest:
            same_grid = (p.grid.shape == first.grid.shape and np.array_equal(p.grid.origin, first.grid.origin)
                         and np.array_equal(p.grid.spacing, first.grid.spacing))
            if not same_grid or p.levels.shape != first.levels.shape or not np.array_equal(p.sigmas, first.sigmas):
                raise ValueError("pyramids of different grids or levels cannot be combined")
        out = cls.__new__(cls)
        out.grid, out.sigmas = first.grid, first.sigmas
        out.levels, out._table = np.empty(first.levels.shape), np.empty(first._table.shape)  # C order: flat views
        for mine, part in ((out.levels, "levels"), (out._table, "_table")):
            # one pass over the terms' arrays per term (NumPy's products and sum took three times as long)
            _scaled(mine.reshape(-1), w0, np.ascontiguousarray(getattr(first, part)).reshape(-1))
            for w, p in rest:
                _add_scaled(mine.reshape(-1), w, np.ascontiguousarray(getattr(p, part)).reshape(-1))
        out._coarse = ((-1, -1), None)
        return out

    @property
    def n_levels(self) -> int:
        return self.levels.shape[0]

    def window(self, first: int, count: int) -> range:
        """Levels ``first .. first + count - 1``, cut at the coarsest level."""
        if not 0 <= first < self.n_levels:
            raise ValueError(f"first level must be in [0, {self.n_levels - 1}], got {first}")
        if count < 1:
            raise ValueError(f"a window holds at least one level, got {count}")
        return range(first, min(first + count, self.n_levels))

    def coarse_table(self, first: int, count: int | None = None) -> np.ndarray:
        """``(nx, ny, nz, 5)``: ``[psi, psibar, d/dx, d/dy, d/dz psibar]`` with ``psibar`` the mean of
        levels ``first .. first + count - 1`` (all from ``first`` on without ``count``) and its gradient
        the mean of their finite-difference gradients.

        ``first = 0`` with every level is the paper's field; a window of
        coarser levels is a smoother field whose valleys reach further, and a
        window of the finest levels keeps thin weak layers that the coarse
        levels smear, for the coarse-to-fine schedule of the refinement. The
        mean of the levels' gradients is the gradient of their mean (both
        linear), so ``psibar`` is the field whose integral the flow on these
        levels minimises. The last table asked for is kept.
        """
        used = self.window(first, self.n_levels if count is None else count)
        if self._coarse[0] != (used.start, used.stop):
            mean = self.levels[used.start:used.stop].mean(axis=0)
            # the mean of the levels' finite-difference gradients, taken as the gradient of the mean
            # (both linear): one difference pass per window instead of one per level, written with
            # psi and the mean straight into the table
            table = np.empty(mean.shape + (5,))
            _window_table(self.levels[0], mean, *(float(h) for h in self.grid.spacing), table)
            self._coarse = ((used.start, used.stop), table)
        return self._coarse[1]

    def window_range(self, first: int, count: int | None = None) -> tuple[float, float]:
        """Smallest value and range of psibar of :meth:`coarse_table` over the grid."""
        psibar = self.coarse_table(first, count)[..., 1]
        return float(psibar.min()), float(np.ptp(psibar))

    def gradient_scale(self, first: int, count: int | None = None) -> float:
        """Root mean square of the gradient of :meth:`coarse_table` over the grid (a scale of the field's
        variation, for step sizes)."""
        g = self.coarse_table(first, count)[..., 2:]
        return float(np.sqrt(np.mean(np.einsum("...c,...c->...", g, g))))

    def coarse_field(self, first: int, P: np.ndarray, count: int | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """psi, psibar and grad psibar of :meth:`coarse_table` at points, in one interpolation."""
        out = trilinear(self.grid, self.coarse_table(first, count), P)
        return out[:, 0], out[:, 1], out[:, 2:]

    def level_gradient_grid(self, k: int) -> np.ndarray:
        """Finite-difference gradient of level ``k`` on the grid, ``(nx, ny, nz, 3)``.

        Central differences inside, one-sided at the boundary (exact for
        linear fields everywhere).
        """
        g = np.gradient(self.levels[k], *self.grid.spacing, edge_order=1)
        return np.stack(g, axis=3)

    def value(self, P: np.ndarray) -> np.ndarray:
        """psi (level 0) at points, ``(n,)``."""
        return trilinear(self.grid, self._table[..., :1], P)[:, 0]

    def gradient(self, P: np.ndarray) -> np.ndarray:
        """Level-averaged grad psi at points, ``(n, 3)``."""
        return self.value_and_gradient(P)[1]

    def value_and_gradient(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """psi and the level-averaged grad psi at points in one pass."""
        out = trilinear(self.grid, self._table, P)
        return out[:, 0], out[:, 1:]

    def level_value(self, k: int, P: np.ndarray) -> np.ndarray:
        """Level ``k`` at points, ``(n,)``."""
        return trilinear(self.grid, self.levels[k], P)

    def level_gradient(self, k: int, P: np.ndarray) -> np.ndarray:
        """Finite-difference gradient of level ``k`` at points, ``(n, 3)``."""
        return trilinear(self.grid, self.level_gradient_grid(k), P)


@numba.njit(cache=True)
def _scaled(out, w, a):
    """``out = w a`` (flat arrays)."""
    for i in range(out.shape[0]):
        out[i] = w * a[i]


@numba.njit(cache=True)
def _add_scaled(out, w, a):
    """``out += w a`` (flat arrays): the products and the sums NumPy would take, in one pass."""
    for i in range(out.shape[0]):
        out[i] += w * a[i]


@numba.njit(cache=True)
def _window_table(psi, mean, hx, hy, hz, out):
    """``out[..., :] = [psi, mean, grad mean]`` with NumPy's ``gradient`` (``edge_order=1``: central
    differences inside, one-sided at the faces; the same operations in the same order, so the same
    bits), in one pass instead of three gradient arrays, a stack and a concatenation."""
    nx, ny, nz = mean.shape
    for i in range(nx):
        i0, i1 = max(i - 1, 0), min(i + 1, nx - 1)  # neighbours, the point itself at a face
        for j in range(ny):
            j0, j1 = max(j - 1, 0), min(j + 1, ny - 1)
            for k in range(nz):
                k0, k1 = max(k - 1, 0), min(k + 1, nz - 1)
                out[i, j, k, 0] = psi[i, j, k]
                out[i, j, k, 1] = mean[i, j, k]
                out[i, j, k, 2] = (mean[i1, j, k] - mean[i0, j, k]) / ((i1 - i0) * hx)
                out[i, j, k, 3] = (mean[i, j1, k] - mean[i, j0, k]) / ((j1 - j0) * hy)
                out[i, j, k, 4] = (mean[i, j, k1] - mean[i, j, k0]) / ((k1 - k0) * hz)
