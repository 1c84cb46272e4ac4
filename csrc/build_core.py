"""cffi build script of the matching core (API mode).

setup.py names this file in `cffi_modules`, so `pip install .` compiles csrc/*.c
into the extension module `cellctl.stereo._core`.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from cffi import FFI

HERE = Path(__file__).resolve().parent


def _cdef_from_header(text: str, defines: bool = True) -> str:
    """The public header minus what cffi's parser does not take (guards, includes)."""
    lines = [ln for ln in text.splitlines() if not ln.startswith("#")]
    text = "\n".join(lines)
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
    if not defines:
        return text
    constants = """
        #define CC_DISP_SCALE ...
        #define CC_INVALID ...
        #define CC_MAX_P2 ...
        #define CC_MAX_DISPARITIES ...
        #define CC_MAX_DIM ...
    """
    return constants + text


ffibuilder = FFI()
ffibuilder.cdef(_cdef_from_header((HERE / "cellctl_core.h").read_text()))
# The measurement's hot loops (cellctl.vision.outliers, subpixel) share the module: one extension to build.
ffibuilder.cdef(_cdef_from_header((HERE / "cloud_kernels.h").read_text(), defines=False))
ffibuilder.cdef(_cdef_from_header((HERE / "pixel_marks.h").read_text(), defines=False))
# The change test against the taught table (cellctl.vision.change) too; its two limits for the wrapper's checks.
ffibuilder.cdef("#define CHK_MAX_DIM ...\n#define CHK_MAX_WINDOW ...\n")
ffibuilder.cdef(_cdef_from_header((HERE / "change_kernels.h").read_text(), defines=False))

_sources = sorted(str(p.relative_to(HERE.parent)) for p in HERE.glob("*.c"))
_extra = os.environ.get("CELLCTL_CFLAGS", "").split()
ffibuilder.set_source(
    "cellctl.stereo._core",
    '#include "cellctl_core.h"\n#include "cloud_kernels.h"\n#include "pixel_marks.h"\n#include "change_kernels.h"',
    sources=_sources,
    include_dirs=[str(HERE.relative_to(HERE.parent))],
    # -fvisibility=hidden: the module exports only its init function, so calls between the core's
    # units go direct instead of through the PLT (cc_path_step runs once per pixel and path).
    # -fno-math-errno: the core never reads errno, so sqrt is the one correctly rounded instruction (and a loop
    # of them can be vectorised) instead of a library call kept for errno; the same values.
    extra_compile_args=[
        "-std=c11",
        "-O3",
        "-fno-math-errno",
        "-fopenmp",
        "-fvisibility=hidden",
        "-Wall",
        "-Wextra",
        "-Wno-unused-parameter",
        *_extra,
    ],
    extra_link_args=["-fopenmp", *_extra],
)

if __name__ == "__main__":
    ffibuilder.compile(verbose=True)
