"""Time the coarse input: the five built-in scenes and the Blender sample import.

Prints a table. Usage: python benchmarks/bench_coarse.py [--frames T] [--repeat R]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from fracture.coarse.mesh_sequence import load_coarse_sequence
from fracture.coarse.scenes import PAPER_TRIANGLES, SCENES, build_scene

SAMPLE = Path(__file__).resolve().parents[2] / "shared" / "data" / "blender_cellfracture_cube8"


def best(fn, repeat):
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    rows = []
    for name in SCENES:
        seconds, cf = best(lambda n=name: build_scene(n, 0, args.frames), args.repeat)
        opened = cf.face_fracture_time[cf.face_fracture_time < cf.n_frames]
        rows.append((name, cf.n_components, int((~cf.virtual).sum()), int(cf.virtual.sum()), PAPER_TRIANGLES[name],
                     len(cf.exterior_F), int(opened.min()) + 1 if len(opened) else "-", seconds))
    if SAMPLE.is_dir():
        seconds, (cf, _) = best(lambda: load_coarse_sequence(SAMPLE), args.repeat)
        opened = cf.face_fracture_time[cf.face_fracture_time < cf.n_frames]
        rows.append(("blender cube8 (import)", cf.n_components, len(cf.F), 0, "-", len(cf.exterior_F),
                     int(opened.min()) + 1 if len(opened) else "-", seconds))
    print("| scene | components | fracture tris | virtual | paper | exterior tris | first split frame | seconds |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        print("| " + " | ".join(str(x) if not isinstance(x, float) else f"{x:.2f}" for x in r) + " |")


if __name__ == "__main__":
    from fracture.process import prepare_process

    prepare_process()
    main()
