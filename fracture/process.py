"""Process set-up for a program that refines: explicit calls, made once by the command line and the
benchmarks (importing any module of the package changes nothing).

- :func:`~fracture.refine.clear_stale_numba_cache`: numba caches each compiled
  function beside its source and checks only that file's time stamp, but the
  refinement's kernels call each other across modules; machine code compiled
  from other sources than the current ones is deleted.
- :func:`~fracture.allocator.keep_freed_memory`: glibc keeps freed large
  blocks for reuse (process-wide; see :mod:`fracture.allocator`).
- the threading layer of numba's parallel kernels (:data:`THREADING_LAYER`):
  numba's own work queue, which needs no library beside numba and stays
  safe in a process forked after a parallel kernel ran (GNU OpenMP's hangs
  there); the project's own workers are started with ``spawn`` (sweeps,
  the viewer's re-run process, the benchmarks). A process that does not call
  this gets numba's choice.
"""

from __future__ import annotations


# numba's threading layer for the parallel kernels (see the module notes).
THREADING_LAYER = "workqueue"


def prepare_process(*, allocator: bool = True) -> None:
    """Clear stale compiled kernels, choose the parallel kernels' threading layer and (with ``allocator``)
    tell glibc to keep freed memory."""
    import numba

    from fracture.allocator import keep_freed_memory
    from fracture.refine import clear_stale_numba_cache

    numba.config.THREADING_LAYER = THREADING_LAYER
    clear_stale_numba_cache()
    if allocator:
        keep_freed_memory()
