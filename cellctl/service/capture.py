"""Calibration pairs from the cell's own cameras: saved as left_NN.png / right_NN.png (what `cellctl calibrate`
reads), with checkerboard detection so the person holding the board sees at once whether a pair is usable.

Used by `cellctl capture` and by the station's "capture pair" button.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from cellctl.calib.board import Checkerboard, find_corners
from cellctl.cameras.base import StereoFrame

_PAIR = re.compile(r"left_(\d+)\.png")


@dataclass(frozen=True)
class SavedPair:
    name: str  # the NN of left_NN.png / right_NN.png
    left: Path
    right: Path
    board_left: bool | None  # None: no board given, nothing detected
    board_right: bool | None
    skew_ms: float

    def describe(self) -> str:
        """One line for the person at the cell."""

        def seen(found: bool | None) -> str:
            return "-" if found is None else "found" if found else "NOT FOUND"

        usable = (
            "" if self.board_left is None else "  usable" if self.board_left and self.board_right else "  NOT usable"
        )
        return (
            f"pair {self.name}: skew {self.skew_ms:.1f} ms, board left {seen(self.board_left)}, "
            f"right {seen(self.board_right)}{usable}"
        )


def next_index(folder: Path) -> int:
    """One past the highest NN of left_NN.png in the folder (0 when empty or missing)."""
    if not folder.is_dir():
        return 0
    numbers = [int(m.group(1)) for p in folder.iterdir() if (m := _PAIR.fullmatch(p.name))]
    return max(numbers, default=-1) + 1


def save_pair(frame: StereoFrame, folder: Path, board: Checkerboard | None) -> tuple[SavedPair, np.ndarray]:
    """Write the pair as the next NN; returns what was saved and a picture with the detected corners drawn."""
    folder.mkdir(parents=True, exist_ok=True)
    name = f"{next_index(folder):02d}"
    paths = {side: folder / f"{side}_{name}.png" for side in ("left", "right")}
    for side, image in (("left", frame.left), ("right", frame.right)):
        if not cv2.imwrite(str(paths[side]), image):
            raise OSError(f"cannot write {paths[side]}: check the folder is writable")
    (left_shown, left_found), (right_shown, right_found) = (detect_board(i, board) for i in (frame.left, frame.right))
    saved = SavedPair(name, paths["left"], paths["right"], left_found, right_found, frame.skew_s * 1000.0)
    return saved, np.hstack([left_shown, right_shown])


def detect_board(image: np.ndarray, board: Checkerboard | None) -> tuple[np.ndarray, bool | None]:
    """The image with the board's corners drawn where found, and whether all were found (None: no board)."""
    shown = image.copy() if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if board is None:
        return shown, None
    corners = find_corners(image, board)
    if corners is not None:
        cv2.drawChessboardCorners(shown, board.pattern_size, corners.reshape(-1, 1, 2).astype(np.float32), True)
    return shown, corners is not None
