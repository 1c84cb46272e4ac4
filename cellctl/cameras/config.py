"""What the cameras are: backend, devices, size and timing (read from the [cameras] table of the cell config)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from cellctl.vision.defaults import AVERAGED_FRAMES  # its home: the measurement assumes it for a replayed mean

MAX_AVERAGED_FRAMES = 16


def frames_option(frames: int | None) -> int:
    """A benchmark's `--frames` (None: the cycle's AVERAGED_FRAMES); ValueError outside 1..MAX_AVERAGED_FRAMES."""
    frames = AVERAGED_FRAMES if frames is None else frames
    if not 1 <= frames <= MAX_AVERAGED_FRAMES:
        raise ValueError(
            f"--frames must be 1..{MAX_AVERAGED_FRAMES} (exposures averaged per measurement), got {frames}"
        )
    return frames


@dataclass(frozen=True)
class SimulatedCameraConfig:
    """Simulated cameras: scenes rendered through the calibration's rig, one seed per grab in turn."""

    seeds: tuple[int, ...] = (1, 2, 3, 4, 5)
    color: str = "white"
    skew_ms: float = 0.0  # added to the right camera's timestamps (fault injection)


@dataclass(frozen=True)
class CameraConfig:
    backend: str
    left: str | None = None  # v4l2: device path, preferably /dev/v4l/by-id/... or a udev symlink
    right: str | None = None
    replay_dir: Path | None = None
    size: tuple[int, int] | None = None  # (width, height); None = the calibration's image size
    pixel_format: str = "MJPEG"
    exposure: float | None = None  # V4L2 exposure_time_absolute units (100 us); None = camera auto
    gain: float | None = None
    sync_tolerance_ms: float = 8.0
    timeout_ms: float = 1000.0
    max_regrabs: int = 4
    averaged_frames: int = AVERAGED_FRAMES
    simulated: SimulatedCameraConfig = field(default_factory=SimulatedCameraConfig)
