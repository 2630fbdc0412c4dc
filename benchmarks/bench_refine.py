"""Time the refinement (Sections 4.3, 4.4) on the five built-in scenes, at the paper's output sizes.

Each scene runs in its own process (peak memory is that process's); the
coarse input and the fields are built first and not timed. Prints a table
with the paper's figures (one core of an i7-2600) beside ours.

Usage: python benchmarks/bench_refine.py [--scenes wall clay ...] [--iterations N]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import resource
import time
from pathlib import Path

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
# output triangles and seconds reported in Section 6
PAPER = {"bunny": (174_000, 11.7), "branch": (123_000, 5.0), "wall": (208_000, 13.6),
         "clay": (40_000, 3.0), "jello": (32_000, 3.0)}


def run_scene(name: str, iterations: int | None, out: mp.Queue) -> None:
    import numpy as np

    from fields.build import build_fields
    from fracture.config import load_config
    from fracture.refine.collide import self_intersections
    from fracture.refine.engine import Refiner
    from fracture.refine.mesh import RefineMesh
    from fracture.scenes import build_scene
    from fracture.stages.refine import refine_params

    over = ["input.frames=8", f"refine.max_triangles={PAPER[name][0]}"]
    if iterations is not None:
        over.append(f"refine.iterations={iterations}")
    cfg = load_config(CONFIGS / f"{name}.yaml", over)
    cf = build_scene(name, cfg["seed"], cfg["input"]["frames"])
    fs = build_fields(cf.exterior_V, cf.V, cf.F, resolution=cfg["grid"]["resolution"],
                      padding=cfg["grid"]["padding"], layers=cfg["strength"]["layers"], seed=cfg["seed"],
                      normalize=cfg["strength"]["normalize"], stress_length=cfg["stress"]["length"],
                      strength_weight=cfg["psi"]["strength_weight"], stress_weight=cfg["psi"]["stress_weight"],
                      levels=cfg["pyramid"]["levels"], sigma=cfg["pyramid"]["sigma"])
    mesh = RefineMesh.from_coarse(cf.V, cf.F, cf.sides)
    r = Refiner(mesh, fs.pyramid, cf.exterior_V, cf.exterior_F, refine_params(cfg),
                np.random.default_rng(cfg["seed"]))
    t0 = time.perf_counter()
    log = r.run()
    seconds = time.perf_counter() - t0
    out.put(dict(coarse=len(cf.F), refined=len(mesh.F), seconds=seconds, iterations=len(log.energy),
                 collisions=log.seconds.get("collisions", 0.0), crossings=self_intersections(mesh.V, mesh.F),
                 peak_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--scenes", nargs="+", default=list(PAPER), choices=list(PAPER))
    ap.add_argument("--iterations", type=int, default=None, help="override refine.iterations")
    args = ap.parse_args()
    ctx = mp.get_context("fork")
    print("| scene | coarse tris | refined tris | iterations | seconds | of which collisions | tris/s "
          "| paper tris/s | ratio to paper | self-intersections | peak MB |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for name in args.scenes:
        q = ctx.Queue()
        p = ctx.Process(target=run_scene, args=(name, args.iterations, q))
        p.start()
        r = q.get()
        p.join()
        rate = r["refined"] / r["seconds"]
        paper_rate = PAPER[name][0] / PAPER[name][1]
        print(f"| {name} | {r['coarse']} | {r['refined']} | {r['iterations']} | {r['seconds']:.2f} "
              f"| {r['collisions']:.2f} | {rate:,.0f} | {paper_rate:,.0f} | {rate / paper_rate:.2f} "
              f"| {r['crossings']} | {r['peak_mb']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
