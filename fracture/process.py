"""Process set-up for a program that refines: explicit calls, made once by the command line and the
benchmarks (importing any module of the package changes nothing).

- :func:`~fracture.refine.clear_stale_numba_cache`: numba caches each compiled
  function beside its source and checks only that file's time stamp, but the
  refinement's kernels call each other across modules; machine code compiled
  from other sources than the current ones is deleted.
- :func:`~fracture.allocator.keep_freed_memory`: glibc keeps freed large
  blocks for reuse (process-wide; see :mod:`fracture.allocator`).
"""

from __future__ import annotations


def prepare_process(*, allocator: bool = True) -> None:
    """Clear stale compiled kernels and (with ``allocator``) tell glibc to keep freed memory."""
    from fracture.allocator import keep_freed_memory
    from fracture.refine import clear_stale_numba_cache

    clear_stale_numba_cache()
    if allocator:
        keep_freed_memory()
