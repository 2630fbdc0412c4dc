"""How many threads a caller's parallel kernels run on: every thread set for the process where the work is
large, the calling thread alone where it is small.

numba's kernels run on the threads of GNU OpenMP, which sleep between kernels (:mod:`fracture.process`).
Waking one costs 0.2-0.3 ms per kernel on the project's 2-core machine, and an iteration of the refinement
runs dozens of kernels of well under a millisecond on a surface of a few thousand triangles (the areas and
normals of 2,000 triangles: 29 us on one thread, 273 us on two; of 30,000: 0.69 ms against 0.98 ms). The
refinement's iterations therefore run their kernels on one thread below :data:`PARALLEL_FROM` triangles
(measured in docs/design-measurements.md: the Jell-O and the clay 8-17 % faster, the bunny and the branch
within the machine's spread, the same surfaces to the bit; the collision tests of a 200,000-triangle surface
are faster on both threads, and so is the global search on the field grid, which keeps them).
"""

from __future__ import annotations

from contextlib import contextmanager

# Triangles of a refinement's surface from which an iteration's kernels run on every thread.
PARALLEL_FROM = 150_000


@contextmanager
def kernel_threads(elements: int, parallel_from: int = PARALLEL_FROM):
    """Inside, numba's parallel kernels called from this thread run on every thread set for it when
    ``elements`` reaches ``parallel_from``, on this thread alone below; the count before is restored after.
    numba's thread count is the calling thread's own: other threads are not affected."""
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(before if elements >= parallel_from else 1)
    try:
        yield
    finally:
        numba.set_num_threads(before)
