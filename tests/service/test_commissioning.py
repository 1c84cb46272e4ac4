"""Commissioning commands (`cellctl check`, `cellctl capture`) and the CLI's light start."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from cellctl.calib.board import Checkerboard
from cellctl.cli import main
from cellctl.sim.checkerboard import CheckerboardSimulator, write_pairs
from tests.sim_rig import UNTAUGHT_MEASURE, half_size_rig, write_half_size_rig


def sim_config(
    tmp_path: Path, extra: str = UNTAUGHT_MEASURE, cameras: str = '[cameras]\nbackend = "simulated"\n'
) -> Path:
    calib = write_half_size_rig(tmp_path)
    path = tmp_path / "cell.toml"
    path.write_text(
        f'{cameras}[calibration]\npath = "{calib}"\n[plc]\nport = {free_port()}\n'
        f'[journal]\nstate_dir = "{tmp_path / "state"}"\n[station]\nport = {free_port()}\n{extra}'
    )
    return path


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


@pytest.mark.slow  # renders a simulated scene and rectifies it
def test_check_passes_on_a_working_cell_and_names_a_busy_port(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = sim_config(tmp_path)
    assert main(["check", "--config", str(path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    names = [line.split()[1] for line in lines]
    assert names == ["config", "calibration", "taught", "state", "plc", "station", "cameras", "frames", "rectification"]
    assert all(line.startswith("ok") for line in lines)
    plc_port = int(path.read_text().split("[plc]\nport = ")[1].split()[0])
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", plc_port))
        busy.listen()
        assert main(["check", "--config", str(path)]) == 1
    plc_line = next(line for line in capsys.readouterr().out.splitlines() if " plc " in line)
    assert plc_line.startswith("FAIL") and "already running" in plc_line


def test_check_says_a_cell_that_requires_a_taught_table_has_none(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = sim_config(
        tmp_path,
        extra="[measure]\nrequire_taught_table = true\n",
        cameras='[cameras]\nbackend = "v4l2"\nleft = "/dev/null-left"\nright = "/dev/null-right"\n',
    )
    assert main(["check", "--config", str(path)]) == 1
    line = next(line for line in capsys.readouterr().out.splitlines() if " taught " in line)
    assert line.startswith("FAIL") and "require_taught_table refuses every cycle" in line and "cellctl teach" in line


def test_check_refuses_a_bad_config_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "cell.toml"
    path.write_text("[cameras]\nbackend = 'usb'\n")
    assert main(["check", "--config", str(path)]) == 1
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 1 and out[0].startswith("FAIL  config") and "[calibration] section is missing" in out[0]


def test_capture_saves_numbered_pairs_and_reports_the_board(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    board = Checkerboard.from_spec("9x6", 30.0)
    boards = tmp_path / "boards"
    write_pairs(CheckerboardSimulator(half_size_rig(), board, seed=1).pairs(2, bad=("outside",)), boards)
    path = sim_config(tmp_path, cameras=f'[cameras]\nbackend = "replay"\nreplay_dir = "{boards}"\n')
    out = tmp_path / "captured"
    out.mkdir()
    (out / "left_07.png").write_bytes(b"")  # numbering continues after what is there
    assert (
        main(["capture", "--config", str(path), "-o", str(out), "--board", "9x6", "--count", "3", "--interval", "0"])
        == 0
    )
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0] for line in lines[:3]] == ["pair 08", "pair 09", "pair 10"]
    assert sum("usable" in line and "NOT usable" not in line for line in lines[:3]) == 2  # the "outside" pair is not
    assert "2 of 3 pairs show the whole board" in lines[3]
    assert (out / "left_10.png").is_file() and (out / "right_10.png").is_file()


@pytest.mark.parametrize("argv", [["--help"], ["results", "--help"], ["run", "--help"], ["check", "--help"]])
def test_help_does_not_load_the_heavy_libraries(argv: list[str]) -> None:
    probe = (
        "import sys\nfrom cellctl.cli import main\ntry:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
        "print(sorted(m for m in ('open3d', 'cv2', 'numpy', 'pymodbus') if m in sys.modules))"
    )
    done = subprocess.run([sys.executable, "-c", probe, *argv], capture_output=True, text=True, timeout=120)
    assert done.stdout.strip().splitlines()[-1] == "[]", done.stdout


def test_results_reads_the_journal_without_open3d_or_opencv(tmp_path: Path) -> None:
    from cellctl.service.journal import Journal

    Journal.open(tmp_path).close()
    probe = (
        "import sys\nfrom cellctl.cli import main\nmain(['results', '--state-dir', sys.argv[1]])\n"
        "print(sorted(m for m in ('open3d', 'cv2') if m in sys.modules))"
    )
    done = subprocess.run([sys.executable, "-c", probe, str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert done.stdout.strip().splitlines()[-1] == "[]", done.stdout + done.stderr


def test_version() -> None:
    done = subprocess.run([sys.executable, "-m", "cellctl", "--version"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.startswith("cellctl ")


def test_results_show_local_time_with_its_zone(tmp_path: Path) -> None:
    from cellctl.service.journal import CycleRecord, Journal

    journal = Journal.open(tmp_path)
    journal.record(
        CycleRecord(
            cycle=1, triggered_at=1_767_225_600.0, status="error", error_code=30, cycle_time_ms=900.0, reason="x"
        )
    )
    journal.close()
    environment = {**os.environ, "TZ": "Europe/Berlin"}  # 2026-01-01 00:00 UTC is 01:00 CET there
    command = [sys.executable, "-m", "cellctl", "results", "--state-dir", str(tmp_path)]
    text = subprocess.run(command, capture_output=True, text=True, env=environment, timeout=120).stdout
    assert text.startswith("2026-01-01 01:00:00 CET cycle 1: error 30")
    table = subprocess.run([*command, "--csv"], capture_output=True, text=True, env=environment, timeout=120).stdout
    assert "2026-01-01T01:00:00.000+01:00" in table
