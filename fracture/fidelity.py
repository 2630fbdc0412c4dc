"""Measures of the refinement's effect: how much of a surface lies in weak material, and how far it went.

The paper's refinement exists to move the coarse fracture surface into weak
material (marble veins, wood grain, brick-mortar boundaries, Figs. 1, 4, 9,
10). These figures say whether it did, from area-uniform samples of a surface:

* ``weak_share[q]``: the share of the surface's area where zeta is below its
  ``q``-th percentile *inside the object* (so 20 % of the object's volume is
  "the weakest 20 %", and a surface placed at random scores about ``q``);
* ``strong_share_10``: the share where zeta is above its 90th percentile: in
  the hardest material (the Jell-O's fruit cubes, the bricks' cores);
* mean zeta and mean psi over the surface (area-weighted);
* distances from the surface to another (the coarse one) in grid cells: mean
  and 90th percentile.

Samples are drawn with a fixed seed, so a surface always gets the same figures.
:func:`run_figures` gives them for the coarse and refined surfaces of a run directory.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fields.grid import Grid
from fields.interpolate import trilinear
from fields.stress import distance_to_surface
from fracture.io import layout
from fracture.mesh.exterior import Exterior
from fracture.mesh.sampling import area_samples as surface_samples

PERCENTILES = (10, 20, 30, 90)


def area_samples(V: np.ndarray, F: np.ndarray, count: int = 20000, seed: int = 0) -> np.ndarray:
    """``count`` points spread over the surface with uniform density per area, ``(count, 3)``."""
    return surface_samples(V, F, count, np.random.default_rng(seed))[0]


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
    out = {f"weak_share_{q}": float(np.mean(z < t)) for q, t in thresholds.items() if q < 50}
    if 90 in thresholds:
        out["strong_share_10"] = float(np.mean(z > thresholds[90]))
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


def run_figures(out: str | Path) -> dict:
    """The figures of a run directory: its coarse and refined surfaces against its fields.

    Returns ``coarse`` and ``refined`` (:func:`surface_figures`; the refined
    surface's distances are to the coarse one), the refined ``triangles``,
    ``iterations``, the refine stage's ``seconds``, why it stopped (``stop``),
    the ``functional`` of its last stage, the ``area_ratio`` refined / coarse,
    whether the search's surface was taken (``searched``) and its ``search_seconds``.
    """
    out = Path(out)
    manifest = layout.read_manifest(out)
    grid = layout.read_grid(out)
    zeta = layout.read_field(out, "zeta").astype(np.float64)
    psi = layout.read_field(out, "psi").astype(np.float64)
    BV, BF = layout.read_surface(out, layout.EXTERIOR)
    CV, CF = layout.read_surface(out, layout.COARSE_SURFACE)
    RV, RF = layout.read_surface(out, layout.REFINED_SURFACE)
    thresholds = inside_thresholds(grid, zeta, BV, BF)
    coarse = surface_figures(CV, CF, grid, zeta, thresholds, psi)
    refined = surface_figures(RV, RF, grid, zeta, thresholds, psi, reference=(CV, CF))
    stats = manifest["stats"]["refine"]
    search = stats.get("search") or {}
    return dict(coarse=coarse, refined=refined, triangles=len(RF), iterations=len(stats["functional"]) - 1,
                seconds=manifest["stages"]["refine"]["seconds"], stop=stats["stopped_because"],
                # what the last stage (level 0 for the flow alone and for the polish) minimises, on dense
                # samples: the flow's own quadrature (psi at the corners) differs between meshes
                functional=float(stats["functional_sampled_coarse_and_refined"][-1]), area_ratio=float(stats["area"][-1] / stats["area"][0]),
                searched=bool(search.get("replaced_coarse_surface", False)),
                search_seconds=float(sum(search.get("seconds", {}).values())))
