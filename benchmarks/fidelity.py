"""Does the refinement find the weak material? Figures per scene and per synthetic weak sheet.

For each config: run it up to the refine stage (into a temporary directory),
then measure the coarse and the refined surface with
:mod:`fracture.fidelity`: the share of their area in the weakest 10/20/30 % of
zeta inside the object, mean zeta and psi, the distance of the refined
surface to the coarse one (grid cells: mean and 90th percentile), iterations
and seconds. For the synthetic weak sheets (:mod:`fracture.coarse.scenes.weak_sheets`): the mean
distance of the refined surface to the sheet and the share of its area within
one voxel of it; sheets turned 30, 45 and 60 degrees from the cut too. Every
row is measured with the global search (``refine.search: graphcut``) and
without it (``none``), and says the functional the last stage reached (level
0, shifted: what both minimise; on dense samples of the surface, 16 per cell of
area, so that a coarse and a fine mesh of one surface score alike) and the area
refined / coarse.

    python benchmarks/fidelity.py                       # the scenes and the sheets
    python benchmarks/fidelity.py --scenes example wall --set psi.stress_weight=2
    python benchmarks/fidelity.py --sheets-only --search graphcut
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fields.pyramid import StrengthPyramid  # noqa: E402
from fracture.coarse.scenes.weak_sheets import SHEETS, TURNED, weak_sheet_case  # noqa: E402
from fracture.pipeline import runner  # noqa: E402
from fracture.pipeline.config import load_config  # noqa: E402
from fracture.fidelity import area_samples, run_figures  # noqa: E402
from fracture.refine.engine import Refiner, RefineParams  # noqa: E402
from fracture.mesh.fracture_surface import FractureSurface  # noqa: E402
from scenes import checked_configs  # noqa: E402

SCENES = ["example", "wall", "bunny", "branch", "clay", "jello"]
SEARCHES = ["graphcut", "none"]
# Turned sheets: angle (degrees) and the band that reaches the sheet's far ends (cells).
TURNED_SHEETS = [(30, 16), (45, 24), (60, 40)]


def scene_row(name: str, overrides: list[str]) -> dict:
    cfg = load_config(ROOT / "configs" / f"{name}.yaml", overrides)
    with tempfile.TemporaryDirectory() as tmp:
        out = runner.run(cfg, Path(tmp) / "run", until="refine", progress=False)
        return run_figures(out)


def sheet_row(kind: str, offset: float, params: RefineParams, angle: float = 0.0) -> dict:
    case = weak_sheet_case(kind, offset, angle=angle)
    pyramid = StrengthPyramid(case.grid, case.zeta, levels=5, sigma=1.0)
    mesh = FractureSurface.from_coarse(case.cut_V, case.cut_F, np.tile([0, 1], (len(case.cut_F), 1)))
    start = time.perf_counter()
    log = Refiner(mesh, pyramid, case.BV, case.BF, params, np.random.default_rng(0)).run()
    seconds = time.perf_counter() - start
    d = case.distance_to_sheet(area_samples(mesh.V, mesh.F))
    d0 = case.distance_to_sheet(area_samples(case.cut_V, case.cut_F))
    return dict(coarse=float(d0.mean()), mean=float(d.mean()), within=float(np.mean(d < 1.0)),
                triangles=len(mesh.F), iterations=log.iterations, seconds=seconds,
                functional=float(log.sampled[1]), searched=log.search is not None and log.search.surface is not None)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="*", default=SCENES)
    ap.add_argument("--set", action="append", default=[], help="config override for the scenes, key=value")
    ap.add_argument("--search", nargs="*", default=SEARCHES, choices=SEARCHES)
    ap.add_argument("--sheets-only", action="store_true")
    ap.add_argument("--no-sheets", action="store_true")
    args = ap.parse_args(argv)
    if not args.sheets_only:
        checked_configs(args.scenes, args.set)  # before the first scene's minutes, not after them
    if not args.sheets_only:
        print("| scene | search | weak 10 % | weak 20 % | weak 30 % | strong 10 % | mean zeta | mean psi "
              "| distance mean (cells) | distance p90 | area refined / coarse | functional | triangles | iterations "
              "| seconds (search) |")
        print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
        for name in args.scenes:
            for mode in args.search:
                r = scene_row(name, args.set + [f"refine.search={mode}"])
                if mode == args.search[0]:
                    f = r["coarse"]
                    print(f"| {name} | coarse | {100 * f['weak_share_10']:.1f} | {100 * f['weak_share_20']:.1f} "
                          f"| {100 * f['weak_share_30']:.1f} | {100 * f['strong_share_10']:.1f} | {f['mean_zeta']:.3f} "
                          f"| {f['mean_psi']:.3f} | | | | | | | |", flush=True)
                f = r["refined"]
                label = mode if mode == "none" or r["searched"] else f"{mode} (kept coarse)"
                print(f"| {name} | {label} | {100 * f['weak_share_10']:.1f} | {100 * f['weak_share_20']:.1f} "
                      f"| {100 * f['weak_share_30']:.1f} | {100 * f['strong_share_10']:.1f} | {f['mean_zeta']:.3f} "
                      f"| {f['mean_psi']:.3f} "
                      f"| {f['distance_mean']:.2f} | {f['distance_p90']:.2f} | {r['area_ratio']:.3f} "
                      f"| {r['functional']:.5g} | {r['triangles']} | {r['iterations']} "
                      f"| {r['seconds']:.1f} ({r['search_seconds']:.2f}) |", flush=True)
    if not args.no_sheets:
        print()
        print("| weak sheet | cut offset (voxels) | search | coarse mean distance | refined mean distance "
              "| area within 1 voxel | functional | triangles | iterations | seconds |")
        print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
        cases = [(kind, offset, 0.0, RefineParams().band) for kind in SHEETS for offset in (2.0, 4.0, 8.0)]
        cases += [(TURNED, 4.0, float(angle), float(band)) for angle, band in TURNED_SHEETS]
        for kind, offset, angle, band in cases:
            for mode in args.search:
                # the turned sheets' boxes hold half of each piece's depth beyond the sheet (core 0.5)
                params = RefineParams(max_triangles=20000, search=mode, band=band, **({"core": 0.5} if angle else {}))
                r = sheet_row(kind, offset, params, angle)
                what = f"{kind} {angle:g} deg" if angle else kind
                print(f"| {what} | {offset:g} | {mode if mode == 'none' or r['searched'] else mode + ' (kept)'} "
                      f"| {r['coarse']:.2f} | {r['mean']:.3f} | {100 * r['within']:.1f} % | {r['functional']:.4g} "
                      f"| {r['triangles']} | {r['iterations']} | {r['seconds']:.2f} |", flush=True)


if __name__ == "__main__":
    from fracture.process import prepare_process

    prepare_process()
    main()
