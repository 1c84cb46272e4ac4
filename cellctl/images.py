"""Image conversions used across the package, written once (grey and BGR views of camera images), and
reading image files with their size checked before they are decoded."""

from __future__ import annotations

import os
import struct
from pathlib import Path
from typing import BinaryIO

import cv2
import numpy as np


def grey(image: np.ndarray) -> np.ndarray:
    """The image as one grey channel (BGR or BGRA converted; grey returned as it is)."""
    if image.ndim == 2:
        return image
    code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
    return cv2.cvtColor(image, code)


def grey_f32(image: np.ndarray) -> np.ndarray:
    """`grey` as float32, for arithmetic on grey levels."""
    return grey(image).astype(np.float32)


def bgr(image: np.ndarray) -> np.ndarray:
    """The image as three BGR channels (grey replicated; BGR returned as it is)."""
    return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image


# ---- reading image files without decoding a bomb --------------------------------------------------------
# Why the header is read by hand: OpenCV decodes the whole image before anyone can look at its size (cv2 has
# no header-only read; its own limit, OPENCV_IO_MAX_IMAGE_PIXELS, is 2^30 px and fixed when the library
# loads), so a 20000 x 20000 PNG cost 3.7 GB before a size check could refuse it. PNG (IHDR), JPEG (SOFn)
# and BMP (BITMAPINFOHEADER) keep the size at fixed, documented places of their headers.

#: Larger than any camera of this cell (1280 x 1024 = 1.3 Mpx); far below what would exhaust memory.
MAX_PIXELS = 50_000_000


def image_size(path: str | os.PathLike[str]) -> tuple[int, int] | None:
    """(width, height) from a PNG, JPEG or BMP header; None for other formats or an unreadable header."""
    with open(path, "rb") as file:
        head = file.read(32)
        if head.startswith(b"\x89PNG\r\n\x1a\n") and head[12:16] == b"IHDR":
            width, height = struct.unpack(">II", head[16:24])
            return width, height
        if head.startswith(b"BM") and len(head) >= 26:
            width, height = struct.unpack("<ii", head[18:26])
            return abs(width), abs(height)
        if head.startswith(b"\xff\xd8"):
            file.seek(2)
            return _jpeg_size(file)
    return None


def _jpeg_size(file: BinaryIO) -> tuple[int, int] | None:
    while True:
        marker = file.read(4)
        if len(marker) < 4 or marker[0] != 0xFF:
            return None
        kind, length = marker[1], struct.unpack(">H", marker[2:4])[0]
        if 0xC0 <= kind <= 0xCF and kind not in (0xC4, 0xC8, 0xCC):  # SOFn: precision, height, width
            frame = file.read(5)
            if len(frame) < 5:
                return None
            height, width = struct.unpack(">HH", frame[1:5])
            return width, height
        file.seek(length - 2, os.SEEK_CUR)


def lossy_format(path: str | os.PathLike[str]) -> str | None:
    """ "JPEG" or "WebP" when the file holds an image in a lossy format (by its magic bytes), else None."""
    with open(path, "rb") as file:
        head = file.read(12)
    if head.startswith(b"\xff\xd8\xff"):
        return "JPEG"
    if head.startswith(b"RIFF") and head[8:12] == b"WEBP":
        return "WebP"
    return None


def lossy_warning(path: str | os.PathLike[str], what: str) -> str | None:
    """A line warning that `path` (the `what`) is lossily compressed, or None: its compression smooths away the
    few grey levels of texture a black sole's top is matched on, and its blocks blur the edge (the matrix set 39000
    as JPEG at quality 90: 38 of 84 soles measured right against 44 as PNG, none wrong; 8 of the 44 refused for
    their glue heights' precision or their edges, docs/sole-benchmark.md, forty-sixth round)."""
    kind = lossy_format(path)
    if kind is None:
        return None
    return (
        f"warning: {what} {path} is a {kind}: lossy compression smooths away the fine texture the sole's top is "
        "matched on, so its surface may be refused as measured too coarsely; give the cameras' images losslessly "
        "(PNG, TIFF, BMP)"
    )


def read_image(path: str | os.PathLike[str], flags: int = cv2.IMREAD_COLOR, what: str = "image") -> np.ndarray:
    """Decode an image file; ValueError naming the problem (missing, not a file, too large, undecodable)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{what} {path} does not exist or is not a regular file")
    size = image_size(path)
    if size is not None and size[0] * size[1] > MAX_PIXELS:
        raise ValueError(
            f"{what} {path} is {size[0]}x{size[1]} px, larger than any camera image ({MAX_PIXELS / 1e6:.0f} Mpx "
            "at most): wrong file?"
        )
    image = cv2.imread(str(path), flags)
    if image is None:
        raise ValueError(f"{what} {path} cannot be read as an image (PNG, BMP, JPEG, TIFF...)")
    return image
