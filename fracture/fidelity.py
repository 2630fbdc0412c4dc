"""Measures of the refinement's effect: how much of a surface lies in weak material, and how far it went.

The paper's refinement exists to move the coarse fracture surface into weak
material (marble veins, wood grain, brick-mortar boundaries, Figs. 1, 4, 9,
10). These figures say whether it did, from area-uniform samples of a surface:

* ``weak_share[q]``: the share of the surface's area where zeta is below its
  ``q``-th percentile *inside the object* (so 20 % of the object's volume is
  "the weakest 20 %", and a surface placed at random scores about ``q``);
* mean zeta and mean psi over the surface (area-weighted);
* distances from the surface to another (the coarse one) in grid cells: mean
  and 90th percentile.

Samples are drawn with a fixed seed, so a surface always gets the same figures.
"""

from __future__ import annotations

import numpy as np

from fields.grid import Grid
from fields.interpolate import trilinear
from fields.stress import distance_to_surface
from fracture.exterior import Exterior

PERCENTILES = (10, 20, 30)


def area_samples(V: np.ndarray, F: np.ndarray, count: int = 20000, seed: int = 0) -> np.ndarray:
    """``count`` points spread over the surface with uniform density per area, ``(count, 3)``."""
    T = V[F]
    area = 0.5 * np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1)
    rng = np.random.default_rng(seed)
    f = rng.choice(len(F), size=count, p=area / area.sum())
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)
    bary = np.column_stack([1.0 - s, s * (1.0 - r2), s * r2])
    return np.einsum("nk,nkc->nc", bary, T[f])


def inside_thresholds(grid: Grid, zeta: np.ndarray, BV: np.ndarray, BF: np.ndarray,
                      percentiles=PERCENTILES) -> dict[int, float]:
    """zeta's percentiles over the grid nodes inside the exterior ``(BV, BF)`` (winding number > 1/2, libigl)."""
    inside = Exterior(BV, BF).inside(grid.points())
    values = zeta.reshape(-1)[inside] if inside.any() else zeta.reshape(-1)
    return {q: float(np.percentile(values, q)) for q in percentiles}


def surface_figures(V, F, grid: Grid, zeta: np.ndarray, thresholds: dict[int, float],
                    psi: np.ndarray | None = None, reference: tuple | None = None, count: int = 20000) -> dict:
    """The figures of one surface (module notes).

    Parameters
    ----------
    V, F : the surface.
    grid, zeta : zeta sampled on ``grid``; ``psi`` likewise, optional.
    thresholds : zeta's percentiles inside the object (:func:`inside_thresholds`).
    reference : optional ``(V, F)`` of another surface (the coarse one): distances are measured to it.
    """
    P = area_samples(np.asarray(V, np.float64), np.asarray(F, np.int64), count)
    z = trilinear(grid, zeta, P)
    out = {f"weak_share_{q}": float(np.mean(z < t)) for q, t in thresholds.items()}
    out["mean_zeta"] = float(z.mean())
    if psi is not None:
        out["mean_psi"] = float(trilinear(grid, psi, P).mean())
    if reference is not None:
        d = distance_cells(P, *reference, grid)
        out["distance_mean"] = float(d.mean())
        out["distance_p90"] = float(np.percentile(d, 90))
    return out


def distance_cells(P: np.ndarray, V: np.ndarray, F: np.ndarray, grid: Grid) -> np.ndarray:
    """Distances from points to a triangle surface, in units of the smallest grid spacing."""
    return distance_to_surface(P, V, F) / float(np.min(grid.spacing))
