"""The allocator setting: freed large blocks are reused without faulting their pages in again."""

import ctypes
import ctypes.util
import resource

import pytest

from fracture.allocator import keep_freed_memory

_SIZE = 96 << 20  # above glibc's largest automatic mmap threshold (32 MiB): always mapped afresh by default


def _faults_of_a_fresh_block(libc) -> int:
    """Page faults of allocating ``_SIZE`` bytes, writing them all, and freeing them."""
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    p = libc.malloc(_SIZE)
    assert p
    ctypes.memset(p, 1, _SIZE)
    libc.free(p)
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before


def test_a_freed_block_is_reused_without_page_faults():
    if not keep_freed_memory():
        pytest.skip("not glibc: the allocator cannot be told")
    libc = ctypes.CDLL(ctypes.util.find_library("c"))
    libc.malloc.restype = ctypes.c_void_p
    libc.malloc.argtypes = [ctypes.c_size_t]
    libc.free.argtypes = [ctypes.c_void_p]
    _faults_of_a_fresh_block(libc)  # the heap grows (and its pages are faulted in) once
    # a block mapped afresh would fault in every one of its 4 KiB pages again
    assert _faults_of_a_fresh_block(libc) < 0.01 * _SIZE / 4096
    assert keep_freed_memory()  # a second call is harmless
