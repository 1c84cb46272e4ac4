"""The journal keeps each cycle's recipe and tolerance verdict, and opens journals of older releases."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from cellctl.cli import main
from cellctl.service.journal import Journal
from cellctl.service.outcome import journal_record
from firmware_io.registers import ErrorCode, FeatureBit

OLD_SCHEMA = """
CREATE TABLE cycles (
    id INTEGER PRIMARY KEY AUTOINCREMENT, cycle INTEGER NOT NULL, triggered_at REAL NOT NULL, status TEXT NOT NULL,
    error_code INTEGER NOT NULL, reason TEXT, length_mm REAL, heel_height_mm REAL, toe_height_mm REAL,
    cycle_time_ms REAL NOT NULL, timings TEXT NOT NULL, glue_path TEXT NOT NULL, source TEXT NOT NULL,
    ply_path TEXT, overlay_path TEXT
);
INSERT INTO cycles (cycle, triggered_at, status, error_code, cycle_time_ms, timings, glue_path, source)
VALUES (7, 1780000000.0, 'error', 30, 812.0, '{}', '[]', '{}');
"""


def old_journal(state: Path) -> None:
    state.mkdir()
    with sqlite3.connect(state / "journal.sqlite3") as db:
        db.executescript(OLD_SCHEMA)


def test_an_older_journal_is_read_as_it_is_and_extended_when_the_service_opens_it(tmp_path: Path) -> None:
    state = tmp_path / "state"
    old_journal(state)
    reader = Journal.open(state, readonly=True)  # `cellctl results` on a journal it must not change
    (row,) = reader.last()
    assert row.cycle == 7 and row.recipe == 0 and row.in_tolerance is None and row.failed_features == []
    reader.close()
    journal = Journal.open(state)  # the service: adds the columns, keeps the rows
    record = journal_record(8, 1780000001.0, ErrorCode.NONE, None, 700.0, {}, None, None, 3, FeatureBit.LENGTH)
    journal.record(record)
    assert [(r.cycle, r.recipe) for r in journal.last()] == [(7, 0), (8, 3)]
    journal.close()


def test_recipe_and_verdict_round_trip_and_show_in_results(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    journal = Journal.open(tmp_path / "state")
    ok = journal_record(1, 1780000000.0, ErrorCode.NONE, None, 700.0, {}, None, None, 2)
    ok.status, ok.length_mm, ok.heel_height_mm, ok.toe_height_mm = "ok", 270.0, 18.0, 8.0
    ok.in_tolerance, ok.failed_features = False, ["LENGTH", "TOE_HEIGHT"]
    journal.record(ok)
    journal.record(journal_record(2, 1780000001.0, ErrorCode.RECIPE_UNKNOWN, "recipe 9 ...", 3.0, {}, None, None, 9))
    first, second = journal.last()
    assert first.recipe == 2 and first.in_tolerance is False and first.failed_features == ["LENGTH", "TOE_HEIGHT"]
    assert second.recipe == 9 and second.error_code == ErrorCode.RECIPE_UNKNOWN and second.in_tolerance is None
    journal.close()
    config = tmp_path / "cell.toml"
    calib = Path(__file__).resolve().parents[2] / "deploy" / "sim-calib.yaml"
    config.write_text(
        f'[cameras]\nbackend = "simulated"\n[calibration]\npath = "{calib}"\n[journal]\nstate_dir = "{tmp_path / "state"}"\n'
    )
    assert main(["results", "--config", str(config)]) == 0
    assert "recipe=2 FAIL LENGTH|TOE_HEIGHT" in capsys.readouterr().out
    assert main(["results", "--config", str(config), "--csv"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].endswith("recipe,in_tolerance,failed_features") and lines[1].endswith(",2,False,LENGTH|TOE_HEIGHT")
