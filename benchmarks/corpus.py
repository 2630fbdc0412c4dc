"""Do real Cell Fracture exports run end to end? One row per case of examples/cellfracture.

Each case is run with configs/blender_cube8.yaml (the default refinement budget unless --set says
otherwise) on one of its exports; a row says whether the run completed and whether every piece
came out closed, vertex-manifold and free of self-intersections, with the triangles and seconds.

    python benchmarks/corpus.py                          # Blender's OBJ exports, default config
    python benchmarks/corpus.py --format sample --set refine.max_triangles=20000
    python benchmarks/corpus.py --dir /tmp/held           # cases made with make_cellfracture.py --random
"""

from __future__ import annotations

import argparse
import sys
import tarfile
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fracture.io import layout  # noqa: E402
from fracture.pipeline import runner  # noqa: E402
from fracture.pipeline.config import load_config  # noqa: E402
from fracture.errors import ConfigError, InputError, ResultError, StageError  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--format", default="blender_obj", choices=["sample", "blender_obj", "ply"])
    ap.add_argument("--case", action="append", help="default: every case")
    ap.add_argument("--dir", type=Path, help="cases made elsewhere (one folder per case, as "
                    "tools/make_cellfracture.py writes them) instead of the shipped archives")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE")
    args = ap.parse_args()
    if args.dir:
        cases = sorted(p.name for p in args.dir.iterdir() if (p / "case.json").is_file())
    else:
        archives = sorted((ROOT / "examples" / "cellfracture").glob("*.tar.xz"))
        cases = [a.name[:-len(".tar.xz")] for a in archives]
    if args.case:
        cases = [c for c in cases if c in args.case]
    print("| case | result | bad pieces | refined triangles | seconds |\n| --- | --- | --- | --- | --- |")
    good = 0
    with tempfile.TemporaryDirectory() as tmp:
        root = args.dir or Path(tmp)
        for case in cases:
            if not args.dir:
                with tarfile.open(ROOT / "examples" / "cellfracture" / f"{case}.tar.xz") as tar:
                    tar.extractall(root, filter="data")
            pattern = "*.ply" if args.format == "ply" else "*.obj"
            try:
                cfg = load_config(ROOT / "configs" / "blender_cube8.yaml",
                                  [f"input.path={root / case / args.format}", f"input.glob='{pattern}'"]
                                  + args.overrides)
            except ConfigError as exc:  # a wrong --set: the same for every case
                raise SystemExit(f"error: {exc}") from None
            start = time.perf_counter()
            try:
                out = runner.run(cfg, Path(tmp) / f"run_{case}", progress=False)
            except (InputError, ResultError, StageError) as exc:
                print(f"| {case} | refused: {str(exc)[:120]} | | | {time.perf_counter() - start:.0f} |")
                continue
            manifest = layout.read_manifest(out)
            bad = [i for i, p in enumerate(manifest["stats"]["animate"]["pieces"])
                   if not (p["closed_oriented"] and p["vertex_manifold"] and p["self_intersections"] == 0)]
            good += not bad
            print(f"| {case} | {'ok' if not bad else 'bad pieces'} | {', '.join(map(str, bad))} | "
                  f"{manifest['counts']['refined_fracture_triangles']} | {time.perf_counter() - start:.0f} |")
    print(f"\n{good} of {len(cases)} cases end to end with every piece closed, manifold and uncrossed")
    return 0


if __name__ == "__main__":
    from fracture.process import prepare_process

    prepare_process()
    sys.exit(main())
