"""The README's picture of the effect: coarse and refined fracture surfaces on slices of zeta.

Panels: the example wall's crack and the collapsing wall's fracture network
(their mid-planes), a curved synthetic weak sheet with a flat cut 8 voxels
off and a tilted one 4 voxels off, the marble bunny's network (its
mid-plane) and the branch's oblique cut (the plane through its axis). Each shows
zeta on a slice (dark: weak), where the coarse surface crosses it (white)
and where the refined one does (red).

    python benchmarks/figure_effect.py [--out docs/effect.png]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fields.grid import Grid  # noqa: E402
from fields.pyramid import StrengthPyramid  # noqa: E402
from fracture.coarse.scenes.weak_sheets import weak_sheet_case  # noqa: E402
from fracture.io import layout  # noqa: E402
from fracture.pipeline import runner  # noqa: E402
from fracture.pipeline.config import load_config  # noqa: E402
from fracture.mesh.exterior import Exterior  # noqa: E402
from fracture.refine.engine import Refiner, RefineParams  # noqa: E402
from fracture.mesh.fracture_surface import FractureSurface  # noqa: E402


def plane_crossings(V: np.ndarray, F: np.ndarray, axis: int, at: float) -> np.ndarray:
    """Segments ``(k, 2, 3)`` where the triangles cross the plane ``x[axis] = at``."""
    s = V[:, axis] - at
    S = s[F]
    crossing = (S.min(axis=1) < 0) & (S.max(axis=1) > 0)
    segments = []
    for f in np.flatnonzero(crossing):  # a few hundred triangles of one slice: a loop is clear enough
        points = []
        for k in range(3):
            a, b = F[f, k], F[f, (k + 1) % 3]
            if (s[a] > 0) != (s[b] > 0):
                points.append(V[a] + s[a] / (s[a] - s[b]) * (V[b] - V[a]))
        if len(points) == 2:
            segments.append(points)
    return np.array(segments).reshape(-1, 2, 3)


def panel(ax, grid: Grid, zeta: np.ndarray, axis: int, surfaces, title: str, solid: Exterior | None = None) -> None:
    """zeta on the grid's middle slice across ``axis`` (outside ``solid``, if given, white) and where the
    coarse (white) and refined (red) surfaces cross it."""
    k = grid.shape[axis] // 2
    at = grid.lo[axis] + k * grid.spacing[axis]
    u, v = [a for a in range(3) if a != axis]
    image = np.take(zeta, k, axis=axis).astype(np.float64)
    if solid is not None:
        nodes = np.take(grid.points().reshape(*grid.shape, 3), k, axis=axis)
        image = np.ma.masked_array(image, ~solid.inside(nodes.reshape(-1, 3)).reshape(image.shape))
    ax.imshow(image.T, origin="lower", cmap="viridis", interpolation="bilinear",
              extent=[grid.lo[u], grid.hi[u], grid.lo[v], grid.hi[v]])
    for (V, F), colour, width in zip(surfaces, ("white", "red"), (1.6, 1.4)):
        for seg in plane_crossings(V, F, axis, at):
            ax.plot(seg[:, u], seg[:, v], color=colour, lw=width, solid_capstyle="round")
    ax.set_title(title, fontsize=10)
    ax.set_xticks([])
    ax.set_yticks([])


def sheet_panel(ax, kind: str, offset: float, angle: float = 0.0, **params) -> None:
    case = weak_sheet_case(kind, offset, angle=angle)
    pyramid = StrengthPyramid(case.grid, case.zeta, levels=5, sigma=1.0)
    mesh = FractureSurface.from_coarse(case.cut_V, case.cut_F, np.tile([0, 1], (len(case.cut_F), 1)))
    Refiner(mesh, pyramid, case.BV, case.BF, RefineParams(max_triangles=20000, **params),
            np.random.default_rng(0)).run()
    what = f"sheet turned {angle:g} deg (search)" if angle else f"{kind} weak sheet"
    panel(ax, case.grid, case.zeta, 2, [(case.cut_V, case.cut_F), (mesh.V, mesh.F)],
          f"{what}, cut {offset:g} voxels off")


def scene_panel(ax, name: str, title: str, axis: int = 2) -> None:
    """A config's coarse and refined surfaces on its middle slice of zeta across ``axis``, masked to the object."""
    cfg = load_config(ROOT / "configs" / f"{name}.yaml", ["refine.snapshots=false"])
    with tempfile.TemporaryDirectory() as tmp:
        out = runner.run(cfg, Path(tmp) / "run", until="refine", progress=False)
        grid = layout.read_grid(out)
        zeta = layout.read_field(out, "zeta")
        coarse = layout.read_surface(out, layout.COARSE_SURFACE)
        refined = layout.read_surface(out, layout.REFINED_SURFACE)
        solid = Exterior(*layout.read_surface(out, layout.EXTERIOR))
    panel(ax, grid, zeta, axis, [coarse, refined], title, solid)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "effect.png")
    args = ap.parse_args(argv)
    fig = plt.figure(figsize=(14, 6.6), facecolor="white")
    grid = fig.add_gridspec(2, 4, width_ratios=[1, 1, 1.6, 1.4])
    scene_panel(fig.add_subplot(grid[0, :2]), "example", "example wall (one crack), mid-plane")
    scene_panel(fig.add_subplot(grid[0, 2:]), "wall", "collapsing wall (12 pieces), mid-plane")
    sheet_panel(fig.add_subplot(grid[1, 0]), "curved", 8.0)
    sheet_panel(fig.add_subplot(grid[1, 1]), "turned", 4.0, angle=45.0, search="graphcut", band=24.0, core=0.5)
    scene_panel(fig.add_subplot(grid[1, 2]), "bunny", "marble bunny (7 pieces): soft veins dark")
    scene_panel(fig.add_subplot(grid[1, 3]), "branch", "branch, along its axis: fibre bundles (weak: dark)", axis=0)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=90)
    print(args.out)


if __name__ == "__main__":
    from fracture.process import prepare_process

    prepare_process()
    main()
