"""Named single-thread workers for the measurement's second core (numpy, OpenCV and the C kernels release the GIL).

Each name is its own thread, started at its first use and kept for the process: a task on one worker may wait
on a task it submitted to another (the glue path waits on its patch fits), never on its own.
"""

from __future__ import annotations

import threading
from concurrent import futures

_WORKERS: dict[str, futures.ThreadPoolExecutor] = {}
_LOCK = threading.Lock()


def worker(name: str) -> futures.ThreadPoolExecutor:
    """The one thread called `name` (created at the first call with that name)."""
    with _LOCK:
        if name not in _WORKERS:
            _WORKERS[name] = futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix=name)
        return _WORKERS[name]
