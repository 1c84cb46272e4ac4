"""A one-line progress bar on stderr for long command-line runs.

Hand-written because the only thing needed is a redrawn line; tqdm would be a new dependency.
On a terminal the line is redrawn in place; in a log (not a terminal) each step is one line.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO


class ProgressBar:
    """Counts steps of known number: `advance(label)` starts the next one, `finish()` ends."""

    def __init__(self, total: int, stream: TextIO | None = None, width: int = 24) -> None:
        if total < 1:
            raise ValueError(f"a progress bar needs at least one step, got {total}")
        self.total = total
        self.done = 0
        self._started = False
        self._stream = stream if stream is not None else sys.stderr
        self._width = width
        self._tty = self._stream.isatty()
        self._t0 = time.perf_counter()

    def advance(self, label: str) -> None:
        """The previous step (if any) is done; show the step now running."""
        if self._started:
            self.done = min(self.done + 1, self.total)
        self._started = True
        self._draw(label)

    def finish(self) -> None:
        """All steps are done: draw the full bar with the elapsed time and end the line."""
        self.done = self.total
        self._draw(f"done in {time.perf_counter() - self._t0:.1f} s")
        if self._tty:
            self._stream.write("\n")
            self._stream.flush()

    def _draw(self, label: str) -> None:
        filled = self._width * self.done // self.total
        line = f"[{'#' * filled}{'.' * (self._width - filled)}] {self.done}/{self.total} {label}"
        if self._tty:
            self._stream.write("\r\033[K" + line)  # \033[K clears what a longer previous line left
        else:
            self._stream.write(line + "\n")
        self._stream.flush()
