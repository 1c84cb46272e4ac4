"""Simulated sole scenes: a random sole placed on the table under the rig, rendered, and written to disk.

    scene = SoleScene.random(seed=3, color="black", calib=default_rig(), look=look_for(("pointed-toe",), 3))
    pair = scene.render()
    scene.write(out_dir, pair)  # left.png, right.png, truth.json, depth_left.npy, outline.npy, calib.yaml

`true_cloud` turns the rendered true depth into the measured-points form the reconstruction uses, so
the segmentation and measurement can be checked without the stereo matcher in the loop.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from cellctl.sim.look import SceneLook
from cellctl.sim.render import SOLE_MATERIALS, RenderedPair, SceneRenderer, mount_tilt, project, rig_pose
from cellctl.sim.sole import SoleModel, SolePose, SoleShape
from cellctl.vision.calibration import Calibration
from cellctl.vision.reconstruction import StereoCloud

VIEW_MARGIN_PX = 40  # a random sole keeps this far from the edges of both images
OFF_IMAGE_PX = 100  # SceneLook placement "off-image": an end crosses an image's edge by at most this much (~40 mm)
PLACEMENT_ATTEMPTS = 200
# Soles whose toe and heel halves differ by less than this (fraction of the area; the measurement refuses
# below 4 %) are drawn again: a scene should be measurable, and toe and heel tellable apart, by design.
MEASURABLE_HALF_AREA_DIFFERENCE = 0.07
SHAPE_ATTEMPTS = 30


@dataclass
class SoleScene:
    """One sole on the table under the rig."""

    seed: int
    color: str
    calib: Calibration
    camera_pose: np.ndarray  # 4 x 4, table <- left camera
    sole: SoleModel | None
    look: SceneLook = field(default_factory=SceneLook)

    @classmethod
    def random(
        cls, seed: int, color: str = "white", calib: Calibration | None = None, look: SceneLook | None = None
    ) -> SoleScene:
        """A random sole shape at a random pose that both cameras see completely.

        Without `calib` the rig is the look's (the built-in simulated rig unless the look asks for another).
        """
        if color not in SOLE_MATERIALS:
            raise ValueError(f"sole colour must be one of {', '.join(SOLE_MATERIALS)}, got {color!r}")
        look = look or SceneLook()
        from cellctl.sim.rig import rig_for, rig_height_for

        if calib is None:
            calib = rig_for(look.rig)
        rng = np.random.default_rng(seed)
        for _ in range(SHAPE_ATTEMPTS):  # a plain sole always passes at once: the plain scenes stay as they were
            shape = SoleShape.random(rng, look)
            upright = SoleModel(shape, SolePose(0.0, 0.0, 0.0, False))
            if upright.truth().half_area_difference >= MEASURABLE_HALF_AREA_DIFFERENCE:
                break
        camera_pose = rig_pose(calib, rig_height_for(look.rig), mount_tilt(look.rig_tilt_deg))
        half_turn = 180.0 if look.heading == "any" else 35.0
        off_image = look.placement == "off-image"
        for _ in range(PLACEMENT_ATTEMPTS):
            yaw = rng.uniform(-half_turn, half_turn) + (180.0 if rng.random() < 0.5 else 0.0)
            # Off the image: the sole's centre drawn far enough out that an end may cross an image's edge.
            x = rng.uniform(-60.0, 60.0) if not off_image else rng.choice([-1.0, 1.0]) * rng.uniform(60.0, 200.0)
            pose = SolePose(x, rng.uniform(-50.0, 50.0), yaw, bool(rng.random() < 0.5))
            scene = cls(seed, color, calib, camera_pose, SoleModel(shape, pose), look)
            if off_image and not scene.in_view(0.0) and scene.in_view(-OFF_IMAGE_PX):
                return scene
            if not off_image and scene.in_view(VIEW_MARGIN_PX):
                return scene
        raise ValueError(
            f"no pose of sole {seed} ({shape.length:.0f} mm) fits in both images of this rig: "
            "the cameras see too little of the table"
        )

    def in_view(self, margin_px: float) -> bool:
        """Whether both cameras see the whole sole, `margin_px` inside their images."""
        if self.sole is None:
            return True
        outline = self.sole.outline_table(400)
        # The top without its edge profile: at least as high as the sole anywhere near the outline.
        uv = self.sole.pose.to_sole(outline, self.sole.shape.length)
        top = self.sole.shape.top_height(uv[:, 0], uv[:, 1])
        corners = np.vstack([np.column_stack([outline, np.zeros(len(outline))]), np.column_stack([outline, top])])
        width, height = self.calib.image_size
        for side in ("left", "right"):
            px = project(self.calib, self.camera_pose, side, corners)
            if (
                np.any(px < margin_px)
                or np.any(px[:, 0] > width - 1 - margin_px)
                or np.any(px[:, 1] > height - 1 - margin_px)
            ):
                return False
        return True

    def table_from_measured(self, camera_to_table: np.ndarray) -> np.ndarray:
        """4 x 4 map from a measured table frame (given as rectified left camera -> table) to this scene's."""
        rectified_to_raw = np.eye(4)
        rectified_to_raw[:3, :3] = self.calib.R1.T  # rectified = R1 @ raw
        return self.camera_pose @ rectified_to_raw @ np.linalg.inv(camera_to_table)

    def render(self) -> RenderedPair:
        return SceneRenderer(self.calib, self.camera_pose, self.sole, self.color, self.seed, self.look).render()

    def render_empty(self, shot: int = 1) -> RenderedPair:
        """The same table without the sole, as `cellctl teach` sees it: same textures, new sensor noise (`shot`)."""
        return self.render_empties([shot])[0]

    def render_empties(self, shots: list[int]) -> list[RenderedPair]:
        """`render_empty` for several shots, ray-cast and shaded once (each pair identical to its own render)."""
        renderer = SceneRenderer(self.calib, self.camera_pose, None, self.color, self.seed, self.look)
        # Any seed other than the scene's own: another exposure.
        return renderer.render_shots([self.seed + 7919 * shot for shot in shots])

    def truth(self) -> dict[str, object]:
        """truth.json contents: the three measurements from the model, and everything needed to rebuild it."""
        data: dict[str, object] = {"seed": self.seed, "color": self.color, "look": asdict(self.look)}
        if self.sole is not None:
            data.update(self.sole.truth().to_dict())
            data["sole_pose"] = asdict(self.sole.pose)
            data["sole_shape"] = asdict(self.sole.shape)
        data["camera_pose"] = np.round(self.camera_pose, 9).tolist()
        data["frames"] = (
            "table frame: z = 0 on the table, z towards the cameras, mm; camera_pose maps the raw left "
            "camera's frame into it; depth_left.npy is z in the raw left camera frame (mm, NaN = no hit) "
            "per pixel of left.png; outline.npy is the footprint outline in the table frame"
        )
        return data

    def write(self, out_dir: str | Path, pair: RenderedPair) -> Path:
        """Write left.png, right.png, truth.json, depth_left.npy, outline.npy and calib.yaml into out_dir."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        for name, image in (("left.png", pair.left), ("right.png", pair.right)):
            if not cv2.imwrite(str(out / name), image):
                raise ValueError(f"cannot write {out / name}: check the directory is writable")
        np.save(out / "depth_left.npy", pair.depth_left)
        if self.sole is not None:
            np.save(out / "outline.npy", self.sole.footprint_table(2000))
        (out / "truth.json").write_text(json.dumps(self.truth(), indent=2) + "\n")
        self.calib.save(out / "calib.yaml")
        return out


def true_cloud(calib: Calibration, depth_left: np.ndarray, left: np.ndarray) -> StereoCloud:
    """The measured-points form of a true depth map: every hit pixel, in the rectified left camera frame."""
    height, width = depth_left.shape
    ys, xs = np.nonzero(np.isfinite(depth_left))
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
    pixels = np.column_stack([xs, ys]).astype(np.float64).reshape(-1, 1, 2)
    rays = cv2.undistortPoints(pixels, calib.K1, calib.D1, criteria=criteria).reshape(-1, 2)
    z = depth_left[ys, xs].astype(np.float64)
    points = np.column_stack([rays * z[:, None], z]) @ calib.R1.T  # raw left camera -> rectified left camera
    rect = points @ calib.P1[:, :3].T
    colours = cv2.blur(left.astype(np.float32), (3, 3))[ys, xs]
    return StereoCloud(
        points=points,
        colors=colours,
        pixels=rect[:, :2] / rect[:, 2:3],
        disparity=calib.focal_px * calib.baseline_mm / points[:, 2],
        image_size=(width, height),
    )
