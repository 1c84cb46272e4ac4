"""Replay cameras: stereo pairs from a directory (left_NN.png / right_NN.png), in turn, for trials and support."""

from __future__ import annotations

import time
from pathlib import Path

from cellctl.calib.pairs import find_pairs
from cellctl.cameras.base import CameraMissing, StereoFrame
from cellctl.images import read_image


class ReplayCameras:
    """A FrameSource that serves the pairs of a directory one after the other, wrapping round."""

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)
        self._next = 0

    def pairs(self) -> list[tuple[Path, Path]]:
        """The (left, right) files of the directory, in natural order of their NN (as `cellctl calibrate` reads them)."""
        if not self.directory.is_dir():
            raise CameraMissing(f"replay directory {self.directory} does not exist")
        try:
            files = find_pairs(self.directory)
        except ValueError:
            files = []
        found = [(f.left, f.right) for f in files if f.left is not None and f.right is not None]
        if not found:
            raise CameraMissing(f"replay directory {self.directory} holds no left_NN.png/right_NN.png pair")
        return found

    def open(self) -> None:
        self.pairs()

    def grab_pair(self, not_before: float | None = None) -> StereoFrame:
        """The next stored pair, stamped now (so always after not_before), with its mean where the folder holds one
        (meanleft_NN.png / meanright_NN.png, as the image log writes them: the cycle's exposures averaged)."""
        pairs = self.pairs()
        left_path, right_path = pairs[self._next % len(pairs)]
        self._next += 1
        means = [path.with_name(f"mean{path.name}") for path in (left_path, right_path)]
        try:
            left, right = read_image(left_path, what="replay image"), read_image(right_path, what="replay image")
            averaged = None
            if all(path.is_file() for path in means):
                averaged = read_image(means[0], what="replay image"), read_image(means[1], what="replay image")
        except (OSError, ValueError) as exc:
            raise CameraMissing(f"replay pair {left_path.name}/{right_path.name}: {exc}") from None
        now = time.monotonic()
        info = {"backend": "replay", "left": str(left_path), "right": str(right_path)}
        return StereoFrame(left, right, now, now, info, averaged)

    def grab_exposures(self, count: int, not_before: float | None = None) -> list[StereoFrame]:
        """The next stored pair alone: a stored pair is one exposure (with its stored mean, if any)."""
        return [self.grab_pair(not_before)]

    def grab_further(self, count: int) -> list[StereoFrame]:
        """None: a stored pair has no further exposures."""
        return []

    def close(self) -> None:
        pass
