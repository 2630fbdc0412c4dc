"""Time the strength fields: sampling, stress, pyramid build and psi / grad psi queries.

Prints a table. Usage: python benchmarks/bench_fields.py [--points N] [--repeat R]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from fields.build import build_fields
from fields.grid import Grid
from fields.pyramid import StrengthPyramid
from fields.strength import KINDS, strength_field
from fields.stress import distance_to_surface
from fracture.mesh.primitives import box, sheet

# The paper's grids (Section 6) with the strength kind of each scene.
CASES = [
    ("bunny 50^3", (50, 50, 50), "marble"),
    ("branch 32x32x64", (32, 32, 64), "elongated"),
    ("wall 150x50x10", (150, 50, 10), "bricks"),
    ("clay 32x64x64", (32, 64, 64), "elongated"),
    ("jello 64x64x32", (64, 64, 32), "inclusions"),
]


def best(fn, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--points", type=int, default=1_000_000, help="query points for psi / grad psi")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--levels", type=int, default=5)
    args = ap.parse_args()

    # Warm up the compiled interpolation kernel (cached on disk after the first run).
    g = Grid.from_bounds([0, 0, 0], [1, 1, 1], (4, 4, 4))
    StrengthPyramid(g, np.zeros(g.shape), levels=1).value_and_gradient(np.zeros((1, 3)))

    rows = []
    for name, shape, kind in CASES:
        lo, hi = np.zeros(3), np.asarray(shape, np.float64) / max(shape)
        BV, _ = box(lo, hi, (4, 4, 4))
        SV, SF = sheet(lambda u, v: np.stack([0.5 * hi[0] + 0.1 * np.sin(5 * u), u, v], 1),
                       (0, hi[1]), (0, hi[2]), 12, 12)
        grid = Grid.from_bounds(lo, hi, shape)
        X = grid.points()
        layer = KINDS[kind][1]()  # the kind's defaults
        t_strength = best(lambda: strength_field(X, (lo, hi), [layer], seed=0), args.repeat)
        t_stress = best(lambda: distance_to_surface(X, SV, SF), args.repeat)
        fs = build_fields(BV, SV, SF, resolution=list(shape), padding=0.0, layers=[layer], seed=0,
                          levels=args.levels)
        t_pyramid = best(lambda: StrengthPyramid(grid, fs.psi, levels=args.levels), args.repeat)
        P = np.random.default_rng(0).uniform(lo, hi, (args.points, 3))
        t_query = best(lambda: fs.pyramid.value_and_gradient(P), args.repeat)
        rows.append((name, grid.size, t_strength, t_stress, t_pyramid, t_query))

    header = ("grid", "nodes", "zeta s", "xi s", f"pyramid({args.levels}) s", f"psi+grad @{args.points:,} s",
              "paper init s")
    print(" | ".join(header))
    print(" | ".join("---" for _ in header))
    for name, nodes, ts, tx, tp, tq in rows:
        print(f"{name} | {nodes:,} | {ts:.3f} | {tx:.3f} | {tp:.3f} | {tq:.3f} | 10-30")


if __name__ == "__main__":
    from fracture.process import prepare_process

    prepare_process()
    main()
