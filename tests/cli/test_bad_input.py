"""Every command, fed what a careless technician types: one line naming the problem, a non-zero exit, no
traceback, no hang (issue 15, finding 10). Each case runs `cellctl` as a process with a time limit."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.service.journal import CycleRecord, Journal
from tests.sim_rig import UNTAUGHT_MEASURE, half_size_rig

pytestmark = pytest.mark.slow  # one process per case (~2-10 s each on the loaded test machine)

CELLCTL = [str(Path(sys.executable).parent / "cellctl")]
TIME_LIMIT_S = 120.0


@dataclass
class Case:
    argv: list[str]
    says: str  # a phrase the one line must contain
    exit_code: int = 2


def run(argv: list[str], cwd: Path, shell_tail: str = "") -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    if shell_tail:
        command = " ".join(f"'{a}'" for a in [*CELLCTL, *argv]) + shell_tail
        return subprocess.run(
            ["bash", "-o", "pipefail", "-c", command],
            cwd=cwd,
            env=env,
            capture_output=True,
            text=True,
            timeout=TIME_LIMIT_S,
        )
    return subprocess.run([*CELLCTL, *argv], cwd=cwd, env=env, capture_output=True, text=True, timeout=TIME_LIMIT_S)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Calibrations, images, journals and configs, good and bad."""
    d = tmp_path_factory.mktemp("bad-input")
    calib = half_size_rig()
    calib.save(d / "calib.yaml")
    width, height = calib.image_size
    for name, level in (("black", 0), ("grey", 128)):
        cv2.imwrite(str(d / f"{name}.png"), np.full((height, width, 3), level, np.uint8))
    texture = np.random.default_rng(1).integers(0, 256, (height, width, 3), dtype=np.uint8)
    cv2.imwrite(str(d / "texture.png"), texture)  # a view unlike the grey one: not its mean
    cv2.imwrite(str(d / "black.jpg"), np.zeros((height, width, 3), np.uint8))
    bomb = bytearray((d / "grey.png").read_bytes())
    bomb[16:24] = (20000).to_bytes(4, "big") * 2  # the IHDR says 20000 x 20000: 3.7 GB if decoded
    (d / "bomb.png").write_bytes(bytes(bomb))
    text = (d / "calib.yaml").read_text()
    (d / "calib-rows.yaml").write_text(text.replace("rows: 3\n   cols: 3", "rows: 4\n   cols: 3", 1))
    calib_k0 = (
        text.split("K1:")[0]
        + "K1: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [0., 0., 0., 0., 0., 0., 0., 0., 1.]\n"
        + "D1:"
        + text.split("D1:")[1]
    )
    (d / "calib-k0.yaml").write_text(calib_k0)
    # replay cameras: listing the pair is all `run` does before it opens the Modbus port
    (d / "replay").mkdir()
    for side in ("left", "right"):
        cv2.imwrite(str(d / "replay" / f"{side}_01.png"), np.zeros((height, width, 3), np.uint8))
    (d / "fifo").mkdir()
    os.mkfifo(d / "fifo" / "left_01.png")
    cv2.imwrite(str(d / "fifo" / "right_01.png"), np.zeros((8, 8, 3), np.uint8))
    (d / "garbage-state").mkdir()
    (d / "garbage-state" / "journal.sqlite3").write_bytes(b"this is not SQLite" * 100)
    (d / "dir-state" / "journal.sqlite3").mkdir(parents=True)
    journal = Journal.open(d / "full-state")
    path = np.random.default_rng(1).uniform(0, 100, (300, 3)).tolist()
    for cycle in range(1, 200):
        journal.record(CycleRecord(cycle, 0.0, "ok", 0, 1.0, None, 1.0, 1.0, 1.0, {}, path))
    journal.close()
    return d


def config(d: Path, name: str, plc: str, state: str = "state") -> str:
    path = d / f"{name}.toml"
    path.write_text(
        f'[cameras]\nbackend = "replay"\nreplay_dir = "replay"\n[calibration]\npath = "calib.yaml"\n'
        f'[plc]\n{plc}\n[journal]\nstate_dir = "{state}"\n[station]\nenabled = false\n{UNTAUGHT_MEASURE}'
    )
    return str(path)


@pytest.fixture(scope="module")
def taken_port() -> Iterator[int]:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        yield taken.getsockname()[1]


CASES: dict[str, Callable[[Path, int], Case]] = {
    "run: port in use": lambda d, port: Case(
        ["run", "--config", config(d, "busy", f"port = {port}")], "port already in use"
    ),
    "run: unresolvable host": lambda d, _: Case(
        ["run", "--config", config(d, "nohost", 'host = "no-such-host.invalid"\nport = 0')], "cannot serve Modbus"
    ),
    "run: host not on this PC": lambda d, _: Case(
        ["run", "--config", config(d, "farhost", 'host = "192.0.2.1"\nport = 0')], "one of this PC's"
    ),
    "run: missing serial port": lambda d, _: Case(
        ["run", "--config", config(d, "rtu", 'transport = "rtu"\nserial_port = "/dev/ttyNOPE9"')],
        "does the serial port exist",
    ),
    "run: garbage journal": lambda d, _: Case(
        ["run", "--config", config(d, "garbage", "port = 0", "garbage-state")], "move it away"
    ),
    "run: journal is a directory": lambda d, _: Case(
        ["run", "--config", config(d, "dirjournal", "port = 0", "dir-state")], "is not a file"
    ),
    "run: bad allow-list": lambda d, _: Case(
        ["run", "--config", config(d, "allow", 'allowed_clients = ["plc-1"]')], "allowed_clients"
    ),
    "results: garbage journal": lambda d, _: Case(["results", "--state-dir", str(d / "garbage-state")], "move it away"),
    "results: journal is a directory": lambda d, _: Case(
        ["results", "--state-dir", str(d / "dir-state")], "is not a file"
    ),
    "measure: matrix rows/cols do not match": lambda d, _: Case(
        ["measure", "--calib", str(d / "calib-rows.yaml"), str(d / "grey.png"), str(d / "grey.png")],
        "rows/cols that do not match",
    ),
    "measure: K1 = 0": lambda d, _: Case(
        ["measure", "--calib", str(d / "calib-k0.yaml"), str(d / "grey.png"), str(d / "grey.png")],
        "not a camera matrix",
    ),
    "measure: black pair": lambda d, _: Case(
        ["measure", "--untaught", "--calib", str(d / "calib.yaml"), str(d / "black.png"), str(d / "black.png")],
        "too few measured points",
        exit_code=1,
    ),
    "measure: no taught table": lambda d, _: Case(
        ["measure", "--calib", str(d / "calib.yaml"), str(d / "grey.png"), str(d / "grey.png")],
        "teach the empty fixture first",
    ),
    "measure: a mean of another view": lambda d, _: Case(
        [
            "measure",
            "--untaught",
            "--calib",
            str(d / "calib.yaml"),
            str(d / "grey.png"),
            str(d / "grey.png"),
            "--mean",
            str(d / "texture.png"),
            str(d / "grey.png"),
        ],
        "does not show the same still view as LEFT",
    ),
    "measure: image bomb": lambda d, _: Case(
        ["measure", "--calib", str(d / "calib.yaml"), str(d / "bomb.png"), str(d / "grey.png")],
        "larger than any camera image",
    ),
    "teach: image bomb": lambda d, _: Case(
        ["teach", "--calib", str(d / "calib.yaml"), str(d / "bomb.png"), str(d / "grey.png")],
        "larger than any camera image",
    ),
    "teach: missing image": lambda d, _: Case(
        ["teach", "--calib", str(d / "calib.yaml"), str(d / "grey.png"), str(d / "absent.png")],
        "does not exist",
    ),
    "measure: glue spacing 1e-6": lambda d, _: Case(
        [
            "measure",
            "--calib",
            str(d / "calib.yaml"),
            "--glue-spacing",
            "1e-6",
            str(d / "grey.png"),
            str(d / "grey.png"),
        ],
        "spacing in 0.1..50 mm",
    ),
    "measure: wall draft 45 degrees": lambda d, _: Case(
        ["measure", "--calib", str(d / "calib.yaml"), "--wall-draft", "45", str(d / "grey.png"), str(d / "grey.png")],
        "--wall-draft: a wall's draft must be in (0, 10] degrees",
    ),
    "measure: glue height tolerance 0": lambda d, _: Case(
        [
            "measure",
            "--calib",
            str(d / "calib.yaml"),
            "--glue-height-tolerance",
            "0",
            str(d / "grey.png"),
            str(d / "grey.png"),
        ],
        "glue height tolerance must be in 0.1..10 mm",
    ),
    "plc-sim: missing serial port": lambda d, _: Case(
        ["plc-sim", "--serial", "/dev/ttyNOPE9", "--cycles", "1"], "cannot connect to the controller", exit_code=1
    ),
    "plc-sim: no cycles": lambda d, _: Case(["plc-sim", "--cycles", "0"], "--cycles 0 must be at least 1"),
    "simulate: too many empty-table exposures": lambda d, _: Case(
        ["simulate", "sole", "--out", str(d / "scene"), "--empty", "12"], "must be 0..9"
    ),
    "simulate: output under a file": lambda d, _: Case(
        ["simulate", "sole", "--out", str(d / "grey.png" / "x")], "Not a directory"
    ),
    "bench-sole: missing calibration": lambda d, _: Case(
        ["bench-sole", "--calib", str(d / "absent.yaml"), "--soles", "1"], "does not exist"
    ),
    "bench-sole: --only seed not in the matrix": lambda d, _: Case(
        ["bench-sole", "--matrix", "--soles", "84", "--first-seed", "3000", "--only", "3002,3090"],
        "seed 3090 is not in the matrix (3000..3083)",
    ),
    "bench-sole: --only without --matrix": lambda d, _: Case(["bench-sole", "--only", "3"], "--only needs --matrix"),
    "bench-sole: --declared-walls without --matrix": lambda d, _: Case(
        ["bench-sole", "--declared-walls"], "--declared-walls needs --matrix"
    ),
    "bench-sole: --lighting without --matrix": lambda d, _: Case(
        ["bench-sole", "--lighting", "ring"], "--lighting needs --matrix"
    ),
    "bench-sole: unknown --lighting": lambda d, _: Case(
        ["bench-sole", "--matrix", "--lighting", "sun"], "--lighting must be one of bars, shadowed-bars"
    ),
    "bench-sole: --rig without --matrix": lambda d, _: Case(["bench-sole", "--rig", "fine"], "--rig needs --matrix"),
    "bench-sole: unknown --rig": lambda d, _: Case(
        ["bench-sole", "--matrix", "--rig", "pinhole"], "--rig must be one of default, distorted"
    ),
    "bench-sole: --combined without --variations": lambda d, _: Case(
        ["bench-sole", "--matrix", "--combined"], "--combined needs --matrix --variations"
    ),
    "bench-sole: --combined with clashing variations": lambda d, _: Case(
        ["bench-sole", "--matrix", "--combined", "--variations", "flat,tall"], "both set height"
    ),
    "results: missing config": lambda d, _: Case(["results", "--config", str(d / "absent.toml")], "does not exist"),
    "rectify: matrix rows/cols do not match": lambda d, _: Case(
        [
            "rectify",
            "--calib",
            str(d / "calib-rows.yaml"),
            str(d / "grey.png"),
            str(d / "grey.png"),
            "-o",
            str(d / "r"),
        ],
        "rows/cols that do not match",
    ),
    "calibrate: FIFO named like an image": lambda d, _: Case(
        ["calibrate", str(d / "fifo"), "--board", "9x6", "--square", "25", "-o", str(d / "c.yaml")],
        "not a regular image file",
    ),
}


@pytest.mark.parametrize("name", list(CASES))
def test_bad_input_gives_one_line_and_a_non_zero_exit(workdir: Path, taken_port: int, name: str) -> None:
    case = CASES[name](workdir, taken_port)
    result = run(case.argv, workdir)
    text = (result.stdout + result.stderr).strip()
    assert "Traceback" not in text, text
    assert result.returncode == case.exit_code, text
    stream = result.stdout if case.exit_code == 1 and name.startswith("measure") else result.stderr
    lines = stream.strip().splitlines()
    if case.argv[0] == "run":  # the service logs its start and stop (INFO) on stderr too, as under journald
        lines = [line for line in lines if " INFO " not in line]
    assert len(lines) == 1, text  # one line, nothing else on that stream
    assert case.says in stream, text


def test_a_jpeg_pair_is_measured_with_a_warning_naming_its_lossy_compression(workdir: Path) -> None:
    """Lossy images are measured, not refused for their format, but a refusal for the surface would otherwise
    name only texture, noise and focus: one warning line per JPEG on stderr, the result's one line on stdout."""
    jpeg, png = str(workdir / "black.jpg"), str(workdir / "black.png")
    result = run(["measure", "--untaught", "--calib", str(workdir / "calib.yaml"), jpeg, png], workdir)
    assert result.returncode == 1 and "Traceback" not in result.stderr, result.stderr
    assert len(result.stdout.strip().splitlines()) == 1 and "too few measured points" in result.stdout
    warnings = result.stderr.strip().splitlines()
    assert len(warnings) == 1 and warnings[0].startswith(f"warning: LEFT image {jpeg} is a JPEG"), result.stderr
    assert "losslessly" in warnings[0]


def test_results_into_a_closed_pipe_ends_quietly(workdir: Path) -> None:
    result = run(["results", "--state-dir", str(workdir / "full-state"), "--json"], workdir, " | head -c 100")
    assert "Traceback" not in result.stderr and "Error" not in result.stderr, result.stderr
    assert len(result.stdout) == 100
