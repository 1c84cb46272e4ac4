"""The taught empty table: what the cell looks like with nothing on it, learnt once at set-up.

    taught = teach_table(reconstructor.points_from_disparity(left, right), calib)   # `cellctl teach`
    save_taught(taught, calib_path)        # <calib>.table.npz (images, disparity) + <calib>.table.json
    taught = load_taught(calib_path, calib)
    SoleReconstructor(calib, taught=taught)

Why: a sole is then "what rises above the taught table" and its edge is where the image changed against
the taught reference, whatever the colours of sole and table (docs/measurements.md, Teaching the table).
Everything taught lives in this one place: the table plane, the rectified reference pair, the reference
disparity of the empty fixture, the calibration it was taught with (fingerprint) and when. Each cycle
checks that the table still lies where it was taught (`check_drift`): a moved table or rig must be taught
again, never measured against a stale plane.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cellctl.vision.calibration import Calibration
from cellctl.vision.cloud import StereoCloud
from cellctl.vision.image_noise import CLEAN_IMAGE_NOISE_DN, NOISY_EXPOSURES_DN, image_noise_dn
from cellctl.vision.table import TABLE_INLIER_MM, TableDisparity, TablePlane, find_table, refine_table

FORMAT_VERSION = 1
MIN_TABLE_FRACTION = 0.5  # of the image: the empty table must fill most of the view to be taught
MAX_OBJECT_FRACTION = 0.002  # of the measured points higher than OBJECT_HEIGHT_MM: something lies on the table
OBJECT_HEIGHT_MM = 3.0
# The flatness test reads the table's shape, not one point's depth noise: mean heights over blocks of pixels. A
# warped or stepped fixture spans many blocks; a point's noise (1 mm sd on a rig with a 40 mm baseline, where a
# point-by-point 1.5 mm band kept only 87 % of a flat table) averages out over a block's ~250 points.
FLAT_BLOCK_PX = 16
FLAT_BLOCK_MIN_POINTS = 32  # fewer measured points: the block says nothing about the shape
FLAT_CLIP_MM = 10.0  # a mismatch's height counts no more than this in a block's mean
MIN_FLAT_FRACTION = 0.9  # of the blocks within TABLE_INLIER_MM of the plane
MAX_DRIFT_HEIGHT_MM = 0.4  # the table's median height against the taught plane; heights are wanted to 0.5 mm
MAX_DRIFT_TILT_DEG = 0.15  # over a 300 mm sole, 0.15 degrees is 0.8 mm of height from end to end
DRIFT_SAMPLE_STRIDE = 16  # every 16th measured point (~50000): the median offset to a few micrometres
DRIFT_BAND_MM = 5.0  # points this close to the taught plane are table candidates for the drift check


class TeachError(ValueError):
    """The empty table could not be taught (something on it, too little of it measured, wrong calibration)."""


class NoisyTeachError(TeachError):
    """The empty table could not be taught and the images are noisy: more pairs averaged may teach it."""


@dataclass(frozen=True)
class TaughtTable:
    """The empty fixture as taught: plane and reference pair in the rectified left camera frame."""

    plane: TablePlane
    left: np.ndarray  # rectified reference pair of the empty table, grey float32 (as StereoCloud.rectified)
    right: np.ndarray
    disparity: np.ndarray  # float32 H x W, px, NaN where the matcher measured nothing
    calibration_fingerprint: str
    taught_at: float  # seconds since the epoch (UTC)

    def table_disparity(self, calib: Calibration) -> np.ndarray:
        """The plane's disparity at every rectified left pixel (float32 H x W, table.TableDisparity)."""
        width, height = calib.image_size
        return TableDisparity.of(self.plane, calib).values((slice(0, height), slice(0, width))).astype(np.float32)

    def disparity_band(self, calib: Calibration, max_height_mm: float, margin_px: int = 2) -> tuple[int, int]:
        """(min_disparity, num_disparities) from the table up to `max_height_mm` above it, anywhere in view.

        A point h above the table at depth Z has d = f B / (Z - h cos(tilt)); the band's top takes the
        nearest table point raised by h, which bounds every point of the view.
        """
        table = self.table_disparity(calib)
        fb = calib.focal_px * calib.baseline_mm
        nearest_depth = fb / float(table.max())
        lowest = int(np.floor(float(table.min()))) - margin_px
        highest = int(np.ceil(fb / max(nearest_depth - max_height_mm, 1.0))) + margin_px
        return max(lowest, 0), highest - max(lowest, 0) + 1

    def matches(self, calib: Calibration) -> bool:
        return self.calibration_fingerprint == calibration_fingerprint(calib)


@dataclass(frozen=True)
class Drift:
    """How far the table seen now lies from the taught plane; `problem` says why that is too far (or None)."""

    height_mm: float  # median height of the table points against the taught plane
    tilt_deg: float  # angle between the plane fitted now and the taught one
    table_points: int
    problem: str | None


MAX_AVERAGED_EXPOSURES = 256  # their sum still fits 16 bits


def average_exposures(images: list[np.ndarray]) -> np.ndarray:
    """Several exposures of the same static view averaged (uint8): sensor noise falls by sqrt(count)."""
    if not images or any(image.shape != images[0].shape for image in images):
        raise TeachError("teaching needs one or more images of the same size per camera")
    if len(images) > MAX_AVERAGED_EXPOSURES:
        raise TeachError(f"at most {MAX_AVERAGED_EXPOSURES} exposures can be averaged, got {len(images)}")
    # Summed in 16 bits and rounded through a table: the mean np.round gives (halves to even), without the float
    # copies of every image (a cycle averages four pairs: ~70 ms that way, ~15 this way).
    total = np.zeros(images[0].shape, np.uint16)
    for image in images:
        np.add(total, image, out=total, casting="unsafe")
    rounded = np.round(np.arange(255 * len(images) + 1) / len(images)).astype(np.uint8)
    return np.asarray(rounded[total])


def calibration_fingerprint(calib: Calibration) -> str:
    """Hash of everything that places a rectified pixel in space: a taught table is only valid with it."""
    digest = hashlib.sha256()
    digest.update(np.asarray(calib.image_size, np.int64).tobytes())
    for matrix in (calib.K1, calib.D1, calib.K2, calib.D2, calib.R, calib.T, calib.P1, calib.P2):
        digest.update(np.round(np.asarray(matrix, np.float64), 9).tobytes())
    return digest.hexdigest()[:16]


def flat_fraction(pixels: np.ndarray, heights: np.ndarray, image_size: tuple[int, int]) -> float:
    """Share of the blocks of FLAT_BLOCK_PX pixels with FLAT_BLOCK_MIN_POINTS or more measured points (pixels N x 2,
    x y) whose mean height over the plane (heights N, mm, clipped to FLAT_CLIP_MM) lies within TABLE_INLIER_MM."""
    columns = image_size[0] // FLAT_BLOCK_PX + 1
    block = (pixels[:, 1] // FLAT_BLOCK_PX).astype(np.int64) * columns + (pixels[:, 0] // FLAT_BLOCK_PX).astype(
        np.int64
    )
    counts = np.bincount(block)
    sums = np.bincount(block, weights=np.clip(heights, -FLAT_CLIP_MM, FLAT_CLIP_MM))
    full = counts >= FLAT_BLOCK_MIN_POINTS
    if not full.any():
        return 0.0
    return float(np.mean(np.abs(sums[full] / counts[full]) < TABLE_INLIER_MM))


def teach_table(
    cloud: StereoCloud, calib: Calibration, now: float | None = None, exposure_noise: float | None = None
) -> TaughtTable:
    """The taught table from one measured pair of the EMPTY fixture; TeachError if it is not empty or not seen.
    exposure_noise: what averaging the pair's exposures removed (`image_noise.exposure_noise_dn`), if known: a
    refusal names a noisy camera by it."""
    width, height = cloud.image_size
    if cloud.rectified is None:
        raise TeachError("teaching needs the rectified pair of a stereo measurement, not a cloud from elsewhere")
    fraction = len(cloud.points) / float(width * height)
    if fraction < MIN_TABLE_FRACTION:
        remedy = _noise_remedy(cloud.rectified[0], exposure_noise)
        raise (NoisyTeachError if remedy else TeachError)(
            f"only {100 * fraction:.0f} % of the view measured (need {100 * MIN_TABLE_FRACTION:.0f} %): "
            + (remedy or "check lighting, focus and that the cameras see the table")
        )
    plane = find_table(cloud.points)
    if plane is None:
        raise TeachError("no table plane found: the empty table must fill most of the view")
    plane = refine_table(cloud, plane)
    heights = plane.heights(cloud.points)
    raised = float(np.mean(heights > OBJECT_HEIGHT_MM))
    if raised > MAX_OBJECT_FRACTION:
        remedy = _noise_remedy(cloud.rectified[0], exposure_noise)
        raise (NoisyTeachError if remedy else TeachError)(
            f"{100 * raised:.1f} % of the view lies more than {OBJECT_HEIGHT_MM:g} mm above the table: remove "
            "everything from the fixture" + (f"; if it is empty, {remedy}" if remedy else " and teach again")
        )
    if flat_fraction(cloud.pixels, heights, cloud.image_size) < MIN_FLAT_FRACTION:
        raise TeachError("the measured view is not one flat table: teach with the empty, flat fixture")
    disparity = np.full((height, width), np.nan, np.float32)
    x, y = np.round(cloud.pixels).astype(int).T
    disparity[y, x] = cloud.disparity
    left, right = cloud.rectified
    return TaughtTable(
        plane, left, right, disparity, calibration_fingerprint(calib), time.time() if now is None else now
    )


def _noise_remedy(grey: np.ndarray, exposure_noise: float | None = None) -> str | None:
    """The remedy when the images are noisier than a clean camera's, else None. Noise leaves a matcher with holes
    and stray matches above the table (a 6 DN sensor: 24 % of the view measured from one pair; averaged over
    four, 2.6 % of it 3 mm above the table; over sixteen, taught). The mean of the pairs may read clean on its own
    (a sensor three times as noisy as the simulator's: four pairs left 0.2-0.4 % of the view above the table),
    so what averaging removed (`exposure_noise`) is read too."""
    more = (
        "teach with more pairs of the empty table (four times as many halve the noise), or check exposure, gain and "
        "lighting"
    )
    noise = image_noise_dn(grey)
    if noise > CLEAN_IMAGE_NOISE_DN:
        return f"the images are noisy ({noise:.1f} DN, a clean camera reads under {CLEAN_IMAGE_NOISE_DN:g}): {more}"
    if exposure_noise is not None and exposure_noise > NOISY_EXPOSURES_DN:
        return (
            f"the camera is noisy (its exposures differ from their mean by {exposure_noise:.1f} DN, a clean "
            f"camera's by under {NOISY_EXPOSURES_DN:g}): {more}"
        )
    return None


def check_drift(taught: TaughtTable, points: np.ndarray, exclude: np.ndarray | None = None) -> Drift:
    """Whether the table under the current cloud (camera frame, N x 3) still lies on the taught plane.

    Points within DRIFT_BAND_MM of the taught plane, minus `exclude` (bool N, e.g. the sole and its
    surroundings), are the table now; their median height and the tilt of a plane fitted to them are
    compared with the taught plane.
    """
    # Without `exclude`, every DRIFT_SAMPLE_STRIDE-th row read in place: the rows (and the strides) a mask of all
    # points would give, without copying the ~5 10^5 points first.
    sample = points[::DRIFT_SAMPLE_STRIDE] if exclude is None else points[~exclude][::DRIFT_SAMPLE_STRIDE]
    heights = taught.plane.heights(sample)
    near = np.abs(heights) < DRIFT_BAND_MM
    if np.count_nonzero(near) < 1000:
        return Drift(float("nan"), float("nan"), int(near.sum()), "the table is not where it was taught: teach again")
    offset = float(np.median(heights[near]))
    close = np.abs(heights - offset) < TABLE_INLIER_MM
    now = TablePlane.fit(sample[near & close])
    tilt = float(np.degrees(np.arccos(np.clip(abs(now.normal @ taught.plane.normal), -1.0, 1.0))))
    problem = None
    if abs(offset) > MAX_DRIFT_HEIGHT_MM or tilt > MAX_DRIFT_TILT_DEG:
        problem = (
            f"the table lies {offset:+.2f} mm and {tilt:.2f} degrees from where it was taught "
            f"(limits {MAX_DRIFT_HEIGHT_MM:g} mm, {MAX_DRIFT_TILT_DEG:g} degrees): the table or the cameras "
            "moved; teach the empty table again (cellctl teach)"
        )
    return Drift(offset, tilt, int(np.count_nonzero(near & close)), problem)


def taught_paths(calib_path: str | os.PathLike[str]) -> tuple[Path, Path]:
    """(<calib>.table.npz, <calib>.table.json) beside the calibration file."""
    base = Path(calib_path)
    stem = base.with_suffix("") if base.suffix else base
    return Path(f"{stem}.table.npz"), Path(f"{stem}.table.json")


def save_taught(taught: TaughtTable, calib_path: str | os.PathLike[str]) -> tuple[Path, Path]:
    """Write the taught table beside the calibration; returns the two paths written."""
    arrays, meta = taught_paths(calib_path)
    np.savez_compressed(arrays, left=taught.left, right=taught.right, disparity=taught.disparity)
    info = {
        "format": FORMAT_VERSION,
        "plane_normal": [float(v) for v in taught.plane.normal],
        "plane_offset_mm": float(taught.plane.offset),
        "calibration_fingerprint": taught.calibration_fingerprint,
        "taught_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(taught.taught_at)),
        "taught_at_s": taught.taught_at,
        "image_size": [int(taught.disparity.shape[1]), int(taught.disparity.shape[0])],
    }
    meta.write_text(json.dumps(info, indent=2) + "\n")
    return arrays, meta


def load_taught(calib_path: str | os.PathLike[str], calib: Calibration) -> TaughtTable | None:
    """The table taught beside `calib_path`, None if none was taught; TeachError if it does not fit `calib`."""
    arrays, meta = taught_paths(calib_path)
    if not meta.exists() and not arrays.exists():
        return None
    try:
        info = json.loads(meta.read_text())
        with np.load(arrays) as data:
            left, right = data["left"].astype(np.float32), data["right"].astype(np.float32)
            disparity = data["disparity"].astype(np.float32)
        plane = TablePlane(np.asarray(info["plane_normal"], np.float64), float(info["plane_offset_mm"]))
        taught = TaughtTable(
            plane, left, right, disparity, str(info["calibration_fingerprint"]), float(info["taught_at_s"])
        )
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise TeachError(f"taught table {meta} / {arrays} unreadable ({exc}): teach the table again") from None
    if info.get("format") != FORMAT_VERSION:
        raise TeachError(f"taught table {meta} has format {info.get('format')}, need {FORMAT_VERSION}: teach again")
    if not taught.matches(calib):
        raise TeachError(
            f"taught table {meta} was taught with another calibration: teach the empty table again after calibrating"
        )
    return taught
