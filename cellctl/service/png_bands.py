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

import struct
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np

BAND_ROWS = 64  # ~5 ms of encoding per band at 1280 px colour
_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_COLOUR_TYPE = {1: 0, 3: 2, 4: 6}  # grey, RGB, RGBA


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
    if channels >= 3:  # PNG stores RGB(A)
        image = image[..., [2, 1, 0, 3][:channels]]
    rows = np.ascontiguousarray(image).reshape(height, width * channels)
    header = struct.pack(">IIBBBBB", width, height, 8, _COLOUR_TYPE[channels], 0, 0, 0)
    deflate = zlib.compressobj(1, zlib.DEFLATED, 15, 9, zlib.Z_HUFFMAN_ONLY)
    with open(path, "wb") as out:
        out.write(_SIGNATURE + _chunk(b"IHDR", header))
        for top in range(0, height, BAND_ROWS):
            pause()
            band = rows[top : top + BAND_ROWS]
            filtered = np.empty((len(band), band.shape[1] + 1), np.uint8)
            filtered[:, 0] = 2  # Up: each byte minus the one above it (zero above the first row)
            filtered[:, 1:] = band
            filtered[1:, 1:] -= band[:-1]
            if top > 0:
                filtered[0, 1:] -= rows[top - 1]
            data = deflate.compress(filtered.tobytes())
            if data:
                out.write(_chunk(b"IDAT", data))
        out.write(_chunk(b"IDAT", deflate.flush()) + _chunk(b"IEND", b""))
