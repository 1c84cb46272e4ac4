"""What the cameras are: backend, devices, size and timing (read from the [cameras] table of the cell config)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

# Their home: the measurement assumes the first for a replayed mean, and its glue heights' limit is calibrated on both.
from cellctl.vision.defaults import AVERAGED_FRAMES, MORE_EXPOSURES

MAX_AVERAGED_FRAMES = 16


def frames_option(frames: int | None) -> int:
    """A benchmark's `--frames` (None: the cycle's AVERAGED_FRAMES); ValueError outside 1..MAX_AVERAGED_FRAMES."""
    return _count_option("--frames", frames, AVERAGED_FRAMES, 1, "exposures averaged per measurement")


def retry_frames_option(frames: int | None) -> int:
    """A benchmark's `--retry-frames` (None: the cycle's MORE_EXPOSURES; 0: never); ValueError outside
    0..MAX_AVERAGED_FRAMES."""
    return _count_option(
        "--retry-frames", frames, MORE_EXPOSURES, 0, "exposures averaged in all on a second measurement; 0: none"
    )


def _count_option(flag: str, frames: int | None, default: int, low: int, meaning: str) -> int:
    """An exposure count given as `flag` (None: `default`); ValueError outside low..MAX_AVERAGED_FRAMES."""
    frames = default if frames is None else frames
    if not low <= frames <= MAX_AVERAGED_FRAMES:
        raise ValueError(f"{flag} must be {low}..{MAX_AVERAGED_FRAMES} ({meaning}), got {frames}")
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
    # Pairs averaged in all when a cycle is refused for its glue heights' precision and more may pass: the cycle
    # grabs the difference and measures once more (cellctl.service.measuring); 0, or not above averaged_frames: never.
    retry_averaged_frames: int = MORE_EXPOSURES
    simulated: SimulatedCameraConfig = field(default_factory=SimulatedCameraConfig)
