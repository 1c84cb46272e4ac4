"""Calibration captures on disk: left_NN / right_NN image pairs in a folder."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

IMAGE_EXTENSIONS: tuple[str, ...] = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


@dataclass(frozen=True)
class PairFiles:
    """The two image files of one capture."""

    name: str  # the NN of left_NN.png / right_NN.png
    left: Path | None
    right: Path | None


def find_pairs(directory: str | os.PathLike[str]) -> list[PairFiles]:
    """The left_NN / right_NN image pairs in `directory`, in natural order of NN."""
    folder = Path(directory)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder} is not a directory of left_NN.png / right_NN.png pairs")
    found: dict[str, dict[str, Path]] = {}
    for path in folder.iterdir():
        match = re.fullmatch(r"(left|right)_(.+)", path.stem)
        if match and path.suffix.lower() in IMAGE_EXTENSIONS:
            if not path.is_file():  # a FIFO would block the image reader forever
                raise ValueError(f"{path} is not a regular image file (a FIFO, device or directory?): move it away")
            found.setdefault(match.group(2), {})[match.group(1)] = path
    if not found:
        raise ValueError(f"no left_NN.png / right_NN.png images in {folder}: capture checkerboard pairs there first")

    def natural(name: str) -> list[object]:
        return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]

    names = sorted(found, key=natural)
    return [PairFiles(name, found[name].get("left"), found[name].get("right")) for name in names]
