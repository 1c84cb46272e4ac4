"""The cycle journal: durable rows that survive reopening, artifact retention, and `cellctl results`."""

from __future__ import annotations

import csv
import io
import json
from datetime import datetime
from pathlib import Path

import pytest

from cellctl.cli import main
from cellctl.service.journal import CycleRecord, Journal, WalCheckpointer


def ok(cycle: int) -> CycleRecord:
    return CycleRecord(
        cycle=cycle,
        triggered_at=1_700_000_000.0 + cycle,
        status="ok",
        error_code=0,
        cycle_time_ms=800.0 + cycle,
        length_mm=270.5,
        heel_height_mm=30.25,
        toe_height_mm=12.5,
        timings={"match": 0.5},
        glue_path=[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]],
        source={"backend": "simulated", "seed": cycle},
    )


def failed(cycle: int) -> CycleRecord:
    return CycleRecord(
        cycle=cycle,
        triggered_at=1_700_000_100.0,
        status="error",
        error_code=10,
        cycle_time_ms=1.5,
        reason="left camera unplugged",
    )


def test_rows_survive_reopening_and_keep_their_values(tmp_path: Path) -> None:
    journal = Journal.open(tmp_path)
    first = journal.record(ok(1))
    journal.record(failed(2))
    journal.close()  # the service stops...
    again = Journal.open(tmp_path)  # ...and starts again
    again.record(ok(3))
    records = again.last()
    assert [r.cycle for r in records] == [1, 2, 3]
    assert records[0].id == first and records[0].glue_path == [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]
    assert records[0].source == {"backend": "simulated", "seed": 1}
    assert records[1].error_code == 10 and records[1].length_mm is None and records[1].reason == "left camera unplugged"
    assert [r.cycle for r in again.last(2)] == [2, 3]
    assert again.find(3).heel_height_mm == 30.25 and again.find(99) is None
    mode = again._db.execute("PRAGMA journal_mode").fetchone()[0]
    assert mode == "wal"


def test_artifacts_beyond_the_retention_limit_are_deleted(tmp_path: Path) -> None:
    journal = Journal.open(tmp_path)
    for cycle in range(1, 6):
        row = journal.record(ok(cycle))
        folder = journal.artifact_dir(row)
        folder.mkdir(parents=True)
        (folder / "sole.ply").write_text("ply")
        journal.attach_artifacts(row, folder / "sole.ply", None)
    assert journal.prune_artifacts(keep=2) == 3
    kept = [r for r in journal.last() if r.ply_path is not None]
    assert [r.cycle for r in kept] == [4, 5]
    assert sorted(p.name for p in (tmp_path / "cycles").iterdir()) == ["00000004", "00000005"]
    assert len(journal.last()) == 5  # rows are all kept
    assert journal.prune_artifacts(keep=2) == 0


def test_artifact_folders_no_row_refers_to_are_pruned_at_start(tmp_path: Path) -> None:
    journal = Journal.open(tmp_path)
    kept = journal.record(ok(1))
    journal.artifact_dir(kept).mkdir(parents=True)
    (journal.artifact_dir(kept) / "sole.ply").write_text("ply")
    journal.attach_artifacts(kept, journal.artifact_dir(kept) / "sole.ply", None)
    # kill -9 while writing (a staging folder left), and between a rename and its commit (unreferenced folder):
    (tmp_path / "partial" / "00000002").mkdir(parents=True)
    journal.artifact_dir(99).mkdir(parents=True)
    journal.close()
    again = Journal.open(tmp_path)
    assert again.prune_orphans() == 2
    assert [p.name for p in (tmp_path / "cycles").iterdir()] == [journal.artifact_dir(kept).name]
    assert not any((tmp_path / "partial").iterdir())
    assert (journal.artifact_dir(kept) / "sole.ply").is_file()


def test_last_cycle_survives_a_restart(tmp_path: Path) -> None:
    assert Journal.open(tmp_path).last_cycle() == 0
    journal = Journal.open(tmp_path)
    for cycle in (7, 8):
        journal.record(ok(cycle))
    journal.close()
    assert Journal.open(tmp_path).last_cycle() == 8


def test_results_command_text_json_csv(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    journal = Journal.open(tmp_path)
    for record in (ok(1), failed(2), ok(3)):
        journal.record(record)
    journal.close()
    assert main(["results", "--state-dir", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 3 and "cycle 2: error 10 (left camera unplugged)" in lines[1]
    assert "length=270.50 heel=30.25 toe=12.50 mm points=2" in lines[0]
    assert main(["results", "--state-dir", str(tmp_path), "--json", "--last", "2"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert [d["cycle"] for d in data] == [2, 3] and data[1]["glue_path"][1] == [4.0, 5.0, 6.0]
    assert datetime.fromisoformat(data[1]["triggered_at"]).timestamp() == pytest.approx(1_700_000_003.0)
    assert main(["results", "--state-dir", str(tmp_path), "--csv"]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert [r["status"] for r in rows] == ["ok", "error", "ok"] and rows[0]["glue_points"] == "2"
    assert datetime.fromisoformat(rows[0]["triggered_at"]).utcoffset() is not None


def test_results_without_a_journal_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["results", "--state-dir", str(tmp_path / "none")]) == 2
    assert "no journal at" in capsys.readouterr().err


def big(cycle: int) -> CycleRecord:
    """A row of ~60 KB (a 2000-point glue path, the PLC's maximum): ~15 WAL pages."""
    record = ok(cycle)
    record.glue_path = [[100.0 + i / 7, 50.0 - i / 3, 20.0 + i / 11] for i in range(2000)]
    return record


def test_with_a_checkpointer_no_commit_checkpoints_the_wal_and_the_thread_does_between_cycles(tmp_path: Path) -> None:
    journal = Journal.open(tmp_path)
    database = tmp_path / "journal.sqlite3"
    checkpoints = WalCheckpointer(journal, every=1000)  # none due while the WAL grows past SQLite's 1000 pages
    start = database.stat().st_size
    for cycle in range(1, 91):  # ~1350 WAL pages: SQLite's own checkpoint would have copied them into the file
        journal.record(big(cycle))
        checkpoints.idle()
    assert database.stat().st_size == start  # no commit checkpointed
    assert checkpoints.done == 0
    checkpoints._every = 32
    checkpoints.idle()  # the service waits for a trigger: the thread checkpoints
    assert checkpoints.wait_done(1, timeout_s=10.0)
    assert database.stat().st_size > start + 90 * 50_000
    reader = Journal.open(tmp_path, readonly=True)
    assert [r.cycle for r in reader.last(2)] == [89, 90] and len(reader.last()[0].glue_path) == 2000
    reader.close()
    checkpoints.close()
    assert journal._db.execute("PRAGMA wal_autocheckpoint").fetchone()[0] == 1000  # SQLite's own again
    journal.close()


def test_the_wal_autocheckpoint_is_set_through_the_journal_and_a_negative_one_is_refused(tmp_path: Path) -> None:
    journal = Journal.open(tmp_path)
    journal.set_wal_autocheckpoint(0)
    assert journal._db.execute("PRAGMA wal_autocheckpoint").fetchone()[0] == 0
    with pytest.raises(ValueError, match="0 or more"):
        journal.set_wal_autocheckpoint(-1)
    assert journal._db.execute("PRAGMA wal_autocheckpoint").fetchone()[0] == 0
    journal.close()


def test_a_checkpoint_is_requested_once_every_so_many_commits(tmp_path: Path) -> None:
    journal = Journal.open(tmp_path)
    checkpoints = WalCheckpointer(journal, every=3)
    for cycle in range(1, 8):
        journal.record(ok(cycle))
        checkpoints.idle()
        if cycle in (3, 6):
            assert checkpoints.wait_done(cycle // 3, timeout_s=10.0)
    assert checkpoints.done == 2
    row = journal.record(ok(8))
    journal.attach_artifacts(row, None, None)  # artifact updates count too
    checkpoints.idle()
    assert checkpoints.wait_done(3, timeout_s=10.0)
    checkpoints.close()
    journal.close()


def test_artifact_updates_commit_and_leave_the_journal_synced_at_commit(tmp_path: Path) -> None:
    journal = Journal.open(tmp_path)
    row = journal.record(ok(1))
    journal.attach_artifacts(row, tmp_path / "sole.ply", None)
    assert journal._db.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL again for the next cycle's row
    assert not journal._db.in_transaction
    reader = Journal.open(tmp_path, readonly=True)
    assert reader.get(row).ply_path == str(tmp_path / "sole.ply")  # committed: another connection sees it
    reader.close()
    journal.close()
