"""The rigid transform from the cell's table frame to the robot's base frame, taught from touched points.

    fit = solve_robot_frame(cell_points, robot_points, tolerance_mm=1.0)
    if isinstance(fit, FrameFit):
        robot_xyz = fit.transform.apply(table_xyz)
        robot_normals = fit.transform.rotate(table_normals)

The robot touches (or presents a target at) N >= 3 points whose positions the cameras also measure; the
least-squares rigid transform between the two point sets is Kabsch's (an SVD of the cross-covariance,
with the reflection guard). Touch-up is done by hand, so a wrong point (a typo, the wrong tool, the wrong
target) is expected: every non-degenerate triple of points proposes a transform, the one most other
points agree with (residual <= tolerance) wins, and the transform is refitted on its agreeing points until
the set stops changing. Points that disagree are reported, never silently used. With fewer than four
points no point can be checked against the others, which the result says (`checked` is False).
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

#: Residual above which a taught point is rejected (mm): hand touch-up on a sharp tip plus the cameras'
#: own error at a target; a bump of the cell moves points by more than this.
DEFAULT_TOLERANCE_MM = 1.0
#: A triple of points spanning less than this (smallest singular value of the centred set, mm) leaves the
#: rotation about their line undetermined.
MIN_SPREAD_MM = 5.0
#: Triples tried at most (all of them up to 14 points); beyond, a fixed-seed random sample of this many.
MAX_TRIPLES = 400
FILE_FORMAT = "cellctl-robot-frame/1"


@dataclass(frozen=True)
class RigidTransform:
    """x_to = rotation @ x_from + translation (mm)."""

    rotation: np.ndarray  # 3 x 3, proper rotation
    translation: np.ndarray  # 3

    @classmethod
    def identity(cls) -> RigidTransform:
        return cls(np.eye(3), np.zeros(3))

    @classmethod
    def from_matrix(cls, matrix: ArrayLike) -> RigidTransform:
        m = np.asarray(matrix, dtype=float)
        if m.shape != (4, 4) or not np.allclose(m[3], [0, 0, 0, 1]):
            raise ValueError(f"a rigid transform needs a 4 x 4 matrix with last row 0 0 0 1, got shape {m.shape}")
        rotation = m[:3, :3]
        if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) or np.linalg.det(rotation) < 0:
            raise ValueError("the 3 x 3 part of the transform is not a proper rotation")
        return cls(rotation, m[:3, 3].copy())

    @property
    def matrix(self) -> np.ndarray:
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = self.rotation, self.translation
        return m

    def apply(self, points: ArrayLike) -> np.ndarray:
        """Points (N x 3) in the target frame."""
        return np.asarray(points, dtype=float) @ self.rotation.T + self.translation

    def rotate(self, vectors: ArrayLike) -> np.ndarray:
        """Directions (N x 3, e.g. normals) in the target frame: rotation only."""
        return np.asarray(vectors, dtype=float) @ self.rotation.T

    def inverse(self) -> RigidTransform:
        return RigidTransform(self.rotation.T, -self.rotation.T @ self.translation)

    def angle_to_deg(self, other: RigidTransform) -> float:
        """Angle of the rotation between this transform's rotation and another's (degrees)."""
        relative = self.rotation.T @ other.rotation
        return math.degrees(math.acos(float(np.clip((np.trace(relative) - 1.0) / 2.0, -1.0, 1.0))))


def kabsch(source: ArrayLike, target: ArrayLike) -> RigidTransform:
    """Least-squares rigid transform mapping source points onto target points (both N x 3, N >= 3)."""
    src, dst = np.asarray(source, dtype=float), np.asarray(target, dtype=float)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise ValueError(f"kabsch needs two N x 3 point sets with N >= 3, got {src.shape} and {dst.shape}")
    src_mean, dst_mean = src.mean(axis=0), dst.mean(axis=0)
    covariance = (dst - dst_mean).T @ (src - src_mean)
    u, _, vt = np.linalg.svd(covariance)
    reflect = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])  # a mirror is no rigid motion
    rotation = u @ reflect @ vt
    return RigidTransform(rotation, dst_mean - rotation @ src_mean)


@dataclass(frozen=True)
class FrameFit:
    """A solved table -> robot transform and how well each taught point agrees with it."""

    transform: RigidTransform
    residuals_mm: np.ndarray  # N, distance between each robot point and its transformed cell point
    inliers: np.ndarray  # N bool: points the transform was fitted on
    tolerance_mm: float
    checked: bool  #: False with 3 points: none could be checked against the others

    @property
    def rms_mm(self) -> float:
        """Root mean square residual of the points used."""
        return float(np.sqrt(np.mean(self.residuals_mm[self.inliers] ** 2)))

    @property
    def rejected(self) -> list[int]:
        """0-based indices of the points left out."""
        return [int(i) for i in np.flatnonzero(~self.inliers)]


@dataclass(frozen=True)
class FrameFitFailed:
    """No transform could be trusted, and why (for the operator)."""

    reason: str


def solve_robot_frame(
    cell_points: ArrayLike, robot_points: ArrayLike, tolerance_mm: float = DEFAULT_TOLERANCE_MM
) -> FrameFit | FrameFitFailed:
    """The table -> robot base transform from corresponding points, with disagreeing points rejected."""
    cell, robot = np.asarray(cell_points, dtype=float), np.asarray(robot_points, dtype=float)
    if cell.shape != robot.shape or cell.ndim != 2 or cell.shape[1] != 3:
        return FrameFitFailed(f"need two N x 3 point lists of the same length, got {cell.shape} and {robot.shape}")
    if len(cell) < 3:
        return FrameFitFailed(f"{len(cell)} points taught: at least 3 are needed (4 or more to check each other)")
    if not np.all(np.isfinite(cell)) or not np.all(np.isfinite(robot)):
        return FrameFitFailed("a taught point has a missing or non-finite coordinate")
    if tolerance_mm <= 0:
        raise ValueError(f"tolerance {tolerance_mm} mm must be positive")
    if _spread_mm(cell) < MIN_SPREAD_MM:
        return FrameFitFailed(
            f"the points lie on a line (spread {_spread_mm(cell):.1f} mm < {MIN_SPREAD_MM:g} mm): "
            "teach points spread over the table, not along one edge"
        )
    inliers = _best_consensus(cell, robot, tolerance_mm)
    if inliers is None:
        return FrameFitFailed(
            f"no three points agree with each other within {tolerance_mm:g} mm: check that robot and cell "
            "coordinates are listed in the same order and in mm"
        )
    for _ in range(10):  # refit on the consensus until it stops changing
        transform = kabsch(cell[inliers], robot[inliers])
        residuals = np.linalg.norm(transform.apply(cell) - robot, axis=1)
        refreshed = residuals <= tolerance_mm
        if np.count_nonzero(refreshed) < 3 or _spread_mm(cell[refreshed]) < MIN_SPREAD_MM:
            break
        if np.array_equal(refreshed, inliers):
            break
        inliers = refreshed
    transform = kabsch(cell[inliers], robot[inliers])
    residuals = np.linalg.norm(transform.apply(cell) - robot, axis=1)
    if len(cell) > 3 and np.count_nonzero(inliers) < max(3, (len(cell) + 1) // 2):
        return FrameFitFailed(
            f"only {np.count_nonzero(inliers)} of {len(cell)} points agree within {tolerance_mm:g} mm: "
            "more points are wrong than right, re-teach"
        )
    return FrameFit(transform, residuals, inliers, tolerance_mm, checked=len(cell) > 3)


def _spread_mm(points: np.ndarray) -> float:
    """Second singular value of the centred points: how far they are from lying on one line (mm)."""
    if len(points) < 3:
        return 0.0
    return float(np.linalg.svd(points - points.mean(axis=0), compute_uv=False)[1] / math.sqrt(len(points)))


def _best_consensus(cell: np.ndarray, robot: np.ndarray, tolerance_mm: float) -> np.ndarray | None:
    """Inlier mask of the triple-proposed transform most points agree with (ties: smallest residual sum)."""
    triples = list(itertools.combinations(range(len(cell)), 3))
    if len(triples) > MAX_TRIPLES:
        rng = np.random.default_rng(0)  # reproducible: the same points always give the same transform
        triples = [tuple(rng.choice(len(cell), 3, replace=False)) for _ in range(MAX_TRIPLES)]
    best: tuple[int, float] | None = None
    best_mask: np.ndarray | None = None
    for triple in triples:
        index = list(triple)
        if _spread_mm(cell[index]) < MIN_SPREAD_MM:
            continue
        transform = kabsch(cell[index], robot[index])
        residuals = np.linalg.norm(transform.apply(cell) - robot, axis=1)
        mask = residuals <= tolerance_mm
        score = (int(np.count_nonzero(mask)), -float(residuals[mask].sum()))
        if np.count_nonzero(mask) >= 3 and (best is None or score > best):
            best, best_mask = score, mask
    return best_mask


# ---- the file beside the calibration -------------------------------------------------------------


def save_robot_frame(path: Path, fit: FrameFit, note: str = "") -> None:
    """Write the transform and its teach report as JSON (human-readable, diff-able)."""
    document = {
        "format": FILE_FORMAT,
        "from": "table frame of the cell (mm; origin under the left camera, z up from the table)",
        "to": "robot base frame (mm)",
        "table_to_robot": np.round(fit.transform.matrix, 9).tolist(),
        "teach": {
            "points": len(fit.residuals_mm),
            "rejected": fit.rejected,
            "residuals_mm": np.round(fit.residuals_mm, 4).tolist(),
            "rms_mm": round(fit.rms_mm, 4),
            "tolerance_mm": fit.tolerance_mm,
            "checked": fit.checked,
            "note": note,
        },
    }
    path.write_text(json.dumps(document, indent=2) + "\n", encoding="utf-8")


def load_robot_frame(path: Path) -> RigidTransform:
    """The table -> robot transform stored by save_robot_frame; ValueError naming the problem."""
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"robot frame file {path} is not valid JSON: {exc}") from None
    if not isinstance(document, dict) or document.get("format") != FILE_FORMAT:
        raise ValueError(f"{path} is not a robot frame file ({FILE_FORMAT}): run `cellctl teach-robot` to make one")
    try:
        return RigidTransform.from_matrix(document["table_to_robot"])
    except (KeyError, ValueError, TypeError) as exc:
        raise ValueError(f"robot frame file {path}: bad table_to_robot matrix: {exc}") from None
