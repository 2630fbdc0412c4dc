"""The one-off compilation of the kernels, ahead of the first run (``fracref compile``; ``make install`` runs it).

numba compiles the fields', the refinement's, the mesh queries' and the
pieces' kernels the first time they are called and caches the machine code
beside their sources (:mod:`fracture.refine`), which made a fresh install's
first ``fracref run`` wait for it (about half a minute). :func:`compile_kernels`
runs a tiny built-in scene through every stage instead, with the global search
and a grain (the branch: virtual fracture, the anisotropic flow), into a
temporary directory that it removes, with no stage cache (every stage runs).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

# The tiny run: the branch scene on a coarse grid, a small budget, a few frames.
WARMUP_CONFIG = {
    "name": "compile",
    "input": {"kind": "scene", "scene": "branch", "frames": 4},
    "grid": {"resolution": [12, 12, 24]},
    "pyramid": {"levels": 2},
    "refine": {"max_triangles": 3000, "iterations": 6, "search": "graphcut", "snapshots": False},
    "strength": {"layers": [{"kind": "radial", "axis": "z"}, {"kind": "grain", "axis": "z", "ratio": 3.0}]},
    "animate": {"check_samples": 1000, "usd": True},
}


def compile_kernels() -> float:
    """Run :data:`WARMUP_CONFIG` through every stage in a temporary directory (numba compiles and caches the
    kernels on the way); returns the seconds it took."""
    from fracture.pipeline import runner
    from fracture.pipeline.config import check_config

    start = time.perf_counter()
    cfg = check_config(WARMUP_CONFIG, "fracref compile")
    with tempfile.TemporaryDirectory(prefix="fracref-compile-") as tmp:
        runner.run(cfg, Path(tmp) / "run", progress=False)
    _imports_kernels()
    return time.perf_counter() - start


def _imports_kernels() -> None:
    """The kernels of a Cell Fracture import that the built-in scene does not reach: the exact winding
    numbers of its pinholes' apexes and of its shells' probes."""
    import numpy as np

    from fracture.mesh.topology import winding_numbers

    winding_numbers(np.eye(3), np.array([[0, 1, 2]]), np.zeros((1, 3)))
