"""The one-off compilation of the kernels, ahead of the first run (``fracref compile``; ``make install`` runs it).

numba compiles the fields', the refinement's, the mesh queries' and the
pieces' kernels the first time they are called and caches the machine code
beside their sources (:mod:`fracture.refine`), which made a fresh install's
first ``fracref run`` wait for it (about half a minute). :func:`compile_kernels`
runs a tiny built-in scene through every stage instead, with the global search
and a grain (the branch: virtual fracture, the anisotropic flow), into a
temporary directory that it removes, with no stage cache (every stage runs).

On two cores or more a second process (started with ``spawn``) compiles at
the same time: it refines the same scene without the search
(:data:`FLOW_FIRST`), so that it reaches the flow's kernels (the collision
tests, the edge flips, the step limits: 45 of the 125 s) while the first
process is still compiling the search's, and the first one finds them in the
cache. numba writes its cache files whole (a temporary file, then a rename),
so the two may write the same kernel's (the same
scene calls it with the same types in both). ``fracref compile`` took 125 s on one
core and 93 s on two (`docs/design-measurements.md`).
"""

from __future__ import annotations

import signal
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


# Seconds the second process has to unwind once told to stop, before it is killed.
_STOP_SECONDS = 10.0
# The second process's run: the same scene refined without the search, up to the refinement.
FLOW_FIRST = {**WARMUP_CONFIG, "refine": {**WARMUP_CONFIG["refine"], "search": "none", "iterations": 3}}


def compile_kernels(processes: int | None = None) -> float:
    """Run :data:`WARMUP_CONFIG` through every stage in a temporary directory (numba compiles and caches the
    kernels on the way), with :data:`FLOW_FIRST` in a second process beside it when ``processes`` (default:
    the cores) is 2 or more; returns the seconds it took. If the second process fails, its run is made here
    after the first (an error in it then says what it is)."""
    import multiprocessing

    from fracture.process import cores, on_main_thread
    from fracture.refine import clear_stale_numba_cache

    start = time.perf_counter()
    clear_stale_numba_cache()  # here, before the second process looks (it would clear what this one wrote)
    helper = None
    try:
        if (cores() if processes is None else processes) >= 2:
            helper = multiprocessing.get_context("spawn").Process(target=_helper, name="fracref compile",
                                                                  daemon=True)
            # started with Ctrl-C ignored (an ignored signal stays so in the new program, until it sets its own):
            # a Ctrl-C during its start-up would print a traceback of it
            previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if on_main_thread() else None
            try:
                helper.start()
            finally:
                if previous is not None:
                    signal.signal(signal.SIGINT, previous)
        _warm(WARMUP_CONFIG)
        if helper is not None:
            helper.join()
    finally:
        if helper is not None and helper.is_alive():  # stopped: the helper removes its run directory ...
            helper.terminate()
            helper.join(_STOP_SECONDS)
            if helper.is_alive():  # ... unless a compiler pass holds it past this
                helper.kill()
                helper.join()
    if helper is not None and helper.exitcode != 0:
        _warm(FLOW_FIRST, until="refine")
    _unreached_kernels()
    return time.perf_counter() - start


def _warm(config: dict, until: str | None = None) -> None:
    """Run ``config`` into a temporary directory, which goes with it."""
    from fracture.pipeline import runner
    from fracture.pipeline.config import check_config

    cfg = check_config(config, "fracref compile")
    with tempfile.TemporaryDirectory(prefix="fracref-compile-") as tmp:
        runner.run(cfg, Path(tmp) / "run", until=until, progress=False)


def _helper() -> None:
    """The second process: :data:`FLOW_FIRST` up to the refinement. Ctrl-C is the first process's to answer
    (it stops this one); SIGTERM and SIGHUP unwind, so that the run directory goes, and end it without a word
    (what the stop broke on the way, an import half done, is not an error to tell). It stops so too when the
    first process has gone (killed: a daemon process is stopped only by a parent that exits normally)."""
    import os

    from fracture.process import later_if_compiling, prepare_process

    stopped = []

    def stop(signum, frame):
        if not later_if_compiling(signum, frame):
            stopped.append(signum)
            raise SystemExit(128 + signum)

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for signum in (signal.SIGTERM, signal.SIGHUP):  # SIGHUP: the terminal closed
        signal.signal(signum, stop)
    _follow_parent()
    try:
        prepare_process()
        _warm(FLOW_FIRST, until="refine")
    except BaseException:
        if stopped:
            os._exit(128 + stopped[0])
        raise


def _unreached_kernels() -> None:
    """The kernels the built-in scene does not reach, called directly with the types a run passes: a Cell
    Fracture import's exact winding numbers (its pinholes' apexes, its shells' probes); the two-level
    search's (a band of more than a few thousand free nodes: the full grid's labels from the coarse
    level's, and the fine band of every piece) and the flips' test of changed triangles against the rest,
    which the built-in example (the collapsing wall) calls."""
    import numpy as np

    from fracture.mesh.topology import winding_numbers
    from fracture.refine import flips, reach, search

    winding_numbers(np.eye(3), np.array([[0, 1, 2]]), np.zeros((1, 3)))
    labels = np.zeros((3, 3, 3), np.int64)
    search._agreed(np.zeros((1, 3), np.int64), labels)
    reach.near_label(labels, np.arange(2, dtype=np.int64), 0, 1)
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    F = np.array([[0, 1, 2], [0, 1, 3]], np.int64)
    flips._meet_any(V, F, np.array([0], np.int64), np.array([1], np.int64))


def _follow_parent() -> None:
    """SIGTERM to this process once the process that started it has ended (a thread waits for it)."""
    import multiprocessing
    import os
    import threading
    from multiprocessing.connection import wait

    parent = multiprocessing.parent_process()
    if parent is None:
        return

    def watch():
        wait([parent.sentinel])
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="fracref compile: parent", daemon=True).start()
