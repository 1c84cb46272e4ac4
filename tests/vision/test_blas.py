"""Process settings (cellctl.vision.runtime): numpy's OpenBLAS on one thread with the same products; freed memory kept."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.vision.runtime import blas_threads, one_blas_thread


def test_one_blas_thread_sets_numpys_openblas_to_one_thread_with_the_same_products() -> None:
    if blas_threads() is None:
        pytest.skip("numpy here is not built on an OpenBLAS this process can find")
    rng = np.random.default_rng(0)
    points, matrix = rng.random((200_000, 4)) * 500, rng.random((4, 4))
    before = points @ matrix.T
    assert one_blas_thread()
    assert blas_threads() == 1
    assert np.array_equal(points @ matrix.T, before)


def test_keep_freed_memory_lets_the_next_cycle_reuse_what_the_last_one_freed() -> None:
    import resource

    from cellctl.vision.runtime import keep_freed_memory

    def faults_of_a_40_mb_array() -> int:
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        block = np.ones(5 << 20)  # 40 MB, above the largest block glibc would otherwise take from its heap
        after = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        del block
        return after - before

    if not keep_freed_memory():
        pytest.skip("not glibc: its malloc settings are not available here")
    faults_of_a_40_mb_array()  # the heap grows once
    assert faults_of_a_40_mb_array() < 50  # then the freed block is used again (0 here; mapped anew: 532)


def _printed_by_fresh_processes(script: str, modes: tuple[str, ...]) -> dict[str, int]:
    """Per mode, the integer `script` prints when run in a fresh Python process with the mode as its argument."""
    import subprocess
    import sys

    return {
        mode: int(
            subprocess.run([sys.executable, "-c", script, mode], capture_output=True, text=True, check=True).stdout
        )
        for mode in modes
    }


def test_warm_heap_leaves_pages_mapped_for_a_larger_cycle() -> None:
    # A fresh process each, so that nothing earlier grew the heap: the faults of ~60 MB of cycle-sized arrays.
    script = (
        "import resource, sys, numpy as np\n"
        "from cellctl.vision.runtime import keep_freed_memory, warm_heap\n"
        "if not keep_freed_memory(): print(-1); sys.exit()\n"
        "if sys.argv[1] == 'warm': warm_heap(96 << 20)\n"
        "before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt\n"
        "arrays = [np.ones(3 << 17) for _ in range(20)]\n"  # 20 x 3 MB, each under glibc's default mmap threshold
        "print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)\n"
    )
    faults = _printed_by_fresh_processes(script, ("cold", "warm"))
    if faults["cold"] < 0:
        pytest.skip("not glibc: its malloc settings are not available here")
    assert faults["cold"] > 10_000  # 60 MB is ~15000 pages, each faulted in on first touch
    assert faults["warm"] < 0.05 * faults["cold"]


def test_warm_heap_serves_the_threads_made_after_keep_freed_memory() -> None:
    # The measurement's worker threads (glue path, change test, artifact writer) allocate too: with one arena
    # for all threads they take the pages warm_heap touched; each with an arena of its own, it faults them in.
    script = (
        "import ctypes, resource, sys, threading, numpy as np\n"
        "from cellctl.vision.runtime import keep_freed_memory, warm_heap\n"
        "if not keep_freed_memory(): print(-1); sys.exit()\n"
        "if sys.argv[1] == 'own-arenas': ctypes.CDLL('libc.so.6').mallopt(-8, 8)\n"  # 8 arenas: its own
        "warm_heap(96 << 20)\n"
        "faults = []\n"
        "def worker():\n"
        "    before = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt\n"
        "    arrays = [np.ones(3 << 17) for _ in range(20)]\n"  # 20 x 3 MB, as in the test above
        "    faults.append(resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - before)\n"
        "thread = threading.Thread(target=worker)\n"
        "thread.start()\n"
        "thread.join()\n"
        "print(faults[0])\n"
    )
    faults = _printed_by_fresh_processes(script, ("own-arenas", "one-arena"))
    if faults["one-arena"] < 0:
        pytest.skip("not glibc: its malloc settings are not available here")
    assert faults["own-arenas"] > 10_000  # the thread's own heap: ~15000 pages faulted in on first touch
    assert faults["one-arena"] < 0.05 * faults["own-arenas"]
