"""Process set-up for a program that refines: explicit calls, made once by the command line and the
benchmarks (importing any module of the package changes nothing).

- :func:`~fracture.refine.clear_stale_numba_cache`: numba caches each compiled
  function beside its source and checks only that file's time stamp, but the
  refinement's kernels call each other across modules; machine code compiled
  from other sources than the current ones is deleted.
- :func:`~fracture.allocator.keep_freed_memory`: glibc keeps freed large
  blocks for reuse (process-wide; see :mod:`fracture.allocator`).
- the threading layer of numba's parallel kernels (:data:`THREADING_LAYER`):
  GNU OpenMP, whose threads wait for the next kernel spinning: a kernel
  starts in 2 us, against 120-130 us for numba's own work queue on the
  project's 2-core machine, and the refinement runs thousands of small
  kernels (the bunny's refinement 4.0 s against 5.1 s, the Jell-O's 1.35 s
  against 1.96 s; `docs/design-measurements.md`). GNU OpenMP hangs in a
  process forked after a kernel ran: the project's own workers are started
  with ``spawn`` (sweeps, the viewer's re-run process, the benchmarks). A
  layer named in ``NUMBA_THREADING_LAYER`` is kept (the test suite's
  workers share the cores and use the work queue, whose threads sleep).
- the kernels' threads: as many as the cores the process may run on (numba
  counts the machine's, also in a process pinned to fewer), or as asked: a
  sweep's workers share the cores.

A process that does not call this gets numba's choices.
"""

from __future__ import annotations

import os

# numba's threading layer for the parallel kernels (see the module notes).
THREADING_LAYER = "omp"


def cores() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def prepare_process(*, allocator: bool = True, threads: int | None = None) -> None:
    """Clear stale compiled kernels, choose the parallel kernels' threading layer and threads (default:
    one per core the process may run on) and (with ``allocator``) tell glibc to keep freed memory."""
    import numba

    from fracture.allocator import keep_freed_memory
    from fracture.refine import clear_stale_numba_cache

    if "NUMBA_THREADING_LAYER" not in os.environ:
        numba.config.THREADING_LAYER = THREADING_LAYER
    numba.set_num_threads(max(1, min(threads or cores(), numba.config.NUMBA_NUM_THREADS)))
    clear_stale_numba_cache()
    if allocator:
        keep_freed_memory()
