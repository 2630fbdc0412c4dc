"""Time the refinement (Sections 4.3, 4.4) on the five built-in scenes, at the paper's output sizes.

Each scene runs in its own process (peak memory is that process's); the
coarse input and the fields are built first and not timed. A short run first
fills numba's on-disk cache, so no scene pays the one-off compilation (after
an install or a change of the kernels). In each process two iterations on the
coarse surface then load the compiled kernels from that cache, which every
process does once; their time is the "first call" column, apart from the
refinement's. With ``--repeat N`` each scene is refined N times in its process
(same seed, same result). A shared machine varies by 20 % or more, more
between processes (and minutes) than within one: ``--rounds R`` runs the
whole list R times, every scene in a new process each round. The table gives
each scene's fastest run and, in "spread", its slowest over its fastest.
Prints the paper's figures (one core of an i7-2600) beside ours: its seconds over
ours ("paper s / seconds", how many times faster), and the rates of output
triangles (a scene that stops splitting where no vertex moves makes fewer
triangles than the paper's, so the rates are not the speed), and the
effect of the same runs: the share of the coarse and the refined surface's
area in the weakest fifth of zeta (``fracture/fidelity.py``). The
refinement's own loops run on one core; libigl's closest-point queries use
every core the process may run on: ``--cores 1`` pins each scene's process to
one core (the paper's setting), the default leaves it every core.

Usage: python benchmarks/bench_refine.py [--scenes wall clay ...] [--iterations N] [--repeat N] [--rounds R] [--cores N]
"""

from __future__ import annotations

import argparse
import resource
import sys
import time

from scenes import checked_configs, in_processes, refine, scene_with_fields

# output triangles and seconds reported in Section 6
PAPER = {"bunny": (174_000, 11.7), "branch": (123_000, 5.0), "wall": (208_000, 13.6),
         "clay": (40_000, 3.0), "jello": (32_000, 3.0)}


def run_scene(name: str, iterations: int | None, repeat: int, cores: int | None, sets: list, out) -> None:
    import copy
    import os

    if cores is not None:  # before any library starts its threads
        import numba

        os.sched_setaffinity(0, sorted(os.sched_getaffinity(0))[:cores])
        numba.set_num_threads(cores)  # the kernels' threads too (set for every core before the pinning)

    from fracture.mesh.intersect import self_intersections

    over = ["input.frames=8", f"refine.max_triangles={PAPER[name][0]}", *sets]
    if iterations is not None:
        over.append(f"refine.iterations={iterations}")
    cfg, cf, fs = scene_with_fields(name, over)
    warm = cfg.model_copy(update={"refine": cfg.refine.model_copy(update={"iterations": 2})})
    t0 = time.perf_counter()
    refine(warm, cf, fs)
    first = time.perf_counter() - t0
    runs = []
    for _ in range(repeat):
        t1 = time.perf_counter()
        mesh, log = refine(cfg, cf, fs)
        runs.append((time.perf_counter() - t1, log.seconds.get("collisions", 0.0), log.seconds.get("search", 0.0)))
    seconds, collisions, search = min(runs)  # the phases of the fastest run (every run makes the same surface)
    # the effect of the same run (fracture/fidelity.py): the share of its area in the weakest fifth of zeta
    from fracture.fidelity import inside_thresholds, surface_figures

    zeta = fs.field("zeta")
    thresholds = inside_thresholds(fs.grid, zeta, cf.exterior_V, cf.exterior_F)
    effect = {k: surface_figures(V, F, fs.grid, zeta, thresholds)["weak_share_20"]
              for k, (V, F) in (("weak_coarse", (cf.V, cf.F)), ("weak_refined", (mesh.V, mesh.F)))}
    out.put(dict(coarse=len(cf.F), refined=len(mesh.F), seconds=seconds, slowest=max(runs)[0], first=first, **effect,
                 search=search, searched=log.search is not None and log.search.surface is not None,
                 iterations=log.iterations, collisions=collisions, crossings=self_intersections(mesh.V, mesh.F),
                 peak_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--scenes", nargs="+", default=list(PAPER), choices=list(PAPER))
    ap.add_argument("--iterations", type=int, default=None, help="override refine.iterations")
    ap.add_argument("--repeat", type=int, default=1, help="refinements per scene and process; the fastest is shown")
    ap.add_argument("--rounds", type=int, default=1, help="runs of the whole scene list, a new process per scene each")
    ap.add_argument("--cores", type=int, default=None, help="pin each scene's process to this many cores (default: all)")
    ap.add_argument("--set", action="append", default=[], help="config override, key=value (e.g. refine.search=none)")
    args = ap.parse_args()
    for flag in ("repeat", "rounds", "cores"):
        if getattr(args, flag) is not None and getattr(args, flag) < 1:
            ap.error(f"--{flag} must be at least 1, got {getattr(args, flag)}")
    checked_configs(args.scenes, args.set)
    t0 = time.perf_counter()
    for _ in in_processes(run_scene, ["jello"], 2, 1, args.cores, args.set):  # compiles the kernels, or loads them from the cache
        pass
    print(f"(kernels ready in {time.perf_counter() - t0:.1f} s, not timed below)\n")
    best = {}
    for _ in range(args.rounds):
        for name, r in in_processes(run_scene, args.scenes, args.iterations, args.repeat, args.cores, args.set):
            old = best.get(name, r)
            best[name] = dict(min(old, r, key=lambda x: x["seconds"]), slowest=max(old["slowest"], r["slowest"]),
                              first=min(old["first"], r["first"]), peak_mb=max(old["peak_mb"], r["peak_mb"]))
            print(f"  {name}: {r['seconds']:.2f} s", file=sys.stderr, flush=True)
    print("| scene | coarse tris | refined tris | iterations | seconds | of which search | of which collisions "
          "| paper s | paper s / seconds | tris/s | paper tris/s | weak 20 % coarse | weak 20 % refined "
          "| self-intersections | peak MB | first call s | spread |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for name, r in best.items():
        r["spread"] = r["slowest"] / r["seconds"]
        rate = r["refined"] / r["seconds"]
        paper_rate = PAPER[name][0] / PAPER[name][1]
        search = f"{r['search']:.2f}" + ("" if r["searched"] or not r["search"] else " (kept coarse)")
        print(f"| {name} | {r['coarse']} | {r['refined']} | {r['iterations']} | {r['seconds']:.2f} | {search} "
              f"| {r['collisions']:.2f} | {PAPER[name][1]:.1f} | {PAPER[name][1] / r['seconds']:.2f} | {rate:,.0f} "
              f"| {paper_rate:,.0f} "
              f"| {100 * r['weak_coarse']:.1f} | {100 * r['weak_refined']:.1f} | {r['crossings']} | {r['peak_mb']:.0f} | {r['first']:.2f} | {r['spread']:.2f} |", flush=True)


if __name__ == "__main__":
    from fracture.process import prepare_process

    prepare_process()
    main()
