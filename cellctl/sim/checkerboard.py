"""Checkerboard image pairs of a known rig, for testing and demonstrating stereo calibration.

Each pair shows a flat checkerboard at a random pose in front of the rig, imaged through the rig's exact
camera model (intrinsics, lens distortion, relative pose) with defocus blur and sensor noise. A few pairs
are deliberately bad, the way real captures go wrong, and a calibration must reject them:

- "outside": the board is partly outside one image, so its corners cannot all be found;
- "blur": the board was moving while the two unsynchronised cameras exposed, so both images are heavily
  motion-blurred and show the board at different positions.

Rendering works backwards from the pixels: every pixel's ray (the lens model inverted once with
cv2.undistortPoints) is intersected with the board plane through the plane's homography, and the board
texture is sampled there with cv2.remap. That keeps a 1280x1024 image to a few tens of milliseconds.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from cellctl.calib.board import Checkerboard
from cellctl.vision.calibration import Calibration

BAD_KINDS: tuple[str, ...] = ("outside", "blur")
_BACKGROUND = 70  # grey level of the table around the board
_DARK, _LIGHT = 30, 220  # grey levels of the printed squares


@dataclass(frozen=True)
class BoardPose:
    """Pose of the board in the left camera frame: x_cam = rotation @ x_board + translation (mm)."""

    rotation: np.ndarray
    translation: np.ndarray

    def moved(self, shift_mm: np.ndarray, turn_rad: np.ndarray) -> BoardPose:
        """The pose after a small motion: a translation and a rotation about the board's own axes."""
        turn = cv2.Rodrigues(np.asarray(turn_rad, np.float64).reshape(3, 1))[0]
        return BoardPose(self.rotation @ turn, self.translation + np.asarray(shift_mm, np.float64).reshape(3, 1))


@dataclass(frozen=True)
class BoardTexture:
    """The printed board as an image, already blurred: `texel_mm` mm per texel."""

    image: np.ndarray
    texel_mm: float


@dataclass
class BoardPair:
    """One simulated capture: the two images, the true board pose and whether it is a bad pair."""

    name: str  # "01", "02", ...: the NN of left_NN.png / right_NN.png
    left: np.ndarray
    right: np.ndarray
    pose: BoardPose
    kind: str = "good"  # "good" or one of BAD_KINDS


class BoardCameras:
    """The rig's two cameras looking at the board: where its corners appear, and its image at a pose."""

    def __init__(self, rig: Calibration, board: Checkerboard, blur_sigma: float) -> None:
        self.rig, self.board, self.blur_sigma = rig, board, blur_sigma
        self._rays: dict[str, np.ndarray] = {}

    def render_image(self, pose: BoardPose, side: str, texture: BoardTexture | None = None) -> np.ndarray:
        """The noiseless image of the board at `pose` in one camera, float32 grey levels.

        `texture` defaults to the board blurred for this pose (see `texture_for`).
        """
        texture = texture or self.texture_for(pose)
        rotation, translation = self.in_camera(pose, side)
        # Homography from the board plane (X, Y, 1) to normalised camera coordinates; its inverse maps
        # each pixel's ray back onto the board.
        to_board = np.linalg.inv(np.column_stack([rotation[:, 0], rotation[:, 1], translation.ravel()]))
        rays = self._pixel_rays(side)
        board = rays @ to_board.T
        w = board[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            # Rays that meet the plane behind the camera (w <= 0) see background: send them off-texture.
            scale = np.where(w > 0, 1.0 / (w * texture.texel_mm), np.nan)
        # Texel i covers [i, i + 1) texels from the outline's corner, so its centre sits at i + 0.5.
        origin = self.board.outline()[0] / texture.texel_mm + 0.5
        map_x = np.nan_to_num(board[..., 0] * scale - origin[0], nan=-1e6).astype(np.float32)
        map_y = np.nan_to_num(board[..., 1] * scale - origin[1], nan=-1e6).astype(np.float32)
        return cv2.remap(
            texture.image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=_BACKGROUND
        )

    def texture_for(self, pose: BoardPose) -> BoardTexture:
        """The board blurred so that its image at `pose` is blurred by at least `blur_sigma` px.

        The blur belongs before the pixel sampling, as in a real lens: blurring a sharp rendering afterwards
        leaves the aliasing of the sharp edges in, and that shifts the corners by up to 0.2 px. The
        blur is set where the board looks finest - its farthest point, across the tilt - and
        is a little stronger elsewhere, as depth of field would make it.
        """
        finest_mm_per_px = 0.0
        for side in ("left", "right"):
            rotation, translation = self.in_camera(pose, side)
            depth = (self.board.outline() @ rotation.T + translation.T)[:, 2].max()
            facing = max(abs(rotation[2, 2]), 0.3)  # cosine of the tilt between board normal and view axis
            K = self.rig.K1 if side == "left" else self.rig.K2
            finest_mm_per_px = max(finest_mm_per_px, depth / (min(K[0, 0], K[1, 1]) * facing))
        return self._board_texture(self.blur_sigma * finest_mm_per_px)

    def projected_corners(self, pose: BoardPose, side: str) -> np.ndarray:
        """Where the board's inner corners truly appear in one camera (N x 2 px)."""
        return self.project(self.board.object_points().astype(np.float64), pose, side)

    def _board_texture(self, blur_mm: float) -> BoardTexture:
        # 1.5 texels per blur sigma is enough for bilinear sampling to follow the blurred edges smoothly;
        # a whole number of texels per square puts every edge exactly on a texel boundary.
        texel_mm = self.board.square_mm / np.ceil(self.board.square_mm / (blur_mm / 1.5))
        outline = self.board.outline()
        size_mm = outline[2, :2] - outline[0, :2]
        width, height = (int(np.ceil(v / texel_mm)) for v in size_mm)
        # Square index of each texel centre; the square between the first four inner corners is dark (the
        # convention the corner detection uses to number corners the same way in both cameras).
        xs = (outline[0, 0] + (np.arange(width) + 0.5) * texel_mm) / self.board.square_mm
        ys = (outline[0, 1] + (np.arange(height) + 0.5) * texel_mm) / self.board.square_mm
        col, row = np.floor(xs).astype(int), np.floor(ys).astype(int)
        in_x = (col >= -1) & (col <= self.board.cols - 1)
        in_y = (row >= -1) & (row <= self.board.rows - 1)
        dark = ((col[None, :] + row[:, None]) % 2 == 0) & in_x[None, :] & in_y[:, None]
        sharp = np.where(dark, _DARK, _LIGHT).astype(np.float32)
        return BoardTexture(cv2.GaussianBlur(sharp, (0, 0), 1.5, borderType=cv2.BORDER_REPLICATE), texel_mm)

    def _pixel_rays(self, side: str) -> np.ndarray:
        """Homogeneous normalised ray (x, y, 1) of every pixel of one camera, lens distortion removed."""
        if side not in self._rays:
            K, D = (self.rig.K1, self.rig.D1) if side == "left" else (self.rig.K2, self.rig.D2)
            width, height = self.rig.image_size
            grid = np.stack(np.meshgrid(np.arange(width), np.arange(height)), axis=-1).reshape(-1, 1, 2)
            criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
            normalised = cv2.undistortPoints(grid.astype(np.float64), K, D, criteria=criteria).reshape(height, width, 2)
            self._rays[side] = np.concatenate([normalised, np.ones((height, width, 1))], axis=-1)
        return self._rays[side]

    def in_camera(self, pose: BoardPose, side: str) -> tuple[np.ndarray, np.ndarray]:
        if side == "left":
            return pose.rotation, pose.translation
        return self.rig.R @ pose.rotation, self.rig.R @ pose.translation + self.rig.T

    def project(self, points: np.ndarray, pose: BoardPose, side: str) -> np.ndarray:
        rotation, translation = self.in_camera(pose, side)
        K, D = (self.rig.K1, self.rig.D1) if side == "left" else (self.rig.K2, self.rig.D2)
        projected, _ = cv2.projectPoints(points, cv2.Rodrigues(rotation)[0], translation, K, D)
        return projected.reshape(-1, 2)


@dataclass
class CheckerboardSimulator:
    """Renders checkerboard pairs as the rig `rig` would capture them."""

    rig: Calibration
    board: Checkerboard
    seed: int = 0
    noise_sigma: float = 3.0  # sensor noise, grey levels (a typical USB camera)
    blur_sigma: float = 0.6  # optical blur, px, where the board is farthest and most oblique (more elsewhere)
    distance_mm: tuple[float, float] = (420.0, 680.0)  # range of board distances
    max_tilt_rad: float = 0.6  # ~35 degrees: Zhang's method needs tilted views to pin down the focal length
    _rng: np.random.Generator = field(init=False, repr=False)
    cameras: BoardCameras = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.seed)
        self.cameras = BoardCameras(self.rig, self.board, self.blur_sigma)

    def render_image(self, pose: BoardPose, side: str, texture: BoardTexture | None = None) -> np.ndarray:
        """The noiseless image of the board at `pose` in one camera, float32 grey levels (BoardCameras)."""
        return self.cameras.render_image(pose, side, texture)

    def texture_for(self, pose: BoardPose) -> BoardTexture:
        """The board blurred so that its image at `pose` is blurred by at least `blur_sigma` px."""
        return self.cameras.texture_for(pose)

    def projected_corners(self, pose: BoardPose, side: str) -> np.ndarray:
        """Where the board's inner corners truly appear in one camera (N x 2 px)."""
        return self.cameras.projected_corners(pose, side)

    def pairs(self, good: int, bad: tuple[str, ...] = BAD_KINDS) -> list[BoardPair]:
        """`good` sound pairs with the bad pairs of the given kinds spread among them."""
        unknown = [kind for kind in bad if kind not in BAD_KINDS]
        if unknown:
            raise ValueError(f"unknown bad pair kind {unknown[0]!r}: choose from {', '.join(BAD_KINDS)}")
        kinds = ["good"] * good
        for i, kind in enumerate(bad):
            # Spread the bad pairs evenly so they do not all sit at the end of the list.
            kinds.insert(min(len(kinds), (i + 1) * (good + len(bad)) // (len(bad) + 1)), kind)
        return [self.render(f"{i + 1:02d}", kind) for i, kind in enumerate(kinds)]

    def render(self, name: str, kind: str = "good") -> BoardPair:
        """Render one pair of the given kind at a fresh random pose."""
        if kind == "good":
            pose = self._visible_pose()
            left, right = self._capture(pose, "left"), self._capture(pose, "right")
        elif kind == "outside":
            pose = self._outside_pose()
            left, right = self._capture(pose, "left"), self._capture(pose, "right")
        elif kind == "blur":
            pose = self._visible_pose()
            left, right = self._moving_capture(pose)
        else:
            raise ValueError(f"unknown pair kind {kind!r}: use 'good' or one of {', '.join(BAD_KINDS)}")
        return BoardPair(name, left, right, pose, kind)

    # -- poses ------------------------------------------------------------------------------------

    def _random_pose(self, lateral_mm: float) -> BoardPose:
        tilt = self._rng.uniform(-self.max_tilt_rad, self.max_tilt_rad, 2)
        spin = self._rng.uniform(-0.35, 0.35)
        rotation = cv2.Rodrigues(np.array([tilt[0], tilt[1], spin]))[0]
        distance = self._rng.uniform(*self.distance_mm)
        centre = np.array([self._rng.uniform(-lateral_mm, lateral_mm), self._rng.uniform(-lateral_mm, lateral_mm), 0])
        centre = centre * distance / self.distance_mm[1] + np.array([self.rig.baseline_mm / 2, 0, distance])
        board_centre = np.array([(self.board.cols - 1) / 2, (self.board.rows - 1) / 2, 0]) * self.board.square_mm
        return BoardPose(rotation, (centre - rotation @ board_centre).reshape(3, 1))

    def _visible_pose(self) -> BoardPose:
        """A random pose with the whole printed board inside both images."""
        for _ in range(1000):
            pose = self._random_pose(lateral_mm=250.0)
            if all(self._inside(pose, side, margin_px=8) for side in ("left", "right")):
                return pose
        raise ValueError("no board pose fits in both images: use a smaller board or a longer distance")

    def _outside_pose(self) -> BoardPose:
        """A random pose with between a quarter and a half of the inner corners outside the left image."""
        width, height = self.rig.image_size
        for _ in range(5000):
            pose = self._random_pose(lateral_mm=450.0)
            corners = self.projected_corners(pose, "left")
            inside = (corners[:, 0] >= 0) & (corners[:, 0] < width) & (corners[:, 1] >= 0) & (corners[:, 1] < height)
            if 0.5 <= inside.mean() <= 0.75:
                return pose
        raise ValueError("no board pose is partly outside the image: the board is too small for this rig")

    def _inside(self, pose: BoardPose, side: str, margin_px: float) -> bool:
        width, height = self.rig.image_size
        # Sample the outline densely: with lens distortion a straight board edge is curved in the image.
        outline = self.board.outline(margin_squares=0.5)
        edges = np.concatenate([np.linspace(a, b, 20) for a, b in zip(outline, np.roll(outline, -1, axis=0))])
        rotation, translation = self.cameras.in_camera(pose, side)
        if np.any((edges @ rotation.T + translation.T)[:, 2] <= 0):
            return False
        points = self.cameras.project(edges, pose, side)
        limit = np.array([width, height]) - margin_px
        return bool(np.all(points >= margin_px) and np.all(points < limit))

    # -- imaging ----------------------------------------------------------------------------------

    def _capture(self, pose: BoardPose, side: str) -> np.ndarray:
        return self._sensor(self.render_image(pose, side))

    def _moving_capture(self, pose: BoardPose) -> tuple[np.ndarray, np.ndarray]:
        """The board sliding ~6 mm and turning slightly while the two cameras expose at different times."""
        direction = self._rng.normal(size=3)
        direction[2] *= 0.2
        shift = 6.0 * direction / np.linalg.norm(direction)
        turn = self._rng.normal(scale=0.01, size=3)
        steps = np.linspace(0.0, 1.0, 9)
        texture = self.texture_for(pose)
        # The right camera starts its exposure when the left one is half-way through.
        frames = {
            side: np.mean([self.render_image(pose.moved(s * shift, s * turn), side, texture) for s in start + steps], 0)
            for side, start in (("left", 0.0), ("right", 0.5))
        }
        return self._sensor(frames["left"]), self._sensor(frames["right"])

    def _sensor(self, image: np.ndarray) -> np.ndarray:
        noisy = image + self.noise_sigma * self._rng.standard_normal(image.shape, dtype=np.float32)
        return np.clip(noisy + 0.5, 0, 255).astype(np.uint8)


def write_pairs(pairs: list[BoardPair], out_dir: str | os.PathLike[str]) -> list[Path]:
    """Write pairs as left_NN.png / right_NN.png; returns the written paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for pair in pairs:
        for side, image in (("left", pair.left), ("right", pair.right)):
            path = out / f"{side}_{pair.name}.png"
            if not cv2.imwrite(str(path), image):
                raise ValueError(f"cannot write {path}: check the directory is writable")
            written.append(path)
    return written
