"""Image files: sizes read from headers, bombs refused before they are decoded (issue 15, finding 9), lossy
formats told by their magic bytes."""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.images import image_size, lossy_format, read_image


@pytest.mark.parametrize("suffix", [".png", ".jpg", ".bmp"])
def test_size_from_the_header(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"image{suffix}"
    cv2.imwrite(str(path), np.zeros((37, 53, 3), np.uint8))
    assert image_size(path) == (53, 37)
    assert read_image(path).shape == (37, 53, 3)


def test_a_png_bomb_is_refused_before_decoding(tmp_path: Path) -> None:
    path = tmp_path / "bomb.png"
    cv2.imwrite(str(path), np.zeros((8, 8), np.uint8))
    data = bytearray(path.read_bytes())
    data[16:24] = struct.pack(">II", 20000, 20000)  # what the header claims is what the decoder would allocate
    path.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="is 20000x20000 px, larger than any camera image"):
        read_image(path, what="LEFT image")


def test_unreadable_files_are_named(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="does not exist or is not a regular file"):
        read_image(tmp_path / "missing.png")
    (tmp_path / "text.png").write_text("not an image")
    with pytest.raises(ValueError, match="cannot be read as an image"):
        read_image(tmp_path / "text.png")


@pytest.mark.parametrize(
    ("suffix", "kind"), [(".png", None), (".bmp", None), (".tiff", None), (".jpg", "JPEG"), (".webp", "WebP")]
)
def test_lossy_formats_are_told_by_their_content(tmp_path: Path, suffix: str, kind: str | None) -> None:
    path = tmp_path / f"image{suffix}"
    assert cv2.imwrite(str(path), np.zeros((8, 8, 3), np.uint8))
    renamed = path.rename(tmp_path / "image.png")  # the name says PNG; the bytes decide
    assert lossy_format(renamed) == kind
