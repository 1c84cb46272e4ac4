"""A lossless PNG written in bands of rows, with a call before each band that may hold the writer back.

The image log writes its pictures between cycles (cellctl.service.imagelog). A whole `cv2.imwrite` of a
1280x1024 colour frame takes ~70 ms, and once started it runs to the end. If the PLC triggers again
within that time (the demo's PLC does, ~70 ms after each answer), the write runs beside the next cycle,
and the matcher's OpenMP team waits for the core (one demo: match 231 ms instead of ~65, cycle 1.5 x the
median). Written band by band with `pause()` before each band, the writer stops within one band (~5 ms)
of a trigger and goes on after the cycle.

The format is plain PNG: 8-bit grey, RGB or RGBA, each row Up-filtered (the difference to the row above,
mod 256), deflate with Huffman coding only. Any PNG reader gets the same pixels (tests/service).
"""

from __future__ import annotations

import mmap
import struct
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np

BAND_ROWS = 64  # ~5 ms of encoding per band at 1280 px colour
_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_COLOUR_TYPE = {1: 0, 3: 2, 4: 6}  # grey, RGB, RGBA


def held_buffer(shape: tuple[int, ...]) -> np.ndarray:
    """A zeroed uint8 array in an anonymous mapping of its own, outside malloc's heap, for a picture a writer
    thread holds across cycles (written band by band between them). Held in the heap such a buffer splits the
    heap the cycles allocate from, and glibc grows it under a later cycle, whose measurement then faults the new
    pages in (docs/benchmarks.md, ninth round). Its own mapping is faulted in by the writer's thread and goes
    back whole when the array is freed."""
    count = int(np.prod(shape))
    return np.frombuffer(mmap.mmap(-1, max(count, 1)), np.uint8, count).reshape(shape)


def held_copy(image: np.ndarray) -> np.ndarray:
    """`image` (uint8) copied into a held_buffer."""
    held = held_buffer(image.shape)
    held[...] = image
    return held


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def write_png_in_bands(path: Path, image: np.ndarray, pause: Callable[[], None]) -> None:
    """`image` (H x W grey or H x W x 3/4 BGR(A), uint8) to `path` as PNG; `pause()` runs before each band.
    ValueError for other images; OSError if the file cannot be written."""
    image = np.asarray(image)
    channels = 1 if image.ndim == 2 else (image.shape[2] if image.ndim == 3 else 0)
    if image.dtype != np.uint8 or channels not in _COLOUR_TYPE or image.shape[0] == 0 or image.shape[1] == 0:
        raise ValueError(f"PNG bands: an 8-bit grey, BGR or BGRA image, got {image.dtype} {image.shape}")
    height, width = image.shape[:2]
    order = [2, 1, 0, 3][:channels] if channels >= 3 else [0]  # PNG stores RGB(A)
    # Each band's rows are put into PNG's channel order as the band is written, not the whole image before the
    # first band: that copy (~11 ms for the image log's 1024 x 3400 overlay, most of it faulting in a buffer of
    # the image's size) ran in one piece, beside the next cycle if a trigger came meanwhile. The caller holds
    # `image` meanwhile (a frame of the journaled cycle, or a held_copy). The band's buffers, the previous band's
    # last row and the filtered band lie outside the heap: they are held while the writer pauses for a cycle.
    raw = held_buffer((BAND_ROWS, width * channels))
    above = held_buffer((width * channels,))  # the last row of the band before (its Up filter's row above)
    buffer = held_buffer((BAND_ROWS, width * channels + 1))
    header = struct.pack(">IIBBBBB", width, height, 8, _COLOUR_TYPE[channels], 0, 0, 0)
    deflate = zlib.compressobj(1, zlib.DEFLATED, 15, 9, zlib.Z_HUFFMAN_ONLY)
    with open(path, "wb") as out:
        out.write(_SIGNATURE + _chunk(b"IHDR", header))
        for top in range(0, height, BAND_ROWS):
            pause()
            source = image[top : top + BAND_ROWS]
            rows = len(source)
            band = raw[:rows]
            pixels = band.reshape(rows, width, channels)
            for channel, index in enumerate(order):
                pixels[..., channel] = source[..., index] if channels >= 3 else source.reshape(rows, width)
            filtered = buffer[:rows]
            filtered[:, 0] = 2  # Up: each byte minus the one above it (zero above the first row)
            filtered[:, 1:] = band
            filtered[1:, 1:] -= band[:-1]
            if top > 0:
                filtered[0, 1:] -= above
            above[...] = band[-1]
            data = deflate.compress(filtered.tobytes())
            if data:
                out.write(_chunk(b"IDAT", data))
        out.write(_chunk(b"IDAT", deflate.flush()) + _chunk(b"IEND", b""))
