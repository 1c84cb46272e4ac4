"""Camera backends behind one interface: FrameSource.grab_pair() -> StereoFrame, or a CameraError.

source = open_frame_source(config.cameras, calib)
frame = source.grab_pair()          # CameraMissing / FrameTimeout / OutOfSync on failure
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from cellctl.cameras.base import CameraError, CameraMissing, FrameSource, FrameTimeout, OutOfSync, StereoFrame
from cellctl.cameras.config import CameraConfig

if TYPE_CHECKING:  # importing it loads OpenCV, which reading a config does not need
    from cellctl.vision.calibration import Calibration

__all__ = [
    "CameraError",
    "CameraMissing",
    "FrameSource",
    "FrameTimeout",
    "OutOfSync",
    "StereoFrame",
    "open_frame_source",
]


def open_frame_source(config: CameraConfig, calib: Calibration | None) -> FrameSource:
    """The backend the config names; nothing is opened yet (a missing camera shows at the first grab).
    Only the simulated cameras need `calib` (they render through it): ValueError without one."""
    tolerance_s = config.sync_tolerance_ms / 1000.0
    if config.backend == "simulated":
        from cellctl.cameras.simulated import SimulatedCameras

        if calib is None:
            raise ValueError("the simulated cameras render through the calibration, which did not load")

        sim = config.simulated
        return SimulatedCameras(
            calib,
            sim.seeds,
            sim.color,
            skew_s=sim.skew_ms / 1000.0,
            sync_tolerance_s=tolerance_s,
            max_regrabs=config.max_regrabs,
            exposures=max(config.averaged_frames, config.retry_averaged_frames),
        )
    if config.backend == "replay":
        from cellctl.cameras.replay import ReplayCameras

        assert config.replay_dir is not None
        return ReplayCameras(config.replay_dir)
    from cellctl.cameras.v4l2 import V4l2Camera, V4l2Cameras

    assert config.left is not None and config.right is not None
    cameras = [
        V4l2Camera(
            device,
            size=config.size,
            pixel_format=config.pixel_format,
            exposure=config.exposure,
            gain=config.gain,
            timeout_s=config.timeout_ms / 1000.0,
        )
        for device in (config.left, config.right)
    ]
    return V4l2Cameras(cameras[0], cameras[1], sync_tolerance_s=tolerance_s, max_regrabs=config.max_regrabs)
