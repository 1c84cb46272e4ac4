"""The artifact writer: people-work only while the service is idle, the newest cycles first, never lost at stop."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from cellctl.cameras.base import StereoFrame
from cellctl.service.artifacts import MAX_PENDING, ArtifactJob, ArtifactWriter
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
            job.folder.mkdir(parents=True, exist_ok=True)
            (job.folder / f"cycle-{job.cycle}.ply").write_text("ply")
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
