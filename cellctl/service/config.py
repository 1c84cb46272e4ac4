"""The cell configuration file (TOML), read and checked once at service start.

    config = CellConfig.load("deploy/cell-sim.toml")
    config.plc.endpoint()           # firmware_io TcpEndpoint or SerialEndpoint
    config.calibration.path         # absolute Path

Every problem is a ConfigError naming the file, the section and key, what is wrong and what to write
instead: unknown keys (a typo must not silently fall back to a default), wrong types, impossible values and
files that do not exist. Relative paths are taken relative to the config file, so a config and its
calibration can be moved together.

The table reader that refuses every key the same way is cellctl.service.config_table; the [plc] section
(the longest) is cellctl.service.config_plc; the cameras' section is cellctl.cameras.config.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cellctl.cameras.config import (
    AVERAGED_FRAMES,
    MAX_AVERAGED_FRAMES,
    MORE_EXPOSURES,
    CameraConfig,
    SimulatedCameraConfig,
)
from cellctl.service.config_plc import PlcConfig, read_plc
from cellctl.service.config_table import ConfigError, Table, read_toml
from cellctl.vision.defaults import (
    DEPTH_RANGE_MM,
    GLUE_HEIGHT_TOLERANCE_MM,
    GLUE_HEIGHT_TOLERANCE_RANGE_MM,
    GLUE_OFFSET_MM,
    GLUE_OFFSET_RANGE_MM,
    GLUE_SPACING_MM,
    GLUE_SPACING_RANGE_MM,
    WALL_DRAFT_RANGE_DEG,
)

__all__ = ["CellConfig", "ConfigError", "ImageLogConfig", "MeasureConfig", "OpcUaConfig", "PlcConfig"]

BACKENDS = ("simulated", "replay", "v4l2")
PIXEL_FORMATS = ("MJPEG", "YUYV")
SOLE_COLOURS = ("white", "black")  # cellctl.sim.render.SOLE_MATERIALS (not imported: it pulls in Open3D)


@dataclass(frozen=True)
class CalibrationConfig:
    path: Path


SOLE_WALLS = ("unknown", "vertical", "drafted")


def read_sole_wall(t: Table, wall_key: str, draft_key: str, default: float | None) -> float | None:
    """A sole model's wall as a config table states it (`wall_key`: SOLE_WALLS; `draft_key`: degrees, with
    "drafted" only), as measure_sole's wall_draft_deg: None unknown, 0 vertical, else the draft; `default` where
    the table leaves it out (the cell's word for a recipe)."""
    stated = "unknown" if default is None else "vertical" if default == 0.0 else "drafted"
    wall = t.choice(wall_key, SOLE_WALLS, stated)
    if wall != "drafted":
        if draft_key in t.data:
            raise t.fail(draft_key, f'a draft goes with {wall_key} = "drafted", not {wall!r}')
        return None if wall == "unknown" else 0.0
    if draft_key not in t.data:
        if default:  # the cell's draft
            return default
        raise t.fail(draft_key, f'missing: {wall_key} = "drafted" needs the mould\'s draft in degrees, e.g. 3')
    low, high = WALL_DRAFT_RANGE_DEG
    return t.number(draft_key, above=low, high=high)


@dataclass(frozen=True)
class MeasureConfig:
    depth_range_mm: tuple[float, float] = DEPTH_RANGE_MM
    glue_offset_mm: float = GLUE_OFFSET_MM
    glue_spacing_mm: float = GLUE_SPACING_MM
    glue_height_tolerance_mm: float = GLUE_HEIGHT_TOLERANCE_MM
    # Refuse every cycle without a usable taught table. Untaught, only the colour test finds the edge and only
    # depth checks it: on the matrix sets 9-12 of 84 results were valid and wrong that way (docs/sole-benchmark.md,
    # thirteenth round). A cell that measures only plain one-colour soles on a plain table may set it false.
    require_taught_table: bool = True
    # The soles' side wall ([measure] sole_wall, sole_draft_deg), as measure_sole's wall_draft_deg: None unknown
    # (the cell refuses a sole whose wall is too low all round to show whether it leans out, `wall_too_low`), 0
    # vertical (known from the mould: its outline is its foot however low it is), else the mould's draft in degrees
    # (cellctl.vision.wall_draft: the outline is moved out to the foot the cameras cannot see).
    sole_wall_draft_deg: float | None = None


@dataclass(frozen=True)
class JournalConfig:
    state_dir: Path
    keep_artifacts: int = 500  # cycles whose PLY and overlay PNG are kept; the SQLite rows are all kept


@dataclass(frozen=True)
class RecipesConfig:
    directory: Path | None = None  # one TOML per shoe model (cellctl.service.recipes); None: recipe 0 only


@dataclass(frozen=True)
class RobotConfig:
    frame_file: Path | None = None  # table -> robot transform from `cellctl teach-robot`; None: beside calibration
    publish_frame: str = "table"  # "table" or "robot": the frame of the glue points the PLC gets
    nozzle_offset_mm: float = 0.0  # glue points moved this far along their normals (nozzle stand-off)


@dataclass(frozen=True)
class OpcUaConfig:
    enabled: bool = False
    endpoint: str = "opc.tcp://0.0.0.0:4840/cellctl/"
    cell_name: str = "cell"
    allow_anonymous: bool = False
    username: str | None = None
    password_file: Path | None = None  # file holding the password (0600), never the password in the config
    history: int = 100  # results kept for history reads and the ResultHistory variable


@dataclass(frozen=True)
class StationConfig:
    """The operator station (web pages and /metrics), served by the service itself."""

    enabled: bool = True
    bind: str = "127.0.0.1"  # only this machine; "0.0.0.0" shows it to the plant network
    port: int = 8080
    token: str | None = None  # actions (capture) need it; without one they are refused
    board: str | None = None  # checkerboard inner corners COLSxROWS for capture feedback, e.g. "9x6"


@dataclass(frozen=True)
class ImageLogConfig:
    """Raw pair and overlay of every failed cycle and every Nth good one, under state_dir/images."""

    every_nth_good: int = 0  # 0: failed cycles only
    keep_cycles: int = 200
    max_mb: float = 500.0


@dataclass(frozen=True)
class CellConfig:
    source: Path
    cameras: CameraConfig
    calibration: CalibrationConfig
    measure: MeasureConfig
    plc: PlcConfig
    journal: JournalConfig
    station: StationConfig = StationConfig()
    image_log: ImageLogConfig = ImageLogConfig()
    recipes: RecipesConfig = RecipesConfig()
    robot: RobotConfig = RobotConfig()
    opcua: OpcUaConfig = OpcUaConfig()

    @property
    def robot_frame_path(self) -> Path:
        """Where the taught table -> robot transform lives: configured, or beside the calibration."""
        return self.robot.frame_file or self.calibration.path.with_name("robot-frame.json")

    @classmethod
    def load(cls, path: str | Path) -> CellConfig:
        """Read and check a config file; ConfigError names every problem's key and what to do."""
        source = Path(path).expanduser().resolve()
        if not source.is_file():
            raise ConfigError(f"config file {source} does not exist (see deploy/cell-line.example.toml)")
        return cls.from_dict(read_toml(source), source)

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: Path) -> CellConfig:
        root = Table(data, "top level", source)
        sections = {
            name: root.table(name)
            for name in (
                *("cameras", "calibration", "measure", "plc", "journal", "station", "image_log"),
                *("recipes", "robot", "opcua"),
            )
        }
        for name in ("cameras", "calibration", "journal"):
            if name not in data:
                raise ConfigError(f"{source}: the [{name}] section is missing")
        for table in sections.values():
            table.name = table.name.removeprefix("top level.")
        root.finish()
        config = cls(
            source=source,
            cameras=_cameras(sections["cameras"]),
            calibration=_calibration(sections["calibration"]),
            measure=_measure(sections["measure"]),
            plc=read_plc(sections["plc"]),
            journal=_journal(sections["journal"]),
            station=_station(sections["station"]),
            image_log=_image_log(sections["image_log"]),
            recipes=_recipes(sections["recipes"]),
            robot=_robot(sections["robot"]),
            opcua=_opcua(sections["opcua"]),
        )
        return config


def _cameras(t: Table) -> CameraConfig:
    backend = t.choice("backend", BACKENDS)
    left = t.get("left", str, None)
    right = t.get("right", str, None)
    replay_dir = t.path("replay_dir", None)
    size = t.get("size", list, None)
    if size is not None:
        if len(size) != 2 or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size):
            raise t.fail("size", f"expected [width, height] in pixels, got {size!r}")
        size = (size[0], size[1])
    simulated = _simulated(t.table("simulated"))
    config = CameraConfig(
        backend=backend,
        left=left,
        right=right,
        replay_dir=replay_dir,
        size=size,
        pixel_format=t.choice("pixel_format", PIXEL_FORMATS, "MJPEG"),
        exposure=t.optional_number("exposure", low=0),
        gain=t.optional_number("gain", low=0),
        sync_tolerance_ms=t.number("sync_tolerance_ms", 8.0, above=0, high=1000),
        timeout_ms=t.number("timeout_ms", 1000.0, above=0, high=60000),
        max_regrabs=t.integer("max_regrabs", 4, low=0, high=100),
        averaged_frames=t.integer("averaged_frames", AVERAGED_FRAMES, low=1, high=MAX_AVERAGED_FRAMES),
        retry_averaged_frames=t.integer("retry_averaged_frames", MORE_EXPOSURES, low=0, high=MAX_AVERAGED_FRAMES),
        simulated=simulated,
    )
    t.finish()
    if backend == "v4l2":
        for key, value in (("left", left), ("right", right)):
            if value is None:
                raise t.fail(
                    key, "required for backend 'v4l2': the camera's device, e.g. /dev/v4l/by-id/usb-...-video-index0"
                )
            if not value.startswith("/dev/"):
                raise t.fail(key, f"{value!r} is not a device path under /dev/")
        if left == right:
            raise t.fail("right", "left and right name the same device")
    if backend == "replay":
        if replay_dir is None:
            raise t.fail("replay_dir", "required for backend 'replay': a directory of left_NN.png/right_NN.png pairs")
        if not replay_dir.is_dir():
            raise t.fail("replay_dir", f"directory {replay_dir} does not exist")
    return config


def _simulated(t: Table) -> SimulatedCameraConfig:
    seeds = t.get("seeds", list, [1, 2, 3, 4, 5])
    if not seeds or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds):
        raise t.fail("seeds", f"expected a non-empty list of scene numbers >= 0, got {seeds!r}")
    config = SimulatedCameraConfig(
        seeds=tuple(seeds),
        color=t.choice("color", SOLE_COLOURS, "white"),
        skew_ms=t.number("skew_ms", 0.0, low=0, high=10000),
    )
    t.finish()
    return config


def _calibration(t: Table) -> CalibrationConfig:
    path = t.path("path")
    t.finish()
    assert path is not None
    if not path.is_file():
        raise t.fail("path", f"calibration file {path} does not exist: run `cellctl calibrate` and point here")
    return CalibrationConfig(path)


def _measure(t: Table) -> MeasureConfig:
    depth = t.get("depth_range_mm", list, list(DEPTH_RANGE_MM))
    if len(depth) != 2 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in depth):
        raise t.fail("depth_range_mm", f"expected [near, far] in mm, got {depth!r}")
    if not 0 < depth[0] < depth[1]:
        raise t.fail("depth_range_mm", f"{depth!r} is impossible: need 0 < near < far")
    config = MeasureConfig(
        depth_range_mm=(float(depth[0]), float(depth[1])),
        glue_offset_mm=t.number(
            "glue_offset_mm", GLUE_OFFSET_MM, low=GLUE_OFFSET_RANGE_MM[0], high=GLUE_OFFSET_RANGE_MM[1]
        ),
        glue_spacing_mm=t.number(
            "glue_spacing_mm", GLUE_SPACING_MM, low=GLUE_SPACING_RANGE_MM[0], high=GLUE_SPACING_RANGE_MM[1]
        ),
        glue_height_tolerance_mm=t.number(
            "glue_height_tolerance_mm",
            GLUE_HEIGHT_TOLERANCE_MM,
            low=GLUE_HEIGHT_TOLERANCE_RANGE_MM[0],
            high=GLUE_HEIGHT_TOLERANCE_RANGE_MM[1],
        ),
        require_taught_table=t.get("require_taught_table", bool, MeasureConfig.require_taught_table),
        sole_wall_draft_deg=read_sole_wall(t, "sole_wall", "sole_draft_deg", MeasureConfig.sole_wall_draft_deg),
    )
    t.finish()
    return config


def _journal(t: Table) -> JournalConfig:
    state_dir = t.path("state_dir")
    assert state_dir is not None
    config = JournalConfig(state_dir=state_dir, keep_artifacts=t.integer("keep_artifacts", 500, low=0, high=1_000_000))
    t.finish()
    if state_dir.exists() and not state_dir.is_dir():
        raise t.fail("state_dir", f"{state_dir} exists and is not a directory")
    return config


def _station(t: Table) -> StationConfig:
    token = t.get("token", str, None)
    if token is not None and len(token) < 8:
        raise t.fail("token", "too short: use at least 8 characters (e.g. `openssl rand -hex 16`)")
    board = t.get("board", str, None)
    if board is not None and not re.fullmatch(r"\d+x\d+", board):
        raise t.fail("board", f'{board!r} is not COLSxROWS inner corners, e.g. "9x6"')
    config = StationConfig(
        enabled=t.get("enabled", bool, True),
        bind=t.get("bind", str, "127.0.0.1"),
        port=t.integer("port", 8080, low=0, high=65535),
        token=token,
        board=board,
    )
    t.finish()
    return config


def _image_log(t: Table) -> ImageLogConfig:
    config = ImageLogConfig(
        every_nth_good=int(t.number("every_nth_good", 0, low=0)),
        keep_cycles=int(t.number("keep_cycles", 200, low=0)),
        max_mb=t.number("max_mb", 500.0, low=0),
    )
    t.finish()
    return config


def _recipes(t: Table) -> RecipesConfig:
    directory = t.path("dir", None)
    t.finish()
    if directory is not None and not directory.is_dir():
        raise t.fail("dir", f"recipe directory {directory} does not exist (examples: deploy/recipes/)")
    return RecipesConfig(directory)


def _robot(t: Table) -> RobotConfig:
    config = RobotConfig(
        frame_file=t.path("frame_file", None),
        publish_frame=t.choice("publish_frame", ("table", "robot"), "table"),
        nozzle_offset_mm=t.number("nozzle_offset_mm", 0.0, low=-50, high=50),
    )
    t.finish()
    return config


def _opcua(t: Table) -> OpcUaConfig:
    config = OpcUaConfig(
        enabled=t.get("enabled", bool, False),
        endpoint=t.get("endpoint", str, OpcUaConfig.endpoint),
        cell_name=t.get("cell_name", str, "cell"),
        allow_anonymous=t.get("allow_anonymous", bool, False),
        username=t.get("username", str, None),
        password_file=t.path("password_file", None),
        history=int(t.number("history", 100, low=1, high=100000)),
    )
    t.finish()
    if not config.endpoint.startswith("opc.tcp://"):
        raise t.fail("endpoint", f"{config.endpoint!r} is not an opc.tcp:// URL, e.g. opc.tcp://0.0.0.0:4840/cellctl/")
    if config.enabled and not config.allow_anonymous and (config.username is None or config.password_file is None):
        raise t.fail(
            "username",
            "OPC UA without anonymous access needs username and password_file (or allow_anonymous = true)",
        )
    if config.password_file is not None and not config.password_file.is_file():
        raise t.fail("password_file", f"{config.password_file} does not exist")
    return config
