"""Process settings that keep every measurement cycle as fast as the median, set once before READY.

The service (cellctl.service.measuring) and the cycle bench (cellctl.eval.cycle_bench) call the same three.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import logging

import numpy  # also so that threadpoolctl sees numpy's BLAS: it finds only the libraries already loaded
from threadpoolctl import threadpool_info, threadpool_limits

log = logging.getLogger(__name__)


def one_blas_thread() -> bool:
    """numpy's BLAS on one thread for the whole process; False (logged) where numpy's BLAS is not found.

    The measurement's matrix products are thin (points x 3 or 4 times a 3 x 3 or 4 x 4 matrix): one thread
    does each in a few ms. On OpenBLAS's default thread team the same products took 2.5-3.5 x longer in sum
    on the 2-core cell PC under load, single ones up to 358 ms instead of ~10 ms, because the team waits for a
    core the measurement's other threads (or any other process) hold. The numbers are the same on one thread
    (each element is computed whole by one thread). threadpoolctl finds numpy's BLAS and sets it.
    """
    if blas_threads() is None:
        log.info("numpy's BLAS was not found in this process: its threads are left as they are")
        return False
    threadpool_limits(limits=1, user_api="blas")  # kept: not used as a context manager
    return True


def blas_threads() -> int | None:
    """The most threads any BLAS loaded in this process uses (None where none is found)."""
    counts = [int(pool["num_threads"]) for pool in threadpool_info() if pool.get("user_api") == "blas"]
    return max(counts) if counts else None


def settle_garbage_collector() -> None:
    """Collect once, then leave every object alive now out of later collections (gc.freeze).

    After start-up and a warm-up the process holds ~10^5 objects the collector tracks (modules, Open3D,
    the servers), and a full pass over them took 75-100 ms on the cell PC: whenever Python's allocation
    counts started one inside a cycle, that cycle was the slowest. Frozen, a pass only sees what was made
    since: well under a millisecond. Called once, after the warm-up."""
    gc.collect()
    gc.freeze()


# glibc's mallopt parameters (malloc.h) and the values set: above any array a cycle makes (the largest are
# ~12 MB), and far above what a cycle frees at once; one arena for every thread (below).
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_ARENA_MAX = -1, -3, -8
_MMAP_THRESHOLD_BYTES = 256 << 20
_TRIM_THRESHOLD_BYTES = 1 << 30
_ARENAS = 1  # every thread on the main heap, which the trim threshold keeps and warm_heap warms


def keep_freed_memory() -> bool:
    """glibc's malloc keeps the memory a cycle frees for the next one; False (logged) where it cannot be set.

    A cycle allocates and frees some 10^2 MB of numpy arrays. By default glibc maps blocks above a threshold
    it raises only as it sees them freed, and hands freed memory at the top of its heap back to the kernel:
    the next cycle takes it again page by page, each page a fault the kernel zeroes. Measured on the simulated
    cell: 12-14k faults (30-140 ms of system time under load) in each of the first cycles after the warm-up,
    ~1k from the seventh; with these settings 0-3k in the first cycle of each new sole size, then none. The
    process keeps the heap of its largest cycle (it reaches that peak every cycle anyway).

    Every thread made after this call allocates from the one main heap (M_ARENA_MAX 1). By default each thread
    that allocates gets an arena of its own (up to 8 per core): the cycle's worker threads (the glue path's,
    the change test's, the artifact writer) then grew and shrank heaps of their own, which the trim threshold
    does not govern (glibc unmaps a thread heap as soon as it is all free) and which warm_heap cannot reach.
    In the demo those threads took 1-6k faults in the cycles where a larger sole came first and again in a few
    later ones (16-17.5k over 20 cycles), and 13.6k in the warm-up's measurement; with one arena 34 in the
    warm-up and at most ~10 a cycle but for one or two heap growths of 0.3-0.8k (docs/benchmarks.md, ninth
    round). The threads share the arena's lock; the measuring thread's CPU per cycle did not change beyond the
    host's noise. Call it before the process starts threads: a thread that has allocated keeps its arena."""
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
        mallopt = getattr(libc, "mallopt", None)
    except OSError:
        mallopt = None
    if mallopt is None or not (
        mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_BYTES)
        and mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD_BYTES)
        and mallopt(_M_ARENA_MAX, _ARENAS)
    ):
        log.info("the C library's malloc settings could not be set (not glibc?): freed memory goes back as before")
        return False
    return True


# Memory touched at warm-up so that a sole larger than the warm-up pair's does not fault its arrays in: in the
# demo the largest sole (296 mm), first seen after the warm-up, spent 47-81 ms in its reprojection against 10-14
# in later cycles; with this much touched at warm-up, 15-19 ms (docs/benchmarks.md). A generous bound, not a
# measured need: it stays resident (keep_freed_memory).
WARM_HEAP_BYTES = 256 << 20
_WARM_BLOCK_BYTES = 8 << 20  # under the mmap threshold above, so the blocks come from the heap and stay in it


def warm_heap(total_bytes: int = WARM_HEAP_BYTES) -> None:
    """Touch `total_bytes` of the malloc heap, then free it: with keep_freed_memory's settings glibc keeps those
    pages, so the first cycle of a larger sole than the warm-up's finds them mapped instead of faulting each
    one in, in whichever thread allocates (one arena for all). Call after keep_freed_memory()."""
    blocks = [numpy.ones(_WARM_BLOCK_BYTES // 8) for _ in range(max(total_bytes // _WARM_BLOCK_BYTES, 0))]
    del blocks
