"""The image log: the raw pair and the overlay of every failed cycle (and every Nth good one), kept for people.

    log = ImageLog(state_dir / "images", calib, ImageLogConfig(every_nth_good=10))
    daemon.events.subscribe(log.on_event)

One flat folder, one entry per journaled cycle, named by the journal's row id:

    left_00000042.png  right_00000042.png     the raw pair as grabbed (lossless), the cycle's last exposure
    meanleft_00000042.png  meanright_00000042.png   the mean of the cycle's exposures, where it averaged several
                                              (cellctl.cameras.averaging: the sole's surface was fitted on them)
    overlay_00000042.png                      what the operator saw (the `cellctl measure --png` picture)
    meta_00000042.json                        cycle, status, error code, reason, time

so the folder is itself a replay set: `backend = "replay"` with `replay_dir` pointing here serves the pairs in
turn (with their means), and `cellctl measure --calib CAL left_00000042.png right_00000042.png --mean
meanleft_00000042.png meanright_00000042.png` measures one again as the cycle did. Retention
keeps the newest `keep_cycles` entries and at most `max_mb` on disk, oldest removed first.
"""

from __future__ import annotations

import json
import logging
import queue
import re
import threading
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from cellctl.cameras.base import StereoFrame
from cellctl.service.config import ImageLogConfig
from cellctl.service.cycle import Measured
from cellctl.service.events import CellEvent, CellState, CycleDone
from cellctl.service.journal import CycleRecord
from cellctl.service.png_bands import held_copy, write_png_in_bands
from cellctl.vision.calibration import Calibration
from cellctl.vision.overlay import draw_overlay, draw_refused

log = logging.getLogger(__name__)

QUEUE_LIMIT = 8  # cycles waiting to be written; beyond, pictures are dropped (with a warning)
BUSY_WAIT_S = 5.0  # longest a step waits for the daemon to finish a cycle
SET_UP_WAIT_S = 5.0  # longest the log's creation waits for its writer's set-up (~25 ms; a loaded host, far more)
KINDS = ("left", "right", "meanleft", "meanright", "overlay", "meta")  # the files of an entry (any may be missing)
_ENTRY = re.compile(rf"({'|'.join(KINDS)})_(\d{{8}})\.(png|json)")
# Lossless and fast (see service.artifacts); the log is written after the PLC has its answer.
PNG_FAST = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY]


@dataclass(frozen=True)
class LoggedCycle:
    """The files of one logged cycle (any may be missing after a crash or a manual clean-up)."""

    row_id: int
    folder: Path

    def path(self, kind: str) -> Path:
        return self.folder / f"{kind}_{self.row_id:08d}.{'json' if kind == 'meta' else 'png'}"

    def meta(self) -> dict[str, object]:
        try:
            return dict(json.loads(self.path("meta").read_text(encoding="utf-8")))
        except (OSError, ValueError):
            return {}


class ImageLog:
    """Writes and prunes the image log folder, in a writer thread of its own: drawing the overlay and writing
    three PNGs takes ~0.2-0.4 s at 1280x1024, which the next trigger must not wait for."""

    def __init__(self, folder: Path, calib: Calibration | None, config: ImageLogConfig) -> None:
        self.folder = folder
        self.calib = calib
        self.config = config
        self._good_seen = 0
        self._queue: queue.Queue[CycleDone] = queue.Queue(maxsize=QUEUE_LIMIT)
        self._writer: threading.Thread | None = None
        self._pending = 0  # queued and not yet written
        self._written = threading.Condition()
        self._busy = False  # the daemon is measuring (its CellState): the writer starts no step meanwhile
        self._set_up = threading.Event()
        if config.keep_cycles > 0:
            self._start_writer()
            # Returned only once the thread has set up its drawing (set_up_text, ~25 ms while the service starts):
            # a process that ends meanwhile (e.g. a journal it cannot open) would end inside OpenCV's set-up on
            # that thread, and C++ aborts the process (seen: "terminate called without an active exception").
            self._set_up.wait(SET_UP_WAIT_S)

    def _start_writer(self) -> None:
        self._writer = threading.Thread(target=self._write_queued, name="image-log", daemon=True)
        self._writer.start()

    def on_event(self, event: CellEvent) -> None:
        """Subscriber for Daemon.events: queues the cycles the config asks for (never blocks the cycle), and
        follows the daemon's phase so that the writer works between cycles."""
        if isinstance(event, CellState):
            with self._written:
                self._busy = event.phase == "busy"
                self._written.notify_all()
            return
        if not (isinstance(event, CycleDone) and event.frame is not None and self.wants(event.record)):
            return
        if self._writer is None:
            self._start_writer()
        try:
            with self._written:
                self._queue.put_nowait(event)
                self._pending += 1
        except queue.Full:  # the disk cannot keep up: lose a picture, never delay the line
            log.warning("cycle %d: image log behind by %d cycles, not logged", event.record.cycle, QUEUE_LIMIT)

    def wait_written(self, timeout_s: float = 30.0) -> bool:
        """True once every queued cycle is on disk (for tests and an orderly stop)."""
        with self._written:
            return self._written.wait_for(lambda: self._pending == 0, timeout_s)

    def _write_queued(self) -> None:
        try:
            set_up_text()
        finally:
            self._set_up.set()
        while True:
            event = self._queue.get()
            try:
                assert event.frame is not None
                self.write(event.record, event.frame, event.measured)
            finally:
                with self._written:
                    self._pending -= 1
                    self._written.notify_all()

    def wants(self, record: CycleRecord) -> bool:
        if self.config.keep_cycles == 0 or record.id is None:
            return False
        if record.status != "ok":
            return True
        self._good_seen += 1
        nth = self.config.every_nth_good
        return nth > 0 and self._good_seen % nth == 0

    def write(self, record: CycleRecord, frame: StereoFrame, measured: Measured | None) -> LoggedCycle | None:
        """The pair, overlay and meta of one cycle, then prune; a failure is logged, never raised."""
        assert record.id is not None
        entry = LoggedCycle(record.id, self.folder)
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            # Each step (a PNG, the overlay: ~0.1 s each) starts only between cycles: written beside a cycle
            # on 2 cores, the three took ~0.3 s off the next cycle (every 10th good cycle was the slowest).
            # The overlay's drawing waits between its parts too (draw_overlay's pause): drawn whole, begun
            # just before a trigger, it ran beside the next cycle's first stages (120 ms of CPU seen).
            steps = [("left", lambda: frame.left), ("right", lambda: frame.right)]
            if (averaged := frame.averaged) is not None:
                steps += [("meanleft", lambda: averaged[0]), ("meanright", lambda: averaged[1])]
            # The overlay held into its bands.
            steps.append(("overlay", lambda: held_copy(self._overlay(record, frame, measured))))
            for kind, picture in steps:
                self._wait_between_cycles()
                image = picture()
                if image.dtype == np.uint8:
                    # In bands of rows, waiting before each: a PNG begun just before a trigger holds the next
                    # cycle back by one band (~5 ms), not by the whole write (~70 ms; cellctl.service.png_bands).
                    write_png_in_bands(entry.path(kind), image, self._wait_between_cycles)
                    continue
                self._wait_between_cycles()
                if not cv2.imwrite(str(entry.path(kind)), image, PNG_FAST):
                    raise OSError(f"cannot write {entry.path(kind)}")
            meta = {
                "row_id": record.id,
                "cycle": record.cycle,
                "triggered_at": record.triggered_at,
                "status": record.status,
                "error_code": record.error_code,
                "reason": record.reason,
            }
            entry.path("meta").write_text(json.dumps(meta), encoding="utf-8")
        except OSError as exc:
            log.warning("cycle %d: image log not written: %s", record.cycle, exc)
            return None
        self.prune()
        return entry

    def _wait_between_cycles(self) -> None:
        """Until the daemon is not measuring (at most BUSY_WAIT_S: a picture is never held back for long)."""
        with self._written:
            self._written.wait_for(lambda: not self._busy, BUSY_WAIT_S)

    def _overlay(self, record: CycleRecord, frame: StereoFrame, measured: Measured | None) -> np.ndarray:
        if measured is not None and self.calib is not None:
            return draw_overlay(
                frame.left, self.calib, measured.reconstruction, measured.measurement, self._wait_between_cycles
            )
        return draw_refused(frame.left, f"cycle {record.cycle}: error {record.error_code}: {record.reason}")

    def entries(self) -> list[LoggedCycle]:
        """Logged cycles, oldest first."""
        if not self.folder.is_dir():
            return []
        ids = {int(m.group(2)) for p in self.folder.iterdir() if (m := _ENTRY.fullmatch(p.name))}
        return [LoggedCycle(i, self.folder) for i in sorted(ids)]

    def find(self, row_id: int) -> LoggedCycle | None:
        entry = LoggedCycle(row_id, self.folder)
        return entry if entry.path("left").is_file() or entry.path("overlay").is_file() else None

    def prune(self) -> int:
        """Remove the oldest entries beyond keep_cycles or max_mb; returns how many went."""
        entries = self.entries()
        sizes = [sum(_size(e.path(k)) for k in KINDS) for e in entries]
        total, budget = sum(sizes), self.config.max_mb * 1e6
        removed = 0
        for entry, size in zip(entries, sizes):
            if len(entries) - removed <= self.config.keep_cycles and total <= budget:
                break
            for kind in KINDS:
                entry.path(kind).unlink(missing_ok=True)
            total -= size
            removed += 1
        return removed


def set_up_text() -> None:
    """Write a character once in the calling thread. OpenCV sets up its fonts per thread, at the thread's first
    cv2.putText (~22 ms of CPU, measured; a second thread pays it again): otherwise the image log's first overlay
    paid it in the piece drawn between two cycles, which then ran beside the next cycle (26 ms of the writer's
    CPU inside one demo cycle)."""
    cv2.putText(np.zeros((16, 16, 3), np.uint8), "0", (0, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1)


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0
