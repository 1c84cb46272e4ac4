"""The glue path as the robot gets it: which frame, how far off the surface, at most MAX_GLUE_POINTS.

The measurement gives points and unit normals in the table frame. The cell publishes them either in that
frame or, once `cellctl teach-robot` has stored the table -> robot base transform, in the robot's base
frame (points transformed, normals rotated). A nozzle stand-off moves each point along its normal, so the
robot can follow the published points without its own offset; the PLC reads the frame and the offset
applied in map v2 (registers 19-23).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cellctl.service.config import CellConfig, ConfigError
from cellctl.vision.robot_frame import RigidTransform, load_robot_frame
from firmware_io.registers import MAX_GLUE_POINTS, GlueFrame


@dataclass(frozen=True)
class GluePathOut:
    """Points and normals ready to publish, with the frame they are in."""

    points: np.ndarray  # N x 3 mm
    normals: np.ndarray  # N x 3 unit
    frame: GlueFrame
    nozzle_offset_mm: float


@dataclass(frozen=True)
class GlueOutput:
    """How the glue path leaves the cell."""

    table_to_robot: RigidTransform | None = None  # None: points stay in the table frame
    nozzle_offset_mm: float = 0.0

    @classmethod
    def from_config(cls, config: CellConfig) -> GlueOutput:
        """The configured output; ConfigError if the robot frame is asked for but not taught."""
        robot = config.robot
        if robot.publish_frame == "table":
            return cls(None, robot.nozzle_offset_mm)
        return cls(_load(config.robot_frame_path), robot.nozzle_offset_mm)

    @property
    def frame(self) -> GlueFrame:
        return GlueFrame.TABLE if self.table_to_robot is None else GlueFrame.ROBOT_BASE

    def prepare(self, points: np.ndarray, normals: np.ndarray) -> GluePathOut:
        """Thin to MAX_GLUE_POINTS, move along the normals by the nozzle offset, change frame."""
        keep = thinned(len(points))
        points, normals = np.asarray(points, float)[keep], np.asarray(normals, float)[keep]
        points = points + self.nozzle_offset_mm * normals
        if self.table_to_robot is not None:
            points, normals = self.table_to_robot.apply(points), self.table_to_robot.rotate(normals)
        return GluePathOut(points, normals, self.frame, self.nozzle_offset_mm)


def thinned(count: int) -> np.ndarray:
    """Indices of at most MAX_GLUE_POINTS points, evenly spread along the path."""
    if count <= MAX_GLUE_POINTS:
        return np.arange(count)
    return np.linspace(0, count, MAX_GLUE_POINTS, endpoint=False).astype(int)


def _load(path: Path) -> RigidTransform:
    if not path.is_file():
        raise ConfigError(
            f'[robot] publish_frame = "robot" needs the taught robot frame {path}: run `cellctl teach-robot` '
            'first, or set publish_frame = "table"'
        )
    try:
        return load_robot_frame(path)
    except ValueError as exc:
        raise ConfigError(f"[robot] {exc}") from None
