"""numpy's BLAS on one thread for the measurement: its matrix products are thin (points x 3 or 4 times a 3 x 3
or 4 x 4 matrix), one thread does each in a few ms, and OpenBLAS's own thread team makes them unpredictable.

Measured on the 2-core cell PC under load (/work/notes/issue-12-cycle2.md): the same products took 2.5-3.5 x
longer in sum on OpenBLAS's default threads, single ones up to 358 ms instead of ~10 ms, because the team
waits for a core that the measurement's other threads (or any other process) hold; one thread never did.
The products themselves are the same numbers on one thread (the rows are split between threads, each element
is computed whole by one).

numpy names no API for this; the OpenBLAS numpy loads exports its setter (scipy-openblas builds prefix the
names), found here among the shared libraries the process has loaded.
"""

from __future__ import annotations

import ctypes
import logging
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

_SETTERS = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads", "openblas_set_num_threads")
_GETTERS = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads", "openblas_get_num_threads")


def _openblas() -> ctypes.CDLL | None:
    """numpy's OpenBLAS, loaded (None where numpy uses another BLAS or the process map cannot be read)."""
    np.dot(np.ones((2, 2)), np.ones((2, 2)))  # numpy loads its BLAS at import; this only makes sure
    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:
        return None
    paths = sorted({line.split()[-1] for line in maps.splitlines() if "openblas" in line.rsplit("/", 1)[-1]})
    for path in paths:
        lib = ctypes.CDLL(path)
        if any(hasattr(lib, name) for name in _SETTERS):
            return lib
    return None


def blas_threads() -> int | None:
    """The threads numpy's OpenBLAS uses (None: not OpenBLAS, or not found)."""
    lib = _openblas()
    getter = None if lib is None else next((getattr(lib, n) for n in _GETTERS if hasattr(lib, n)), None)
    return None if getter is None else int(getter())


def one_blas_thread() -> bool:
    """Set numpy's OpenBLAS to one thread for the whole process; False (logged) where it cannot be set."""
    lib = _openblas()
    setter = None if lib is None else next((getattr(lib, n) for n in _SETTERS if hasattr(lib, n)), None)
    if setter is None:
        log.info("numpy's BLAS is not an OpenBLAS found in this process: its threads are left as they are")
        return False
    setter(ctypes.c_int(1))
    return True
