"""Process set-up for a program that refines: explicit calls, made once by the command line and the
benchmarks (importing any module of the package changes nothing).

- :func:`~fracture.refine.clear_stale_numba_cache`: numba caches each compiled
  function beside its source and checks only that file's time stamp, but the
  refinement's kernels call each other across modules; machine code compiled
  from other sources than the current ones is deleted.
- :func:`~fracture.allocator.keep_freed_memory`: glibc keeps freed large
  blocks for reuse (process-wide; see :mod:`fracture.allocator`).
- the threading layer of numba's parallel kernels (:data:`THREADING_LAYER`):
  GNU OpenMP: a kernel starts in microseconds, against 120-130 us for
  numba's own work queue on the project's 2-core machine, and the
  refinement runs thousands of small kernels (the bunny's refinement 4.0 s
  against 5.1 s, the Jell-O's 1.35 s against 1.96 s;
  `docs/design-measurements.md`). Its threads sleep between kernels
  (:data:`WAIT_POLICY`, unless ``OMP_WAIT_POLICY`` is set): spinning, they
  start a kernel in 1.4 us instead of 9-11, but when another program keeps a
  core busy, every kernel waits for a thread that cannot run, and the
  Jell-O's refinement took 7.8-9.7 s instead of 1.2-1.7 s (the bunny's 28.7 s
  against 5.0 s on one thread). GNU OpenMP reads it when it is loaded, so
  this is called before anything loads it (the command line does so first
  of all). GNU OpenMP hangs in a
  process forked after a kernel ran: the project's own workers are started
  with ``spawn`` (sweeps, the viewer's re-run process, the benchmarks). A
  layer named in ``NUMBA_THREADING_LAYER`` is kept (the test suite's
  workers share the cores and use the work queue, whose threads sleep).
- the kernels' threads: as many as the cores the process may run on (numba
  counts the machine's, also in a process pinned to fewer), or as asked: a
  sweep's workers share the cores. A caller whose kernels are small runs them
  on its own thread (:func:`fracture.threads.kernel_threads`).

A process that does not call this gets numba's choices.
"""

from __future__ import annotations

import os

# numba's threading layer for the parallel kernels (see the module notes).
THREADING_LAYER = "omp"

# How GNU OpenMP's threads wait for the next kernel (``OMP_WAIT_POLICY``; see the module notes).
WAIT_POLICY = "passive"


def on_main_thread() -> bool:
    """Whether this is the main thread (the only one that may set signal handlers)."""
    import threading

    return threading.current_thread() is threading.main_thread()


def cores() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


# Seconds after which a signal that arrived inside a compiler callback is sent again.
_REDELIVER_SECONDS = 0.05


def later_if_compiling(signum: int, frame) -> bool:
    """For a signal handler that raises to stop the program: whether the signal came inside a callback from the
    compiler's C code (numba writing a kernel to its cache through llvmlite), where an exception would be
    printed with its traceback and dropped, and the program would go on; then the signal is sent again a
    moment later, once the callback has returned."""
    while frame is not None:
        if "llvmlite" in frame.f_code.co_filename:
            import threading

            threading.Timer(_REDELIVER_SECONDS, os.kill, (os.getpid(), signum)).start()
            return True
        frame = frame.f_back
    return False


# The threading layers numba knows (NUMBA_THREADING_LAYER).
_LAYERS = ("default", "safe", "threadsafe", "forksafe", "omp", "tbb", "workqueue")


def environment_problem() -> str | None:
    """What numba would refuse with a traceback in the environment (``NUMBA_NUM_THREADS``: a whole number of
    threads from 1; ``NUMBA_THREADING_LAYER``: a layer it knows), said in one line, or None. It reads the first
    when it is imported: the command line asks before it imports anything that imports numba (this module
    imports nothing of the package)."""
    count = os.environ.get("NUMBA_NUM_THREADS")
    if count is not None and not (count.strip().isdigit() and int(count) >= 1):
        return f"NUMBA_NUM_THREADS={count!r}: expected a whole number of threads from 1 (or unset: one per core)"
    layer = os.environ.get("NUMBA_THREADING_LAYER")
    if layer is not None and layer.strip().lower() not in _LAYERS:
        return (f"NUMBA_THREADING_LAYER={layer!r}: expected one of {', '.join(_LAYERS)} (or unset: "
                f"{THREADING_LAYER})")
    return None


def prepare_process(*, allocator: bool = True, threads: int | None = None) -> None:
    """Clear stale compiled kernels, choose the parallel kernels' threading layer and threads (default:
    one per core the process may run on) and (with ``allocator``) tell glibc to keep freed memory. An
    InputError (:func:`environment_problem`) when the environment asks numba for what it cannot do."""
    problem = environment_problem()
    if problem is not None:
        from fracture.errors import InputError

        raise InputError(problem)
    import numba

    from fracture.allocator import keep_freed_memory
    from fracture.refine import clear_stale_numba_cache

    if "NUMBA_THREADING_LAYER" not in os.environ:
        numba.config.THREADING_LAYER = THREADING_LAYER
    os.environ.setdefault("OMP_WAIT_POLICY", WAIT_POLICY)  # read by GNU OpenMP when numba loads it, below
    numba.set_num_threads(max(1, min(threads or cores(), numba.config.NUMBA_NUM_THREADS)))
    clear_stale_numba_cache()
    if allocator:
        keep_freed_memory()
