"""What a cycle leaves for people and robot tools: the sole's cloud as PLY with normals, the glue path as CSV
and PLY polyline (table frame, cellctl.vision.export), and the left image with the glue path drawn.

Written after the PLC has its answer, and only while the service is idle: the PLC may trigger again as
soon as it has read a result, and on 2 cores artifacts written beside a cycle slowed its match by as much
as they saved (docs/sole-benchmark.md). So `ArtifactWriter` keeps the newest few cycles' jobs and a
writer thread writes them step by step, each step started only once the service has waited IDLE_SETTLE_S
for a trigger (a PLC triggering back to back does so sooner); jobs that a busy line never leaves time for are
dropped, oldest first (counted and logged). At stop the daemon's own
thread writes what is still pending. Files go to a staging folder renamed into state_dir/cycles/<row> when
complete, so a job given up at stop leaves nothing behind. The journal is only touched from the daemon's
thread (`attach_finished`, commits without an fsync of their own: cellctl.service.journal), as SQLite
connections belong to one thread. A failure here is logged and never
fails a cycle.
"""

from __future__ import annotations

import collections
import logging
import math
import shutil
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cellctl.cameras.base import StereoFrame
from cellctl.service.journal import CycleRecord, Journal
from cellctl.service.png_bands import held_copy, write_png_in_bands
from cellctl.vision.calibration import Calibration
from cellctl.vision.export import cloud_normals, write_cloud_ply, write_glue_csv, write_glue_ply
from cellctl.vision.measurement import SoleMeasurement
from cellctl.vision.overlay import draw_on_left
from cellctl.vision.reconstruction import Reconstruction

log = logging.getLogger(__name__)

MAX_PENDING = 4  # jobs kept waiting for idle time (each holds a frame pair and the sole's points, ~10 MB)
#: How long the service must have been waiting for a trigger before a step starts. A step runs whole (the PLY
#: with its normals, the overlay's drawing: 25-120 ms), so one begun just before a trigger runs beside the next
#: cycle's first stages and takes a core from its match. A PLC whose next shoe is already waiting triggers
#: within a few of its scans after reading the answer (10-40 ms measured in the back-to-back demo, median
#: 25-35), and then 40 of 120 cycles had a step beside them (their match +50 %, docs/benchmarks.md); a line whose
#: robot glues the shoe before the next trigger leaves seconds. 0.2 s lies between, with ~5x margin either way;
#: back-to-back, the jobs wait (the newest MAX_PENDING are written at stop).
IDLE_SETTLE_S = 0.2
# The writer thread keeps normal priority: a niced thread that holds the GIL (Open3D's PLY writer, numpy)
# and is then starved by the scheduler blocks the daemon's thread behind it (seen at load 20: cycles over
# the PLC link's 5 s liveness). Starting steps only while idle is what keeps it out of the cycles.


@dataclass(frozen=True)
class ArtifactJob:
    """One cycle's artifacts to write: everything needed, nothing shared with the next cycle."""

    row_id: int
    cycle: int
    folder: Path
    frame: StereoFrame
    reconstruction: Reconstruction
    measurement: SoleMeasurement

    @property
    def staging(self) -> Path:
        """Where the files are written first: the cycle's folder appears whole (renamed) or not at all."""
        return self.folder.parent.parent / "partial" / self.folder.name

    def move_into_place(self) -> bool:
        """Rename the written staging folder to the cycle's folder; False (logged) if that fails."""
        try:
            self.folder.parent.mkdir(parents=True, exist_ok=True)
            shutil.rmtree(self.folder, ignore_errors=True)
            self.staging.rename(self.folder)
        except OSError as exc:
            log.warning("cycle %d: artifacts not kept: %s", self.cycle, exc)
            return False
        return True


@dataclass(frozen=True)
class WrittenArtifacts:
    row_id: int
    cycle: int
    ply: Path
    overlay: Path


class ArtifactWriter:
    """Writes artifact jobs on its thread while `idle` is set; the daemon owns the journal side."""

    def __init__(self, calib: Calibration, keep: int) -> None:
        self.calib = calib
        self.keep = keep
        self.dropped = 0
        self._pending: collections.deque[ArtifactJob] = collections.deque()
        self._finished: collections.deque[WrittenArtifacts] = collections.deque()
        self._lock = threading.Lock()
        self._work = threading.Condition(self._lock)
        self._idle = False  # the service waits for a trigger: the writer may work once it has for IDLE_SETTLE_S
        self._idle_since = 0.0  # time.monotonic() when the service began waiting (-inf at stop: no settling)
        self._closing = False
        self._writing = False
        self._abandon = False  # the thread's job in progress was given up at stop: discard it
        self._thread: threading.Thread | None = None

    # ---- the daemon's side ------------------------------------------------------------------------

    def submit(
        self,
        journal: Journal,
        record: CycleRecord,
        frame: StereoFrame,
        result: Reconstruction,
        measurement: SoleMeasurement,
    ) -> None:
        """Queue a measured cycle's artifacts (nothing is written now)."""
        if self.keep == 0 or record.id is None:
            return
        job = ArtifactJob(record.id, record.cycle, journal.artifact_dir(record.id), frame, result, measurement)
        with self._work:
            self._pending.append(job)
            limit = min(self.keep, MAX_PENDING)
            while len(self._pending) > limit:
                old = self._pending.popleft()
                self.dropped += 1
                log.info("cycle %d: artifacts skipped, no idle time before newer cycles", old.cycle)
            self._start()
            self._work.notify_all()

    def set_idle(self, idle: bool) -> None:
        """Whether the service waits for a trigger (the writer works) or runs a cycle (the writer waits)."""
        with self._work:
            if idle and not self._idle:
                self._idle_since = time.monotonic()
            self._idle = idle
            self._work.notify_all()

    def attach_finished(self, journal: Journal) -> None:
        """Record written artifacts in the journal and prune old ones (daemon thread, idle time)."""
        while True:
            with self._lock:
                if not self._finished:
                    return
                done = self._finished.popleft()
            try:
                journal.attach_artifacts(done.row_id, done.ply, done.overlay)
                journal.prune_artifacts(self.keep)
            except Exception as exc:
                log.warning("cycle %d: artifacts not recorded: %s", done.cycle, exc)

    def flush(self, timeout_s: float) -> bool:
        """At stop: write the pending jobs in the calling thread, then wait for the thread's job in progress;
        False (and that job given up) if it does not end within `timeout_s`."""
        with self._work:
            jobs = list(self._pending)
            self._pending.clear()
            self._idle, self._idle_since = True, -math.inf
            self._work.notify_all()
        for job in jobs:
            self._finish(job, self._write(job, wait_idle=False))
        with self._work:
            done = self._work.wait_for(lambda: not self._writing, timeout_s)
            self._abandon = not done
            return done

    def close(self) -> None:
        with self._work:
            self._closing = True
            self._work.notify_all()
        if self._thread is not None:
            self._thread.join(5.0)

    # ---- the writer thread --------------------------------------------------------------------------

    def _start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="artifact writer", daemon=True)
            self._thread.start()

    def _run(self) -> None:
        while True:
            with self._work:
                self._wait_settled(lambda: bool(self._pending))
                if self._closing:
                    return
                job = self._pending.popleft()
                self._writing = True
            self._finish(job, self._write(job, wait_idle=True))

    def _finish(self, job: ArtifactJob, written: WrittenArtifacts | None) -> None:
        """Publish a written job (its folder renamed into place) unless it was given up at stop."""
        with self._work:
            mine = threading.current_thread() is self._thread
            if written is not None and not (mine and self._abandon) and job.move_into_place():
                self._finished.append(written)
            shutil.rmtree(job.staging, ignore_errors=True)
            if mine:
                self._writing = False
            self._work.notify_all()

    def _write(self, job: ArtifactJob, wait_idle: bool) -> WrittenArtifacts | None:
        """The job's steps into its staging folder, each started only while the service is idle (wait_idle)."""
        try:
            job.staging.mkdir(parents=True, exist_ok=True)
            for step in self._steps(job):
                if wait_idle:
                    with self._work:
                        self._wait_settled()
                step()
        except Exception as exc:
            log.warning("cycle %d: artifacts not kept: %s", job.cycle, exc)
            return None
        return WrittenArtifacts(job.row_id, job.cycle, *_paths(job, job.folder))

    def _steps(self, job: ArtifactJob) -> list[Callable[[], None]]:
        """What is written, as short steps (tests replace them to see the scheduling alone)."""
        return artifact_steps(job, self.calib, self._pause)

    def _pause(self) -> None:
        """Within a step, between its parts: the writer's thread waits while a cycle runs (flush's caller,
        writing at stop, does not)."""
        if threading.current_thread() is self._thread:
            with self._work:
                self._wait_settled()

    def _wait_settled(self, ready: Callable[[], bool] = lambda: True) -> None:
        """Until `ready()` and the service has waited for a trigger for IDLE_SETTLE_S, or closing (lock held)."""
        while not self._closing:
            if self._idle and ready():
                left = self._idle_since + IDLE_SETTLE_S - time.monotonic()
                if left <= 0:
                    return
                self._work.wait(left)
            else:
                self._work.wait()


def artifact_steps(
    job: ArtifactJob, calib: Calibration, pause: Callable[[], None] = lambda: None
) -> list[Callable[[], None]]:
    """A job's files as short steps (tens of ms each), into its staging folder: a trigger arriving meanwhile runs
    beside at most one of them. The overlay's PNG, the longest (60-70 ms of CPU on the cell PC, up to 320 ms in
    the loaded demo), is written in bands of rows with `pause()` before each (cellctl.service.png_bands), so it
    stops within a band (~5 ms) of a trigger instead of running beside the next cycle's match."""
    ply, overlay = _paths(job, job.staging)
    picture: list[np.ndarray] = []

    def write_ply() -> None:
        points = job.reconstruction.sole_points
        colours = job.reconstruction.sole_colors[:, ::-1]
        write_cloud_ply(ply, points, cloud_normals(points), colours, frame="table")

    def write_glue() -> None:
        path, folder = job.measurement.glue_path, ply.parent
        write_glue_csv(folder / f"cycle-{job.cycle}-glue.csv", path.points, path.normals)
        write_glue_ply(folder / f"cycle-{job.cycle}-glue.ply", path.points, path.normals, "table", path.closed)

    def draw() -> None:
        picture.append(held_copy(draw_on_left(job.frame.left, calib, job.measurement)))  # held into the PNG's bands

    def write_png() -> None:
        write_png_in_bands(overlay, picture[0], pause)

    return [write_ply, write_glue, draw, write_png]


def _paths(job: ArtifactJob, folder: Path) -> tuple[Path, Path]:
    return folder / f"cycle-{job.cycle}.ply", folder / f"cycle-{job.cycle}-overlay.png"


def finish_artifacts(writer: ArtifactWriter, journal: Journal, timeout_s: float = 10.0) -> None:
    """At stop: write what is pending (flush), record it in the journal, end the writer's thread."""
    if not writer.flush(timeout_s):
        log.warning("stopping with artifacts not written")
    writer.attach_finished(journal)
    writer.close()
    if writer.dropped:
        log.info("artifacts of %d cycles skipped for lack of idle time", writer.dropped)
