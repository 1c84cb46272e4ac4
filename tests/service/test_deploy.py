"""The deployment files and the log keep the promises of docs/service.md (issue 15, findings 3 and 12)."""

from __future__ import annotations

import configparser
import ipaddress
import logging
import tomllib
from pathlib import Path

import pytest

from cellctl.service.config import PlcConfig
from cellctl.service.quiet_log import RepeatQuietLog

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"


def unit() -> configparser.ConfigParser:
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    parser.read_string((DEPLOY / "cellctl.service").read_text())
    return parser


def test_a_config_error_stops_the_unit_instead_of_restarting_it_every_two_seconds() -> None:
    service = unit()["Service"]
    assert service["RestartPreventExitStatus"] == "2"  # `cellctl run` exits 2 on a bad config
    assert int(unit()["Unit"]["StartLimitBurst"]) <= 10


def test_the_watchdog_outlasts_a_cycle_timeout_and_the_heartbeat_grace() -> None:
    watchdog_s = float(unit()["Service"]["WatchdogSec"])
    line = tomllib.loads((DEPLOY / "cell-line.example.toml").read_text())["plc"]
    cycle = line.get("cycle_timeout_s", PlcConfig.cycle_timeout_s)
    liveness = line.get("liveness_timeout_s", PlcConfig.liveness_timeout_s)
    assert cycle + liveness < watchdog_s


def test_the_line_config_binds_one_interface_and_names_its_clients() -> None:
    plc = tomllib.loads((DEPLOY / "cell-line.example.toml").read_text())["plc"]
    assert not ipaddress.ip_address(plc["host"]).is_unspecified  # not 0.0.0.0
    assert plc["allowed_clients"] and plc["max_connections"] >= 2


def test_a_missing_camera_is_logged_once_a_minute_not_every_second(caplog: pytest.LogCaptureFixture) -> None:
    log = logging.getLogger("test.cameras")
    quiet = RepeatQuietLog(log, repeat_s=60.0)
    caplog.set_level("DEBUG", "test.cameras")
    for _ in range(100):  # 100 probes, one a second
        quiet.warning("left gone", "cameras not ready: %s", "left camera unplugged")
    quiet.warning("right gone", "cameras not ready: %s", "right camera unplugged")  # a new problem is told
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warnings == ["cameras not ready: left camera unplugged", "cameras not ready: right camera unplugged"]


def test_run_refuses_a_cycle_timeout_the_systemd_watchdog_would_cut_short(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from cellctl.cli import main

    calib = tmp_path / "calib.yaml"
    calib.write_text((DEPLOY / "sim-calib.yaml").read_text())
    path = tmp_path / "cell.toml"
    path.write_text(
        f'[cameras]\nbackend = "replay"\nreplay_dir = "."\n[calibration]\npath = "{calib}"\n'
        '[plc]\ncycle_timeout_s = 12\n[journal]\nstate_dir = "s"\n'
    )
    monkeypatch.setenv("WATCHDOG_USEC", "15000000")  # what systemd passes for WatchdogSec=15
    assert main(["run", "--config", str(path)]) == 2
    assert "liveness_timeout_s = 17 s must be below the systemd watchdog (15 s" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()  # refused before anything started
