"""Rendering of simulated stereo pairs: a sole on a table, seen through a calibrated rig.

Geometry is exact: every pixel's ray is traced with Open3D's `RaycastingScene` (CPU). Rays start from the
*distorted* pixel positions, undistorted with the camera's own model (cv2.undistortPoints), so the images
carry the lens distortion of the calibration. Pixels on geometric edges are supersampled 4 x 4 so that
the sole's silhouette has the sub-pixel edge profile a real sensor records. Appearance: diffuse shading
from two light bars plus ambient, a weak specular term, low-contrast procedural texture (fractal noise,
not a dot pattern: real soles are weakly textured), a slight lens blur, vignetting, and shot plus read
noise, quantised to 8 bits. A `SceneLook` (cellctl.sim.look) varies all of this: the table and the sole's
colours (cellctl.sim.appearance), a low side light with cast shadows (shadow rays to every light), gloss,
heavy noise, and the right camera's gain and gamma.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from cellctl.sim.appearance import SOLE_MATERIALS, TABLES, ColourScheme, Texture, lights, sole_material, table_texture
from cellctl.sim.look import SceneLook
from cellctl.sim.occlusion import sky_fraction
from cellctl.sim.raycast import SOLE_GEOMETRY, TABLE_GEOMETRY, RayCaster
from cellctl.sim.rig import RIG_HEIGHT_MM
from cellctl.sim.sole import SoleModel
from cellctl.vision.calibration import Calibration

RIG_TILT_DEG = (2.0, -1.0)  # a rig is never mounted perfectly level: about its x and y axes

PART_TOP, PART_WALL, PART_UNDERSIDE, PART_EDGE = 0, 1, 2, 3  # PART_EDGE: top surface within the edge profile


AMBIENT = 0.35
EXPOSURE_DN = 255.0  # pixel value of a white (albedo 1) horizontal surface at the table centre
# Read noise (DN) and variance added per DN of signal (the sensor's conversion gain), per SceneLook.noise.
SENSOR_NOISE: dict[str, tuple[float, float]] = {"normal": (1.0, 0.02), "heavy": (6.0, 0.15)}
LENS_BLUR_PX = 0.5
VIGNETTING = 0.12  # relative fall-off at the image corners
SUPERSAMPLE = 4


def mount_tilt(tilt_magnitude_deg: float) -> tuple[float, float]:
    """The rig's tilt about the table's x and y axes: RIG_TILT_DEG, or with a magnitude (degrees, > 0) that
    direction scaled to it (a rig mounted further off square in the same way)."""
    if tilt_magnitude_deg <= 0.0:
        return RIG_TILT_DEG
    scale = tilt_magnitude_deg / float(np.hypot(*RIG_TILT_DEG))
    return RIG_TILT_DEG[0] * scale, RIG_TILT_DEG[1] * scale


def rig_pose(
    calib: Calibration, height_mm: float = RIG_HEIGHT_MM, tilt_deg: tuple[float, float] = RIG_TILT_DEG
) -> np.ndarray:
    """Pose of the left camera in the table frame (4 x 4, table <- camera) for a rig looking down.

    The baseline mid-point sits `height_mm` above the table origin; the cameras look down (camera z = -table
    z, camera x = table x) with a small tilt, as a mounted rig does.
    """
    down = np.diag([1.0, -1.0, -1.0])
    tilt = cv2.Rodrigues(np.radians([tilt_deg[0], tilt_deg[1], 0.0]))[0]
    rotation = down @ tilt
    right_centre = (-calib.R.T @ calib.T).ravel()  # right optical centre in the left camera frame
    centre = np.array([0.0, 0.0, height_mm]) - rotation @ (right_centre / 2.0)
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rotation, centre
    return pose


def right_pose(calib: Calibration, left_pose: np.ndarray) -> np.ndarray:
    """Pose of the right camera in the table frame from the left camera's pose and the stereo extrinsics."""
    camera_from_right = np.eye(4)
    camera_from_right[:3, :3] = calib.R.T
    camera_from_right[:3, 3] = (-calib.R.T @ calib.T).ravel()
    return left_pose @ camera_from_right


def project(calib: Calibration, pose: np.ndarray, side: str, points: np.ndarray) -> np.ndarray:
    """Pixel positions (N x 2) of table-frame points in the left or right raw image (with distortion)."""
    if side == "right":
        pose = right_pose(calib, pose)
    K, D = (calib.K1, calib.D1) if side == "left" else (calib.K2, calib.D2)
    inverse = np.linalg.inv(pose)
    rvec = cv2.Rodrigues(inverse[:3, :3])[0]
    pixels, _ = cv2.projectPoints(np.asarray(points, np.float64).reshape(-1, 1, 3), rvec, inverse[:3, 3], K, D)
    return pixels.reshape(-1, 2)


@dataclass
class RenderedPair:
    """A rendered stereo pair (BGR uint8) and the left camera's true depth (z in the camera frame, mm)."""

    left: np.ndarray
    right: np.ndarray
    depth_left: np.ndarray  # float32, H x W, NaN where nothing was hit
    sole_mask_left: np.ndarray  # bool, H x W, pixel centre sees the sole


class SceneRenderer:
    """Renders one scene (table and optional sole) through a calibrated rig."""

    def __init__(
        self,
        calib: Calibration,
        camera_pose: np.ndarray,
        sole: SoleModel | None,
        color: str = "white",
        seed: int = 0,
        look: SceneLook | None = None,
        noise_seed: int | None = None,
    ) -> None:
        if color not in SOLE_MATERIALS:
            raise ValueError(f"sole colour must be one of {', '.join(SOLE_MATERIALS)}, got {color!r}")
        self.calib = calib
        self.camera_pose = np.asarray(camera_pose, dtype=np.float64)
        self.sole = sole
        self.look = look or SceneLook()
        self.material = sole_material(color, self.look)
        self.table = TABLES[self.look.table]
        self.lights, self.light_power = lights(self.look)
        rng = np.random.default_rng([seed, 7])
        self._table_texture = table_texture(rng, self.look)
        self._sole_texture = Texture.fractal(rng, (-5.0, -80.0), (320.0, 160.0), 0.2, self.material.octaves)
        if self.look.knurl_period_mm > 0.0:
            look = self.look
            self._sole_texture = self._sole_texture.with_knurl(
                look.knurl_period_mm, look.knurl_angle_deg, look.knurl_contrast
            )
        self._colours = (
            None if sole is None else ColourScheme.draw(np.random.default_rng([seed, 13]), color, self.look, sole.shape)
        )
        # The sensor noise may come from its own seed: the same table (textures from `seed`) shot again.
        self._noise_rng = np.random.default_rng([seed if noise_seed is None else noise_seed, 11])
        self.rays = RayCaster(calib.image_size, sole)

    def render(self) -> RenderedPair:
        """Render both cameras."""
        return self.render_shots([None])[0]

    def render_shots(self, noise_seeds: list[int | None]) -> list[RenderedPair]:
        """The same scene exposed once per noise seed (None: the renderer's own noise).

        Rays and shading are computed once; only the sensor (noise) differs per shot, so each pair is
        pixel-identical to a renderer made with that noise seed.
        """
        left, depth, sole_mask = self._radiance("left")
        right, _, _ = self._radiance("right")
        pairs = []
        for noise_seed in noise_seeds:
            if noise_seed is not None:
                self._noise_rng = np.random.default_rng([noise_seed, 11])
            pairs.append(RenderedPair(self._expose("left", left), self._expose("right", right), depth, sole_mask))
        return pairs

    # ---- one camera ----------------------------------------------------------------------------------

    def _radiance(self, side: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One camera's linear radiance image (H x W x 3), true depth and sole mask, before the sensor."""
        width, height = self.calib.image_size
        pose = self.camera_pose if side == "left" else right_pose(self.calib, self.camera_pose)
        K, D = (self.calib.K1, self.calib.D1) if side == "left" else (self.calib.K2, self.calib.D2)
        hits = self.rays.cast(None, K, D, pose)
        radiance = self._shade(hits, pose)
        edges = self.rays.edge_pixels(hits, (height, width))
        if edges.size:
            pixels = np.column_stack([edges % width, edges // width]).astype(np.float64)
            radiance[edges] = self._supersample(pixels, K, D, pose)
        depth = np.where(np.isfinite(hits["t"]), hits["t"], np.nan).astype(np.float32).reshape(height, width)
        sole_mask = (hits["geometry"] == SOLE_GEOMETRY).reshape(height, width)
        return radiance.reshape(height, width, 3), depth, sole_mask

    def _expose(self, side: str, radiance: np.ndarray) -> np.ndarray:
        """The camera's image of a radiance image: its gain, gamma and the sensor (noise from _noise_rng)."""
        K = self.calib.K1 if side == "left" else self.calib.K2
        gain, gamma = (1.0, 1.0) if side == "left" else (self.look.right_gain, self.look.right_gamma)
        defocus = self.look.left_defocus_px if side == "left" else self.look.right_defocus_px
        blur = float(np.hypot(LENS_BLUR_PX, defocus))
        return self._sensor(radiance * (gain * self.look.exposure_scale), self.calib.image_size, K, gamma, blur)

    def _shade(self, hits: dict[str, np.ndarray], pose: np.ndarray) -> np.ndarray:
        """Linear radiance (BGR, exposure-scaled DN before sensor effects) of every ray's hit."""
        n = len(hits["t"])
        points = hits["points"]
        normals = np.zeros((n, 3), np.float32)
        normals[:, 2] = 1.0
        albedo = np.zeros((n, 3), np.float32)
        texture = np.ones(n, np.float32)
        specular = np.zeros(n, np.float32)
        shininess = np.ones(n, np.float32)
        table = hits["geometry"] == TABLE_GEOMETRY
        albedo[table] = self.table.albedo_bgr
        texture[table] = self._table_texture.sample(points[table, 0], points[table, 1])
        specular[table], shininess[table] = self.table.specular, self.table.shininess
        sole = hits["geometry"] == SOLE_GEOMETRY
        if np.any(sole):
            albedo[sole] = self._shade_sole(hits, sole, normals, texture)
            specular[sole], shininess[sole] = self.material.specular, self.material.shininess
        # The matrix's bars cast no shadow (as every render before the other lights); every other layout does.
        shadowed = self.look.shadows or self.look.lighting != "bars"
        lit = self.rays.unshadowed(points, normals, hits["geometry"] >= 0, self.lights) if shadowed else None
        ambient = AMBIENT * self.look.ambient_scale
        diffuse, highlight = _lighting(
            points, normals, pose[:3, 3], shininess, self.lights, self.light_power, lit, ambient
        )
        room = np.full(n, ambient, np.float32)  # the room's diffuse light, less what the sole hides from the table
        if self.look.ambient_occlusion > 0.0 and self.sole is not None and np.any(table):
            room[table] *= sky_fraction(self.sole, points[table, :2], self.look.ambient_occlusion)
        radiance = albedo * (texture * (room + diffuse))[:, None] + (specular * highlight)[:, None]
        radiance[hits["geometry"] < 0] = 0.0
        return radiance * EXPOSURE_DN

    def _shade_sole(
        self, hits: dict[str, np.ndarray], sole: np.ndarray, normals: np.ndarray, texture: np.ndarray
    ) -> np.ndarray:
        """Normals and texture of the sole's hits written in place; returns their albedo."""
        assert self.sole is not None and self._colours is not None
        shape, pose = self.sole.shape, self.sole.pose
        uv = pose.to_sole(hits["points"][sole, :2], shape.length)
        z = hits["points"][sole, 2]
        part = hits["part"][sole]
        # Smooth analytic normals on the top surface; the walls, underside and edge profile are fine facets.
        top_normals = self.sole.interior_normal_at(hits["points"][sole, :2])
        facet = hits["facet_normals"][sole]
        normals[sole] = np.where((part == 0)[:, None], top_normals, facet)
        # Walls take the texture at (u, v + z) so that it varies down the wall too.
        tex_v = np.where((part == PART_TOP) | (part == PART_EDGE), uv[:, 1], uv[:, 1] + z)
        texture[sole] = self._sole_texture.sample(uv[:, 0], tex_v)
        return self._colours.albedo(shape, uv, part == PART_WALL)

    def _supersample(self, pixels: np.ndarray, K: np.ndarray, D: np.ndarray, pose: np.ndarray) -> np.ndarray:
        offsets = (np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE - 0.5
        ox, oy = np.meshgrid(offsets, offsets)
        sub = (pixels[:, None, :] + np.column_stack([ox.ravel(), oy.ravel()])[None]).reshape(-1, 2)
        radiance = self._shade(self.rays.cast(sub, K, D, pose), pose)
        return radiance.reshape(len(pixels), SUPERSAMPLE * SUPERSAMPLE, 3).mean(axis=1)

    def _sensor(
        self, radiance: np.ndarray, size: tuple[int, int], K: np.ndarray, gamma: float, blur_px: float
    ) -> np.ndarray:
        width, height = size
        image = cv2.GaussianBlur(radiance.astype(np.float32), (0, 0), blur_px)
        ys, xs = np.mgrid[0:height, 0:width].astype(np.float32)
        r2 = ((xs - K[0, 2]) ** 2 + (ys - K[1, 2]) ** 2) / (0.25 * (width**2 + height**2))
        image *= (1.0 - VIGNETTING * r2)[..., None]
        read, shot = SENSOR_NOISE[self.look.noise]
        sigma = self.look.noise_scale * np.sqrt(read**2 + shot * np.maximum(image, 0.0))
        image = image + sigma * self._noise_rng.standard_normal(image.shape, dtype=np.float32)
        if gamma != 1.0:  # the camera's tone curve acts on the noisy signal, as a sensor's LUT does
            image = 255.0 * (np.clip(image, 0.0, 255.0) / 255.0) ** gamma
        return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def _lighting(
    points: np.ndarray,
    normals: np.ndarray,
    eye: np.ndarray,
    shininess: np.ndarray,
    light_positions: np.ndarray,
    power: np.ndarray,
    lit: np.ndarray | None = None,
    ambient: float = AMBIENT,
) -> tuple[np.ndarray, np.ndarray]:
    """Diffuse and Blinn-Phong specular terms of the lights, normalised to 1 - `ambient` at the table origin.

    `lit` (lights x points, bool) switches a light off where its light is blocked: a cast shadow.
    """
    points = points.astype(np.float32)
    normals = normals.astype(np.float32)
    diffuse = np.zeros(len(points), np.float32)
    highlight = np.zeros(len(points), np.float32)
    view = _unit(eye.astype(np.float32) - points)
    reference = 0.0
    for k, light in enumerate(light_positions):
        to_light = light.astype(np.float32) - points
        distance2 = np.einsum("ij,ij->i", to_light, to_light)
        to_light /= np.sqrt(distance2)[:, None]
        falloff = float(light @ light) / distance2
        if power[k] != 1.0:
            falloff *= np.float32(power[k])
        if lit is not None:
            falloff *= lit[k]
        diffuse += np.clip(np.einsum("ij,ij->i", normals, to_light), 0.0, None) * falloff
        half = _unit(to_light + view)
        highlight += np.clip(np.einsum("ij,ij->i", normals, half), 0.0, None) ** shininess * falloff
        reference += power[k] * light[2] / np.linalg.norm(light)
    return diffuse * np.float32((1.0 - ambient) / reference), highlight


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.maximum(np.sqrt(np.einsum("ij,ij->i", vectors, vectors)), 1e-9)[:, None]
