"""Pictures of a Middlebury run: per scene, one PNG grid of disparity and error maps per method.

Top row: the left image and the ground truth.  Then one row per method: its disparity
(colour-mapped over the scene's range, no disparity = black) and its error map (grey left
image where the disparity is within 1 px, red where it is off by more, blue where there is
none; black outside the "all" region, which Middlebury does not evaluate).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from cellctl.eval.middlebury import BAD_PIXEL_THRESHOLD, Scene, SceneResult

BAD_COLOUR = (0, 0, 255)  # BGR red
INVALID_COLOUR = (255, 96, 0)  # BGR blue
LABEL_HEIGHT = 22
GAP = 4


def disparity_colour(disparity: np.ndarray, min_disparity: int, num_disparities: int) -> np.ndarray:
    """BGR picture of a disparity map, colour-mapped over the range; NaN (no disparity) is black."""
    valid = np.isfinite(disparity)
    span = max(num_disparities - 1, 1)
    level = np.clip((np.where(valid, disparity, min_disparity) - min_disparity) * (255.0 / span), 0, 255)
    picture = cv2.applyColorMap(level.astype(np.uint8), cv2.COLORMAP_JET)
    picture[~valid] = 0
    return picture


def error_colour(disparity: np.ndarray, scene: Scene, threshold: float = BAD_PIXEL_THRESHOLD) -> np.ndarray:
    """BGR error map over the "all" region: good = dimmed grey image, bad = red, no disparity = blue."""
    grey = cv2.cvtColor(scene.left, cv2.COLOR_BGR2GRAY) // 2
    picture = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
    evaluated = scene.regions["all"] & np.isfinite(scene.ground_truth)
    invalid = evaluated & ~np.isfinite(disparity)
    with np.errstate(invalid="ignore"):
        bad = evaluated & ~invalid & (np.abs(disparity - scene.ground_truth) > threshold)
    picture[~evaluated] = 0
    picture[bad] = BAD_COLOUR
    picture[invalid] = INVALID_COLOUR
    return picture


def scene_grid(scene: Scene, results: list[SceneResult]) -> np.ndarray:
    """The grid picture of one scene: left image and ground truth, then each method's two maps."""
    info = scene.info
    tiles = [
        (
            _labelled(scene.left, f"{scene.name}: left image"),
            _labelled(
                disparity_colour(scene.ground_truth, info.min_disparity, info.num_disparities),
                f"ground truth (0..{info.min_disparity + info.num_disparities - 1} px)",
            ),
        )
    ]
    for result in results:
        if result.scene != scene.name:
            raise ValueError(f"result of scene {result.scene!r} given for scene {scene.name!r}")
        score = result.score
        tiles.append(
            (
                _labelled(
                    disparity_colour(result.disparity, info.min_disparity, info.num_disparities),
                    f"{result.method}  {result.seconds:.3f} s",
                ),
                _labelled(
                    error_colour(result.disparity, scene),
                    f"bad {score.mean_percent:.2f}%  red >1px  blue none {score.invalid_percent:.1f}%",
                ),
            )
        )
    rows = [_join([left, right], axis=1) for left, right in tiles]
    return _join(rows, axis=0)


def write_scene_grids(scenes: list[Scene], results: list[SceneResult], out_dir: Path) -> list[Path]:
    """Write `middlebury-<scene>.png` per scene into out_dir; returns the paths written."""
    paths = []
    for scene in scenes:
        path = out_dir / f"middlebury-{scene.name}.png"
        grid = scene_grid(scene, [r for r in results if r.scene == scene.name])
        if not cv2.imwrite(str(path), grid):
            raise OSError(f"could not write {path}")
        paths.append(path)
    return paths


def _labelled(picture: np.ndarray, text: str) -> np.ndarray:
    """The picture under a black strip carrying its label."""
    strip = np.zeros((LABEL_HEIGHT, picture.shape[1], 3), np.uint8)
    cv2.putText(strip, text, (4, LABEL_HEIGHT - 7), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (255, 255, 255), 1, cv2.LINE_AA)
    return np.vstack([strip, picture])


def _join(pictures: list[np.ndarray], axis: int) -> np.ndarray:
    """Stack equally sized pictures with a white gap between them."""
    gap_shape = (pictures[0].shape[0], GAP, 3) if axis == 1 else (GAP, pictures[0].shape[1], 3)
    parts: list[np.ndarray] = []
    for picture in pictures:
        if parts:
            parts.append(np.full(gap_shape, 255, np.uint8))
        parts.append(picture)
    return np.concatenate(parts, axis=axis)
