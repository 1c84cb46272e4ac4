"""The artifact writer: people-work only while the service is idle, the newest cycles first, never lost at stop."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from cellctl.cameras.base import StereoFrame
from cellctl.service.artifacts import IDLE_SETTLE_S, MAX_PENDING, ArtifactJob, ArtifactWriter
from cellctl.service.journal import CycleRecord, Journal
from cellctl.sim.rig import default_rig


class StepWriter(ArtifactWriter):
    """The real scheduling with steps that only note what ran (and write a marker file, as a step would)."""

    def __init__(self, keep: int) -> None:
        super().__init__(default_rig(), keep)
        self.ran: list[int] = []
        self.step_started = threading.Event()

    def _steps(self, job: ArtifactJob) -> list[Callable[[], None]]:
        def step() -> None:
            self.step_started.set()
            (job.staging / f"cycle-{job.cycle}.ply").write_text("ply")
            self.ran.append(job.cycle)

        return [step]


@pytest.fixture()
def journal(tmp_path: Path) -> Iterator[Journal]:
    opened = Journal.open(tmp_path / "state")
    yield opened
    opened.close()


def submit(writer: ArtifactWriter, journal: Journal, cycle: int) -> None:
    record = CycleRecord(cycle=cycle, triggered_at=0.0, status="ok", error_code=0, cycle_time_ms=1.0)
    journal.record(record)
    frame = StereoFrame(np.zeros((2, 2, 3), np.uint8), np.zeros((2, 2, 3), np.uint8), 0.0, 0.0, {})
    writer.submit(journal, record, frame, None, None)  # type: ignore[arg-type]  # the steps above use neither


def test_nothing_is_written_while_a_cycle_runs_and_all_of_it_once_idle(journal: Journal) -> None:
    writer = StepWriter(keep=3)
    writer.set_idle(False)
    submit(writer, journal, 1)
    assert not writer.step_started.wait(0.3)  # the service is busy: the job waits
    writer.set_idle(True)
    assert writer.flush(timeout_s=10.0)
    writer.attach_finished(journal)  # the daemon's thread records them
    writer.close()
    assert writer.ran == [1]
    assert [r.ply_path is not None for r in journal.last()] == [True]


def test_a_step_starts_only_once_the_service_has_waited_for_a_trigger_for_the_settling_time(
    journal: Journal,
) -> None:
    """A PLC triggering back to back comes within IDLE_SETTLE_S of the answer: no step starts in such a gap."""
    gap_s = 0.05  # a back-to-back PLC's gap between answer and trigger (10-40 ms measured in the demo)
    assert IDLE_SETTLE_S >= 2 * gap_s
    writer = StepWriter(keep=3)
    submit(writer, journal, 1)
    for _ in range(3):  # three short gaps between back-to-back cycles
        writer.set_idle(True)
        assert not writer.step_started.wait(gap_s)
        writer.set_idle(False)
    assert not writer.step_started.wait(0.4)  # busy: nothing starts however long it takes
    writer.set_idle(True)  # a gap longer than the settling time: the job is written
    assert writer.step_started.wait(10.0)
    assert writer.flush(timeout_s=10.0)
    writer.close()
    assert writer.ran == [1]


def test_idle_told_again_and_again_does_not_restart_the_settling_time(journal: Journal) -> None:
    """The daemon says idle at every tick of its wait for a trigger (0.25 s): only a cycle restarts the clock."""
    writer = StepWriter(keep=3)
    submit(writer, journal, 1)
    deadline = time.monotonic() + 10.0
    while not writer.step_started.is_set() and time.monotonic() < deadline:
        writer.set_idle(True)  # more often than IDLE_SETTLE_S
        writer.step_started.wait(IDLE_SETTLE_S / 4)
    assert writer.step_started.is_set()
    assert writer.flush(timeout_s=10.0)
    writer.close()


def test_a_busy_line_keeps_the_newest_jobs_and_drops_the_oldest(journal: Journal) -> None:
    writer = StepWriter(keep=50)
    writer.set_idle(False)
    cycles = list(range(1, MAX_PENDING + 4))
    for cycle in cycles:
        submit(writer, journal, cycle)
    assert writer.flush(timeout_s=10.0)  # at stop: whatever is pending is written
    writer.close()
    assert writer.ran == cycles[-MAX_PENDING:]
    assert writer.dropped == len(cycles) - MAX_PENDING


def test_retention_prunes_to_the_newest_cycles(journal: Journal) -> None:
    writer = StepWriter(keep=2)
    writer.set_idle(True)
    for cycle in range(1, 5):
        submit(writer, journal, cycle)
        assert writer.flush(timeout_s=10.0)
        writer.attach_finished(journal)
    writer.close()
    kept = sorted(r.cycle for r in journal.last() if r.ply_path is not None)
    assert kept == [3, 4]
    assert len(list((journal.state_dir / "cycles").iterdir())) == 2


def test_keep_zero_writes_nothing(journal: Journal) -> None:
    writer = StepWriter(keep=0)
    writer.set_idle(True)
    submit(writer, journal, 1)
    assert writer.flush(timeout_s=1.0)
    writer.close()
    assert writer.ran == []


class StuckWriter(StepWriter):
    """A writer thread that cannot finish its step until released (starved on a loaded machine)."""

    def __init__(self, keep: int) -> None:
        super().__init__(keep)
        self.release = threading.Event()
        self.stuck = threading.Event()

    def _stuck_step(self) -> None:
        self.stuck.set()
        self.release.wait(30)

    def _steps(self, job: ArtifactJob) -> list[Callable[[], None]]:
        steps = super()._steps(job)
        if threading.current_thread() is not self._thread:
            return steps  # the jobs flush writes itself
        return [self._stuck_step, *steps]


def test_a_job_the_thread_cannot_finish_by_stop_is_given_up_without_a_trace(journal: Journal) -> None:
    writer = StuckWriter(keep=5)
    writer.set_idle(True)
    submit(writer, journal, 1)
    assert writer.stuck.wait(10)  # the thread has taken the job and hangs in its first step
    writer.set_idle(False)
    submit(writer, journal, 2)  # pending: written by flush in this thread
    assert not writer.flush(timeout_s=0.2)
    writer.release.set()
    writer.close()
    writer.attach_finished(journal)
    assert sorted(writer.ran) == [1, 2]  # the thread did finish its step, later...
    kept = {r.cycle: r.ply_path for r in journal.last()}
    assert kept[1] is None and kept[2] is not None  # ...but cycle 1 was given up: no folder, no row
    assert [p.name for p in (journal.state_dir / "cycles").iterdir()] == [Path(kept[2]).parent.name]
    assert not any((journal.state_dir / "partial").iterdir())


class BandWriter(StepWriter):
    """One step in two parts with the writer's pause between them, as the overlay PNG's bands are written."""

    def __init__(self, keep: int) -> None:
        super().__init__(keep)
        self.first_part = threading.Event()
        self.go_on = threading.Event()

    def _steps(self, job: ArtifactJob) -> list[Callable[[], None]]:
        def step() -> None:
            self.first_part.set()
            self.go_on.wait(10)
            self._pause()
            self.ran.append(job.cycle)

        return [step]


def test_a_step_begun_before_a_trigger_stops_at_its_next_part_until_the_cycle_is_over(journal: Journal) -> None:
    writer = BandWriter(keep=3)
    writer.set_idle(True)
    submit(writer, journal, 1)
    assert writer.first_part.wait(10)  # the writer's thread is in the step's first part...
    writer.set_idle(False)  # ...when a trigger comes
    writer.go_on.set()
    threading.Event().wait(0.3)
    assert writer.ran == []  # held at the pause while the cycle runs
    writer.set_idle(True)
    assert writer.flush(timeout_s=10.0)
    writer.close()
    assert writer.ran == [1]


def test_the_overlay_png_is_written_in_bands_with_a_pause_before_each(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import cv2

    import cellctl.service.artifacts as artifacts
    from cellctl.service.png_bands import BAND_ROWS

    calib = default_rig()
    width, height = calib.image_size
    left = np.random.default_rng(0).integers(0, 256, (height, width, 3), np.uint8)
    frame = StereoFrame(left, left, 0.0, 0.0, {})
    job = ArtifactJob(1, 1, tmp_path / "cycles" / "1", frame, None, None)  # type: ignore[arg-type]
    job.staging.mkdir(parents=True)
    pauses: list[int] = []
    drawn = left[::-1].copy()  # the overlay as drawn (the drawing itself is tested with the overlay module)
    monkeypatch.setattr(artifacts, "draw_on_left", lambda image, calib, measurement: drawn)
    *_, draw, write_png = artifacts.artifact_steps(job, calib, lambda: pauses.append(1))
    draw()
    write_png()
    assert len(pauses) == -(-height // BAND_ROWS)
    assert np.array_equal(cv2.imread(str(job.staging / "cycle-1-overlay.png")), drawn)
