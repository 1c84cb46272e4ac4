"""Middlebury v2 ("newEval") stereo evaluation: scenes, ground truth and bad-pixel rates.

The four classic scenes (Tsukuba, Venus, Teddy, Cones) are the benchmark of the paper's
Table 3.  The data folder holds, per scene, left/right images, an 8-bit ground truth
(disparity = value / scale, 0 = unknown) and three region masks (nonocc, all, disc) in which
255 marks an evaluated pixel; disc also uses 128 for non-occluded pixels away from
discontinuities, which Middlebury does not count in "disc".  See the data folder's README.txt.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

REGIONS: tuple[str, ...] = ("nonocc", "all", "disc")
BAD_PIXEL_THRESHOLD = 1.0  # pixels; Middlebury v2 and the paper's Table 3 use 1 px
EVALUATED = 255  # mask value of a pixel that counts in a region


@dataclass(frozen=True)
class SceneInfo:
    """Facts of one scene as Middlebury evaluates it (from the data folder's README.txt)."""

    name: str
    scale: int  # ground-truth value = disparity * scale
    min_disparity: int
    num_disparities: int  # evaluated range is min .. min + num - 1
    layout: str = "2001-2003"  # the data set's folder layout (see cellctl.eval.layouts)


SCENES: dict[str, SceneInfo] = {
    info.name: info
    for info in (
        SceneInfo("tsukuba", scale=16, min_disparity=0, num_disparities=16),
        SceneInfo("venus", scale=8, min_disparity=0, num_disparities=20),
        SceneInfo("teddy", scale=4, min_disparity=0, num_disparities=60),
        SceneInfo("cones", scale=4, min_disparity=0, num_disparities=60),
    )
}

# <repo>/cellctl/eval/middlebury.py -> <repo>/../shared/data/middlebury/2001-2003
# ../shared beside the checkout, unless CELLCTL_MIDDLEBURY names another folder (used by
# builds that run from a copy of the tree, such as `make asan`).
DEFAULT_DATA_DIR = Path(
    os.environ.get(
        "CELLCTL_MIDDLEBURY", Path(__file__).resolve().parents[3] / "shared" / "data" / "middlebury" / "2001-2003"
    )
)


@dataclass(frozen=True)
class Scene:
    """One stereo pair with its ground truth and evaluation regions."""

    info: SceneInfo
    left: np.ndarray  # H x W x 3 uint8, BGR
    right: np.ndarray  # H x W x 3 uint8, BGR
    ground_truth: np.ndarray  # H x W float32 disparity of the left image, NaN = unknown
    regions: dict[str, np.ndarray]  # region name -> H x W bool, True = evaluated; "all" is always one

    @property
    def name(self) -> str:
        return self.info.name


@dataclass(frozen=True)
class Score:
    """Bad-pixel rates of one disparity map against one scene's ground truth."""

    bad_percent: dict[str, float]  # region -> % of evaluated pixels that are bad (invalid included)
    invalid_percent: float  # % of the "all" region without a disparity (NaN)

    @property
    def mean_percent(self) -> float:
        """Mean over the scene's regions: the per-scene "mismatch rate" of the paper's Table 3
        (2001/2003), the bad % of the one region where a data set has no masks (2005/2006)."""
        return float(np.mean(list(self.bad_percent.values())))


@dataclass(frozen=True)
class SceneResult:
    """One method run on one scene."""

    method: str
    scene: str
    disparity: np.ndarray  # float32, NaN = invalid
    score: Score
    seconds: float  # wall-clock time of the method call


DisparityMethod = Callable[[np.ndarray, np.ndarray, int, int], np.ndarray]


def resolve_data_dir(data_dir: str | Path | None = None) -> Path:
    """The Middlebury folder to use, checked to hold all four scenes."""
    path = Path(data_dir) if data_dir is not None else DEFAULT_DATA_DIR
    if not path.is_dir():
        hint = "pass --data DIR" if data_dir is None else "check the path"
        raise FileNotFoundError(
            f"Middlebury data folder not found: {path} ({hint}; it must hold tsukuba/, venus/, teddy/, cones/)"
        )
    missing = [name for name in SCENES if not (path / name).is_dir()]
    if missing:
        raise FileNotFoundError(f"Middlebury data folder {path} lacks scene folder(s): {', '.join(missing)}")
    return path


def region_mask(mask_image: np.ndarray) -> np.ndarray:
    """Evaluated pixels of a Middlebury mask image: only 255 counts (disc's 128 does not)."""
    return mask_image == EVALUATED


def ground_truth_disparity(gt_image: np.ndarray, scale: int) -> np.ndarray:
    """Disparity from Middlebury's integer encoding (value / scale), NaN where value 0 = unknown."""
    disparity = gt_image.astype(np.float32) / np.float32(scale)
    disparity[gt_image == 0] = np.nan
    return disparity


def load_scene(name: str, data_dir: str | Path | None = None) -> Scene:
    """Load one scene ("tsukuba", "venus", "teddy" or "cones") from the data folder."""
    if name not in SCENES:
        raise ValueError(f"unknown Middlebury scene {name!r}; choose from {', '.join(SCENES)}")
    info = SCENES[name]
    folder = (Path(data_dir) if data_dir is not None else resolve_data_dir()) / name
    left = _read(folder / "left.png", colour=True)
    right = _read(folder / "right.png", colour=True)
    gt = _read(folder / "gt.png", colour=False)
    regions = {region: region_mask(_read(folder / f"{region}.png", colour=False)) for region in REGIONS}
    for path, image in [("right.png", right), ("gt.png", gt)] + [(f"{r}.png", m) for r, m in regions.items()]:
        if image.shape[:2] != left.shape[:2]:
            raise ValueError(
                f"{folder / path} is {image.shape[1]}x{image.shape[0]}, but left.png is {left.shape[1]}x{left.shape[0]}"
            )
    return Scene(info, left, right, ground_truth_disparity(gt, info.scale), regions)


def load_scenes(names: Iterable[str] | None = None, data_dir: str | Path | None = None) -> list[Scene]:
    """Load several scenes (all four, in Middlebury's order, by default)."""
    root = resolve_data_dir(data_dir)
    return [load_scene(name, root) for name in (names if names is not None else SCENES)]


def _read(path: Path, *, colour: bool) -> np.ndarray:
    if not path.is_file():
        raise FileNotFoundError(f"missing Middlebury file: {path}")
    image = cv2.imread(str(path), cv2.IMREAD_COLOR if colour else cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"cannot decode image {path}")
    if not colour and (image.ndim != 2 or image.dtype != np.uint8):
        raise ValueError(f"{path} must be an 8-bit single-channel PNG, got shape {image.shape} {image.dtype}")
    return image


def bad_pixel_percent(
    disparity: np.ndarray, ground_truth: np.ndarray, region: np.ndarray, threshold: float = BAD_PIXEL_THRESHOLD
) -> float:
    """% of the region's pixels (with known ground truth) where |d - gt| > threshold or d is invalid."""
    evaluated = _evaluated(disparity, ground_truth, region)
    count = np.count_nonzero(evaluated)
    # float64 so that a difference of exactly `threshold` is never rounded across it.
    error = np.abs(disparity[evaluated].astype(np.float64) - ground_truth[evaluated])
    good = np.count_nonzero(error <= threshold)  # NaN compares False: invalid pixels are bad
    return 100.0 * (count - good) / count


def invalid_percent(disparity: np.ndarray, ground_truth: np.ndarray, region: np.ndarray) -> float:
    """% of the region's pixels (with known ground truth) that have no disparity (NaN or inf)."""
    evaluated = _evaluated(disparity, ground_truth, region)
    invalid = np.count_nonzero(~np.isfinite(disparity[evaluated]))
    return 100.0 * invalid / np.count_nonzero(evaluated)


def _evaluated(disparity: np.ndarray, ground_truth: np.ndarray, region: np.ndarray) -> np.ndarray:
    if disparity.shape != ground_truth.shape or region.shape != ground_truth.shape:
        raise ValueError(
            f"disparity {disparity.shape}, ground truth {ground_truth.shape} and region {region.shape} "
            "must have the same shape"
        )
    if region.dtype != np.bool_:
        raise ValueError("region must be a bool mask (use region_mask() on a Middlebury mask image)")
    evaluated = region & np.isfinite(ground_truth)
    if not evaluated.any():
        raise ValueError("the region holds no pixel with known ground truth")
    return evaluated


def score(disparity: np.ndarray, scene: Scene, threshold: float = BAD_PIXEL_THRESHOLD) -> Score:
    """Bad-pixel rates of a disparity map (float, NaN = invalid) in each of the scene's regions."""
    bad = {r: bad_pixel_percent(disparity, scene.ground_truth, m, threshold) for r, m in scene.regions.items()}
    return Score(bad, invalid_percent(disparity, scene.ground_truth, scene.regions["all"]))


def run_method(name: str, method: DisparityMethod, scene: Scene, repeat: int = 1) -> SceneResult:
    """Run a method on a scene's evaluated disparity range, time it and score it.

    With repeat > 1 the method runs that many times and the fastest time is kept: on a
    shared machine the minimum is the figure least disturbed by other load.  The first
    run's map is scored (the methods are deterministic).
    """
    if repeat < 1:
        raise ValueError(f"repeat must be >= 1, got {repeat}")
    output, seconds = _timed(method, scene)
    for _ in range(repeat - 1):
        seconds = min(seconds, _timed(method, scene)[1])
    disparity = np.asarray(output)
    if disparity.shape != scene.ground_truth.shape:
        raise ValueError(
            f"method {name!r} returned a {disparity.shape} map for the {scene.ground_truth.shape} scene {scene.name}"
        )
    disparity = disparity.astype(np.float32, copy=False)
    return SceneResult(name, scene.name, disparity, score(disparity, scene), seconds)


def _timed(method: DisparityMethod, scene: Scene) -> tuple[np.ndarray, float]:
    start = time.perf_counter()
    output = method(scene.left, scene.right, scene.info.min_disparity, scene.info.num_disparities)
    return output, time.perf_counter() - start


def evaluate(
    methods: dict[str, DisparityMethod],
    scenes: list[Scene],
    repeat: int = 1,
    on_run: Callable[[str, Scene], None] | None = None,
) -> list[SceneResult]:
    """Run every method on every scene; `on_run(method, scene)` is called before each run (progress)."""
    results = []
    for name, method in methods.items():
        for scene in scenes:
            if on_run is not None:
                on_run(name, scene)
            results.append(run_method(name, method, scene, repeat))
    return results


def average_percent(results: Iterable[SceneResult]) -> float:
    """Mean of all region rates of the results: over the four 2001/2003 scenes, the mean of the 12 numbers."""
    return float(np.mean([rate for r in results for rate in r.score.bad_percent.values()]))
