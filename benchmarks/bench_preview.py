"""Preview speed: a re-run of the example with only psi changed, at a preview budget, with the stage cache.

The first run fills the cache (not timed); each timed run changes ``psi.stress_weight`` only, so
the coarse stage, the strength field, the distances and the search's band are reused, and refines at
``refine.max_triangles`` (the preview budget). Prints the seconds per stage of the fastest of
``--repeat`` runs, in this process (the kernels compiled and loaded once before).

    python benchmarks/bench_preview.py [--budget 20000] [--repeat 3]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fracture.io import layout  # noqa: E402
from fracture.pipeline import runner  # noqa: E402
from fracture.pipeline.cache import StageCache  # noqa: E402
from fracture.pipeline.config import load_config  # noqa: E402


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(ROOT / "configs" / "example.yaml"))
    ap.add_argument("--budget", type=int, default=20000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        cache = StageCache(Path(tmp) / "cache")
        common = [f"refine.max_triangles={args.budget}", "refine.snapshots=false"]
        runner.run(load_config(args.config, common), Path(tmp) / "warm", until="refine", progress=False, cache=cache)
        print("| run | stress weight | coarse s | fields s | refine s | total s | wall s | triangles | iterations |")
        print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
        for k in range(args.repeat):
            weight = 0.3 + 0.1 * k
            start = time.perf_counter()
            out = runner.run(load_config(args.config, common + [f"psi.stress_weight={weight}"]), Path(tmp) / f"r{k}",
                             until="refine", progress=False, cache=cache)
            wall = time.perf_counter() - start
            m = layout.read_manifest(out)
            s = {n: v["seconds"] for n, v in m["stages"].items()}
            print(f"| {k + 1} | {weight:.1f} | {s['coarse']:.2f} | {s['fields']:.2f} | {s['refine']:.2f} "
                  f"| {sum(s.values()):.2f} | {wall:.2f} | {m['counts']['refined_fracture_triangles']} "
                  f"| {m['counts']['iterations']} |", flush=True)


if __name__ == "__main__":
    from fracture.process import prepare_process

    prepare_process()
    main()
