"""Pictures of a measurement: the left image with the sole's edge, glue path and measurement points, and a
top view of the reconstructed cloud coloured by height, side by side."""

from __future__ import annotations

import cv2
import numpy as np

from cellctl.vision.calibration import Calibration
from cellctl.vision.measurement import SoleMeasurement
from cellctl.vision.reconstruction import Reconstruction

EDGE_BGR = (0, 255, 0)
GLUE_BGR = (0, 200, 255)
HEEL_BGR = (255, 80, 0)
TOE_BGR = (0, 80, 255)
TOP_VIEW_MM_PER_PX = 0.5


def project_to_left(calib: Calibration, camera_to_table: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Pixels (N x 2) in the raw left image of table-frame points (N x 3)."""
    table_to_camera = np.linalg.inv(camera_to_table)
    rectified = np.asarray(points, np.float64) @ table_to_camera[:3, :3].T + table_to_camera[:3, 3]
    raw = rectified @ calib.R1  # rectified = R1 @ raw
    pixels, _ = cv2.projectPoints(raw.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), calib.K1, calib.D1)
    return pixels.reshape(-1, 2)


def draw_overlay(
    left: np.ndarray, calib: Calibration, reconstruction: Reconstruction, measurement: SoleMeasurement
) -> np.ndarray:
    """Left image with edge, glue path and heel/toe points, next to a top view of the cloud (BGR)."""
    image = draw_on_left(left, calib, measurement)
    _caption(image, measurement)
    top = top_view(reconstruction, measurement)
    if top is None:
        return image
    scale = image.shape[0] / top.shape[0]
    top = cv2.resize(top, (max(1, int(round(top.shape[1] * scale))), image.shape[0]), interpolation=cv2.INTER_AREA)
    return np.hstack([image, top])


def draw_on_left(left: np.ndarray, calib: Calibration, measurement: SoleMeasurement) -> np.ndarray:
    """The raw left image with edge, glue path and heel/toe points where the camera saw them (BGR, no caption)."""
    image = cv2.cvtColor(left, cv2.COLOR_GRAY2BGR) if left.ndim == 2 else left.copy()
    transform = measurement.camera_to_table
    if transform is not None:
        _draw_geometry(image, measurement, lambda pts: project_to_left(calib, transform, pts))
    return image


def top_view(reconstruction: Reconstruction, measurement: SoleMeasurement) -> np.ndarray | None:
    """The sole's points seen from above (+z), coloured by height, with edge, glue path and points."""
    points = reconstruction.sole_points
    if len(points) == 0:
        return None
    lo = points[:, :2].min(axis=0) - 10.0
    hi = points[:, :2].max(axis=0) + 10.0
    width, height = np.ceil((hi - lo) / TOP_VIEW_MM_PER_PX).astype(int) + 1

    # Image rows grow downwards, table y upwards: flip y so the view is as seen from the cameras' side.
    def to_px(xy: np.ndarray) -> np.ndarray:
        return np.column_stack([(xy[:, 0] - lo[0]) / TOP_VIEW_MM_PER_PX, (hi[1] - xy[:, 1]) / TOP_VIEW_MM_PER_PX])

    z = points[:, 2]
    scale = np.clip((z - z.min()) / max(float(np.ptp(z)), 1e-6) * 255, 0, 255).astype(np.uint8)
    colours = cv2.applyColorMap(scale.reshape(-1, 1), cv2.COLORMAP_VIRIDIS).reshape(-1, 3)
    view = np.full((height, width, 3), 30, np.uint8)
    px = np.clip(np.round(to_px(points[:, :2])).astype(int), 0, [width - 1, height - 1])
    view[px[:, 1], px[:, 0]] = colours
    _draw_geometry(view, measurement, lambda pts: to_px(np.asarray(pts)[:, :2]))
    return view


def _draw_geometry(image: np.ndarray, measurement: SoleMeasurement, to_px) -> None:  # noqa: ANN001
    if measurement.outline is not None and len(measurement.outline):
        outline = np.column_stack([measurement.outline, _edge_heights(measurement)])
        cv2.polylines(image, [np.round(to_px(outline)).astype(np.int32)], True, EDGE_BGR, 1, cv2.LINE_AA)
    if measurement.glue_path is not None:
        path = np.round(to_px(measurement.glue_path.points)).astype(np.int32)
        cv2.polylines(image, [path], True, GLUE_BGR, 1, cv2.LINE_AA)
        cv2.circle(image, tuple(int(v) for v in path[0]), 5, GLUE_BGR, 2, cv2.LINE_AA)  # where the path starts
    for point, colour in ((measurement.heel_point, HEEL_BGR), (measurement.toe_point, TOE_BGR)):
        if point is not None:
            centre = np.round(to_px(np.asarray(point, np.float64).reshape(1, 3))[0]).astype(int)
            cv2.drawMarker(image, (int(centre[0]), int(centre[1])), colour, cv2.MARKER_CROSS, 20, 2, cv2.LINE_AA)


def _edge_heights(measurement: SoleMeasurement) -> np.ndarray:
    """Height of the top surface along the outline (from the nearest glue path point): the camera sees the
    edge up there, not on the table."""
    outline = measurement.outline
    if outline is None:
        return np.zeros(0)
    if measurement.glue_path is None:
        return np.zeros(len(outline))
    path = measurement.glue_path.points
    distance = np.linalg.norm(outline[:, None, :] - path[None, :, :2], axis=2)
    return path[np.argmin(distance, axis=1), 2]


def _caption(image: np.ndarray, measurement: SoleMeasurement) -> None:
    if measurement.valid:
        text = (
            f"length {measurement.length_mm:.1f} mm  heel (blue) {measurement.heel_height_mm:.1f} mm  "
            f"toe (red) {measurement.toe_height_mm:.1f} mm  edge green, glue path orange"
        )
        colour = (255, 255, 255)
    else:
        text = f"NOT MEASURED: {measurement.reason}"
        colour = (0, 0, 255)
    cv2.putText(image, text[:110], (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (0, 0, 0), 4, cv2.LINE_AA)
    cv2.putText(image, text[:110], (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, colour, 2, cv2.LINE_AA)
