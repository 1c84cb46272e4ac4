"""The table plane: found by RANSAC and refined on the images, and the table frame it defines.

Every height is measured from this plane (docs/measurements.md, frames).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cellctl.vision.calibration import Calibration
from cellctl.vision.cloud import StereoCloud
from cellctl.vision.subpixel import refine_patches

TABLE_INLIER_MM = 1.5  # RANSAC inlier distance for the table plane
TABLE_RANSAC_HYPOTHESES = 300
TABLE_REFITS = 10  # least-squares refits at most; they stop once their inliers no longer change


@dataclass(frozen=True)
class TablePlane:
    """The table as n . p + d = 0 in the rectified left camera frame, n unit and pointing towards the camera."""

    normal: np.ndarray
    offset: float

    @classmethod
    def fit(cls, points: np.ndarray) -> TablePlane:
        """Least-squares plane through points (N x 3), oriented towards the camera at the origin."""
        centre = points.mean(axis=0)
        centred = points - centre
        # The normal is the scatter matrix's eigenvector of least spread: the same as the SVD's last right
        # singular vector, from a 3 x 3 problem instead of an N x 3 one (N ~ 10^6).
        _, vectors = np.linalg.eigh(centred.T @ centred)
        normal = vectors[:, 0]
        offset = -float(normal @ centre)
        if offset < 0:  # the camera (origin) must be on the positive side
            normal, offset = -normal, -offset
        return cls(normal, offset)

    def heights(self, points: np.ndarray) -> np.ndarray:
        return points @ self.normal + self.offset

    def obliqueness_deg(self) -> float:
        """The angle between the rectified cameras' viewing axis and the table's normal, in degrees (0: looking
        straight down at it)."""
        return float(np.degrees(np.arccos(min(abs(float(self.normal[2])), 1.0))))

    def pixel_mm(self, calib: Calibration) -> float:
        """A rectified pixel's footprint on the table (mm): the camera's distance from the plane over the focal
        length."""
        return abs(float(self.offset)) / calib.focal_px

    def camera_to_table(self) -> np.ndarray:
        """4 x 4 rigid transform from the rectified left camera frame to the table frame.

        Origin: the foot of the camera centre on the table; z: the normal; x: the camera's x axis
        projected onto the table (docs/measurements.md).
        """
        z = self.normal
        x = np.array([1.0, 0.0, 0.0]) - z[0] * z
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        origin = -self.offset * z
        transform = np.eye(4)
        transform[:3, :3] = np.vstack([x, y, z])
        transform[:3, 3] = -transform[:3, :3] @ origin
        return transform


@dataclass(frozen=True)
class TableDisparity:
    """A table plane's disparity, linear in the rectified left pixel: d(x, y) = a x + b y + c, from
    d = -B n.(x - cx, y - cy, f) / o for the plane n.X + o = 0 in the rectified left camera frame."""

    a: float
    b: float
    c: float

    @classmethod
    def of(cls, plane: TablePlane, calib: Calibration) -> TableDisparity:
        n, o, baseline = plane.normal, plane.offset, calib.baseline_mm
        cx, cy, f = calib.P1[0, 2], calib.P1[1, 2], calib.focal_px
        scale = -baseline / o
        return cls(scale * n[0], scale * n[1], scale * (n[2] * f - n[0] * cx - n[1] * cy))

    def at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The disparity (px) at rectified left pixels (x, y) (arrays that broadcast)."""
        return (self.b * y + self.c) + self.a * x

    def values(self, box: tuple[slice, slice]) -> np.ndarray:
        """The disparity (px, float64) at every rectified left pixel of `box` (rows, columns)."""
        rows = np.arange(box[0].start or 0, box[0].stop, dtype=np.float64)
        columns = np.arange(box[1].start or 0, box[1].stop, dtype=np.float64)
        return self.at(columns[None, :], rows[:, None])

    def shift(self, box: tuple[slice, slice], right: bool) -> np.ndarray:
        """Per pixel of `box`, how far along x the other image shows the same table point: -d for a left pixel;
        for a right pixel x_r, +d at the left pixel x_l = x_r + d (solved: d = (a x_r + b y + c) / (1 - a))."""
        d = self.values(box)
        return (d / (1.0 - self.a) if right else -d).astype(np.float32)


def find_table(points: np.ndarray, sample: int = 60000, seed: int = 0, refit_stride: int = 4) -> TablePlane | None:
    """RANSAC on a subsample, then least-squares refits to the inliers of every `refit_stride`-th point.

    The refit matters: heights are measured from this plane, and RANSAC's three-point hypothesis on a
    subsample is only good to about the inlier distance. A quarter of the points (~200000 table points)
    fixes the plane to about a micrometre of statistical error; all of them only cost more time. The
    refits run until their inliers stop changing, so the plane does not depend on which hypothesis won.
    """
    rng = np.random.default_rng(seed)
    subset = points[rng.choice(len(points), size=min(sample, len(points)), replace=False)]
    found = _ransac_plane(subset, rng)
    if found is None or found[1] < 0.2 * len(subset):
        return None
    plane = found[0]
    spread = points[::refit_stride]  # measured pixels in image order: a stride samples the whole view
    near = np.abs(plane.heights(spread)) < TABLE_INLIER_MM
    for _ in range(TABLE_REFITS):
        plane = TablePlane.fit(spread[near])
        again = np.abs(plane.heights(spread)) < TABLE_INLIER_MM
        if np.array_equal(again, near):
            break
        near = again
    return plane


def _ransac_plane(points: np.ndarray, rng: np.random.Generator) -> tuple[TablePlane, int] | None:
    """The three-point plane with the most points within TABLE_INLIER_MM, and that count.

    Written here rather than Open3D's segment_plane: on the same points, seed set, Open3D 0.20's parallel
    RANSAC returned different planes from call to call (3 planes in 12 calls on a simulated half-size cell's
    cloud, whose refits then differed by 0.3 mm in height), so the same images gave different heights.
    """
    triples = points[rng.integers(0, len(points), size=(TABLE_RANSAC_HYPOTHESES, 3))]
    normals = np.cross(triples[:, 1] - triples[:, 0], triples[:, 2] - triples[:, 0])
    lengths = np.linalg.norm(normals, axis=1)
    usable = lengths > 1e-9  # three points on a line define no plane
    if not usable.any():
        return None
    normals = normals[usable] / lengths[usable, None]
    offsets = -np.einsum("ij,ij->i", normals, triples[usable, 0])
    counts = np.zeros(len(normals), np.int64)
    for start in range(0, len(normals), 32):  # 32 hypotheses at a time: an N x 32 block of distances
        block = slice(start, start + 32)
        counts[block] = (np.abs(points @ normals[block].T + offsets[block]) < TABLE_INLIER_MM).sum(axis=0)
    best = int(np.argmax(counts))  # the first of equal counts: deterministic
    normal, offset = normals[best], float(offsets[best])
    if offset < 0:  # as TablePlane.fit: the camera (origin) on the positive side
        normal, offset = -normal, -offset
    return TablePlane(normal, offset), int(counts[best])


def refine_table(cloud: StereoCloud, plane: TablePlane, spacing_px: int = 80, radius_px: float = 16.0) -> TablePlane:
    """The table plane fitted on the images: disparity planes of table patches (cellctl.vision.subpixel), reprojected.

    Every height is measured from this plane, and the matcher's table disparities carry a bias of a few
    hundredths of a pixel (~0.1 mm of height on simulated scenes) that a fit to its points keeps. Local
    patches on a grid rather than one plane over the whole table: each patch gets its own brightness
    correction, so the cameras' different vignetting cannot tilt the plane.
    """
    calib, rectified = cloud.calibration, cloud.rectified
    if calib is None or rectified is None:  # not a stereo cloud: nothing to refine on
        return plane
    width, height = cloud.image_size
    near = np.abs(plane.heights(cloud.points)) < TABLE_INLIER_MM
    mask = np.zeros((height, width), bool)
    x, y = np.round(cloud.pixels[near]).astype(int).T
    mask[y, x] = True
    gx, gy = np.meshgrid(np.arange(spacing_px // 2, width, spacing_px), np.arange(spacing_px // 2, height, spacing_px))
    centres = np.column_stack([gx.ravel(), gy.ravel()]).astype(np.float64)
    centres = centres[mask[centres[:, 1].astype(int), centres[:, 0].astype(int)]]
    if len(centres) < 10:
        return plane
    # Start from the plane itself: in rectified images a plane n.p + o = 0 has d = -B (n . (x - cx, y - cy, f)) / o.
    f, cx, cy, baseline = calib.focal_px, calib.P1[0, 2], calib.P1[1, 2], calib.baseline_mm
    n, o = plane.normal, plane.offset
    start = np.column_stack(
        [
            -baseline * (n[0] * (centres[:, 0] - cx) + n[1] * (centres[:, 1] - cy) + n[2] * f) / o,
            np.full(len(centres), -baseline * n[0] / o),
            np.full(len(centres), -baseline * n[1] / o),
        ]
    )
    left, right = rectified
    fit = refine_patches(left, right, mask, centres, radius_px, start)
    if np.count_nonzero(fit.ok) < 10:
        return plane
    used = fit.ok[fit.ids]
    homogeneous = np.column_stack([fit.xy, fit.disparities(centres), np.ones(len(fit.ids))])[used] @ calib.Q.T
    points, ids = homogeneous[:, :3] / homogeneous[:, 3:4], fit.ids[used]
    refined = TablePlane.fit(points)
    # Patches that do not lie on the table (a missed object, a mismatch) are dropped and the plane refitted.
    starts = np.flatnonzero(np.diff(ids)) + 1  # ids are sorted: one run per patch
    residual = np.array([abs(np.median(h)) for h in np.split(refined.heights(points), starts)])
    patches = ids[np.concatenate([[0], starts])]
    keep = np.isin(ids, patches[residual < max(3.0 * np.median(residual), 0.05)])
    return TablePlane.fit(points[keep])


def find_and_refine_table(cloud: StereoCloud) -> TablePlane | None:
    """The table plane of one cloud: RANSAC, then refined on the images when the cloud has them."""
    plane = find_table(cloud.points)
    if plane is not None and cloud.rectified is not None:
        plane = refine_table(cloud, plane)
    return plane


def not_the_table(points_in_table_frame: np.ndarray) -> str | None:
    """Why a plane is not the table (most points must lie on or above it), None if it may be."""
    # The table frame's z is the height above the plane: no second pass over the ~10^6 points for it.
    below = float(np.mean(points_in_table_frame[:, 2] < -5.0 * TABLE_INLIER_MM))
    if below > 0.05:
        return f"{100 * below:.0f} % of the points lie below the table plane: the plane found is not the table"
    return None
