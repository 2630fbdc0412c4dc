"""The random-cut property test's cases (``tests/cutgen.py``) run end to end, as a table: case, object, cut,
outcome (ok, or the refusal's reason), seconds (docs/import.md shows it).

    python benchmarks/random_cuts.py [--cases N] [--jobs 2]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import re
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]


def _one(seed: int) -> tuple:
    import json

    import cutgen
    from fracture.io import layout

    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        ext_kind, cut_kind, outcome, out = cutgen.run_case(seed, tmp)
        notes = layout.read_manifest(out).get("notes", []) if out is not None else []
    return seed, ext_kind, cut_kind, outcome, time.perf_counter() - start, notes


def _init() -> None:
    sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
    from fracture.process import prepare_process

    prepare_process()


def main(argv=None) -> None:
    import cutgen

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=cutgen.SYSTEMATIC)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    with mp.get_context("spawn").Pool(args.jobs, initializer=_init) as pool:
        rows = pool.map(_one, range(args.cases), chunksize=1)
    print("| case | object | cut | outcome | seconds | notes |\n| --- | --- | --- | --- | --- | --- |")
    for seed, ext_kind, cut_kind, outcome, seconds, notes in rows:
        reason = re.sub(r"\s+", " ", outcome).replace("|", "/")
        said = "; ".join(notes).replace("|", "/")
        print(f"| {seed} | {ext_kind} | {cut_kind} | {reason} | {seconds:.1f} | {said} |")
    ok = sum(r[3] == "ok" for r in rows)
    print(f"\n{ok} of {len(rows)} ran; {len(rows) - ok} refused")


if __name__ == "__main__":
    main()
