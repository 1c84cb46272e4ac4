"""The cell config: the shipped files load, and each kind of mistake is refused naming its key."""

from __future__ import annotations

from pathlib import Path

import pytest

from cellctl.service.config import CellConfig, ConfigError
from firmware_io.endpoints import SerialEndpoint, TcpEndpoint
from firmware_io.registers import WordOrder

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"

MINIMAL = f"""
[cameras]
backend = "simulated"
[calibration]
path = "{DEPLOY / "sim-calib.yaml"}"
[journal]
state_dir = "state"
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "cell.toml"
    path.write_text(text)
    return path


def test_sim_config_loads_with_its_calibration_and_tcp_5020() -> None:
    config = CellConfig.load(DEPLOY / "cell-sim.toml")
    assert config.cameras.backend == "simulated"
    assert config.calibration.path == DEPLOY / "sim-calib.yaml"
    assert config.plc.endpoint() == TcpEndpoint("127.0.0.1", 5020)
    assert not config.measure.require_taught_table  # the demo's plain soles, measured without teaching


def test_line_example_is_complete_apart_from_the_calibration_file(tmp_path: Path) -> None:
    text = (DEPLOY / "cell-line.example.toml").read_text()
    calib = tmp_path / "calib.yaml"
    calib.write_text((DEPLOY / "sim-calib.yaml").read_text())
    config = CellConfig.load(write(tmp_path, text.replace("/etc/cellctl/calib.yaml", str(calib))))
    assert config.cameras.backend == "v4l2"
    assert config.cameras.size == (1280, 1024)
    assert config.measure.require_taught_table
    with pytest.raises(
        ConfigError, match=r"\[calibration\] path: calibration file /etc/cellctl/calib.yaml does not exist"
    ):
        CellConfig.load(write(tmp_path, text))


def test_defaults_and_relative_paths(tmp_path: Path) -> None:
    config = CellConfig.load(write(tmp_path, MINIMAL))
    assert config.journal.state_dir == tmp_path / "state"
    assert config.plc.word_order is WordOrder.HIGH_FIRST
    assert config.measure.depth_range_mm == (450.0, 650.0)
    assert config.measure.require_taught_table  # safe by default: cycles refused until the table is taught


def test_the_cells_sole_wall(tmp_path: Path) -> None:
    assert CellConfig.load(write(tmp_path, MINIMAL)).measure.sole_wall_draft_deg is None
    text = MINIMAL + '[measure]\nsole_wall = "drafted"\nsole_draft_deg = 2.5\n'
    assert CellConfig.load(write(tmp_path, text)).measure.sole_wall_draft_deg == 2.5
    text = MINIMAL + '[measure]\nsole_wall = "vertical"\n'
    assert CellConfig.load(write(tmp_path, text)).measure.sole_wall_draft_deg == 0.0


def test_rtu_endpoint(tmp_path: Path) -> None:
    text = MINIMAL + '[plc]\ntransport = "rtu"\nserial_port = "/dev/ttyUSB0"\nbaudrate = 115200\nparity = "N"\n'
    endpoint = CellConfig.load(write(tmp_path, text)).plc.endpoint()
    assert endpoint == SerialEndpoint("/dev/ttyUSB0", 115200, "N", 1, 8)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ("[plc]\nprot = 5020\n", r"\[plc\] has unknown key\(s\) prot"),
        ('colour = "red"\n', r"unknown key\(s\) colour"),
        ("[plc]\nport = 70000\n", r"\[plc\] port: 70000 is impossible"),
        ('[plc]\nport = "5020"\n', r"\[plc\] port: expected int, got str"),
        ("[plc]\nport = 5020.7\n", r"\[plc\] port: expected int, got float 5020.7"),
        ("[plc]\nunit_id = 1.0\n", r"\[plc\] unit_id: expected int, got float"),
        ("[plc]\nbaudrate = 9600.5\n", r"baudrate: expected int, got float"),
        ("[measure]\nglue_spacing_mm = 1e-6\n", r"glue_spacing_mm: 1e-06 is impossible: must be in 0.1..50"),
        ("[plc]\ncycle_timeout_s = 0\n", r"cycle_timeout_s: 0 is impossible"),
        ("[plc]\nmax_connections = 0\n", r"max_connections: 0 is impossible"),
        ('[plc]\nallowed_clients = ["plc-1"]\n', r"allowed_clients: allowed client 'plc-1' is not an IP address"),
        ("[plc]\nallowed_clients = [5]\n", r"allowed_clients: expected a list of addresses"),
        ('[plc]\ntransport = "rtu"\n', r"\[plc\] serial_port: required for transport 'rtu'"),
        ('[plc]\ntransport = "rtu"\nserial_port = "/dev/ttyS0"\nunit_id = 0\n', r"unit_id: Modbus RTU unit id 0"),
        ('[plc]\nword_order = "middle"\n', r"word_order: 'middle' is not one of"),
        ("[plc]\nheartbeat_period_s = 0.6\n", r"heartbeat_period_s: 0.6 is impossible"),
        ("[measure]\ndepth_range_mm = [650, 450]\n", r"depth_range_mm: .* need 0 < near < far"),
        ("[measure]\nglue_spacing_mm = 0\n", r"glue_spacing_mm: 0 is impossible"),
        ("[measure]\nglue_height_tolerance_mm = 0\n", r"glue_height_tolerance_mm: 0 is impossible: must be in 0.1..10"),
        ('[measure]\nrequire_taught_table = "yes"\n', r"require_taught_table"),
        ('[measure]\nsole_wall = "drafted"\n', r"sole_draft_deg: missing: sole_wall = \"drafted\" needs"),
        ('[measure]\nsole_wall = "drafted"\nsole_draft_deg = 30\n', r"sole_draft_deg: 30 is impossible"),
    ],
)
def test_mistakes_are_refused_naming_the_key(tmp_path: Path, extra: str, message: str) -> None:
    text = extra + MINIMAL if not extra.startswith("[") else MINIMAL + extra
    with pytest.raises(ConfigError, match=message):
        CellConfig.load(write(tmp_path, text))


@pytest.mark.parametrize(
    ("cameras", "message"),
    [
        ('backend = "usb"', r"backend: 'usb' is not one of"),
        ('backend = "v4l2"\nleft = "/dev/video0"', r"\[cameras\] right: required for backend 'v4l2'"),
        ('backend = "v4l2"\nleft = "video0"\nright = "/dev/video2"', r"left: 'video0' is not a device path"),
        ('backend = "v4l2"\nleft = "/dev/video0"\nright = "/dev/video0"', r"left and right name the same device"),
        ('backend = "replay"\nreplay_dir = "nowhere"', r"replay_dir: directory .*nowhere does not exist"),
        ('backend = "simulated"\nsize = [1280]', r"size: expected \[width, height\]"),
        ('backend = "simulated"\npixel_format = "H264"', r"pixel_format: 'H264' is not one of"),
        ('backend = "simulated"\nsync_tolerance_ms = -1', r"sync_tolerance_ms: -1 is impossible"),
        ('backend = "simulated"\naveraged_frames = 0', r"averaged_frames: 0 is impossible: must be in 1..16"),
        (
            'backend = "simulated"\nretry_averaged_frames = 17',
            r"retry_averaged_frames: 17 is impossible: must be in 0..16",
        ),
        (
            'backend = "simulated"\n[cameras.simulated]\nseeds = []',
            r"\[cameras.simulated\] seeds: expected a non-empty",
        ),
        ('backend = "simulated"\n[cameras.simulated]\nskew = 3', r"\[cameras.simulated\] has unknown key\(s\) skew"),
    ],
)
def test_camera_mistakes(tmp_path: Path, cameras: str, message: str) -> None:
    text = MINIMAL.replace('backend = "simulated"', cameras)
    with pytest.raises(ConfigError, match=message):
        CellConfig.load(write(tmp_path, text))


def test_missing_file_section_and_bad_toml(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        CellConfig.load(tmp_path / "none.toml")
    with pytest.raises(ConfigError, match=r"the \[journal\] section is missing"):
        CellConfig.load(write(tmp_path, MINIMAL.split("[journal]")[0]))
    with pytest.raises(ConfigError, match="is not valid TOML"):
        CellConfig.load(write(tmp_path, "[cameras\n"))
    with pytest.raises(ConfigError, match="calibration file .*missing.yaml does not exist"):
        CellConfig.load(write(tmp_path, MINIMAL.replace(str(DEPLOY / "sim-calib.yaml"), "missing.yaml")))
