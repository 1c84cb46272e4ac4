"""Pictures of a measurement: the left image with the sole's edge, glue path and measurement points, and a
top view of the reconstructed cloud coloured by height, side by side."""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from cellctl.vision.calibration import Calibration
from cellctl.vision.measurement import MeasurementResult, SoleMeasurement
from cellctl.vision.reconstruction import ReconstructionResult

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
    left: np.ndarray,
    calib: Calibration,
    reconstruction: ReconstructionResult,
    measurement: MeasurementResult,
    pause: Callable[[], None] = lambda: None,
) -> np.ndarray:
    """Left image with edge, glue path and heel/toe points, next to a top view of the cloud (BGR).

    `pause()` is called between the parts (the left image, the top view, ~40-80 ms each): a writer drawing
    between the cell's cycles waits there while a cycle runs (cellctl.service.imagelog)."""
    image = draw_on_left(left, calib, measurement)
    _caption(image, measurement)
    _legend(image)
    pause()
    top = top_view(reconstruction, measurement)
    if top is None:
        return image
    pause()
    scale = image.shape[0] / top.shape[0]
    top = cv2.resize(top, (max(1, int(round(top.shape[1] * scale))), image.shape[0]), interpolation=cv2.INTER_AREA)
    z = reconstruction.sole_points[:, 2]
    return np.hstack([image, top, height_scale(float(z.min()), float(z.max()), image.shape[0])])


def draw_refused(left: np.ndarray, text: str) -> np.ndarray:
    """The raw left image of a cycle that gave no measurement, captioned with why (BGR)."""
    image = cv2.cvtColor(left, cv2.COLOR_GRAY2BGR) if left.ndim == 2 else left.copy()
    size = _text_size(image)
    _put(image, "NOT MEASURED", (10, int(40 * size)), (0, 0, 255), size * 1.2)
    words, line, y = text.split(), "", int(80 * size)
    per_line = max(20, int(image.shape[1] / (19 * size)))
    for word in words:
        if len(line) + len(word) + 1 > per_line:
            _put(image, line, (10, y), (255, 255, 255), size)
            line, y = "", y + int(34 * size)
        line = f"{line} {word}".strip()
    _put(image, line, (10, y), (255, 255, 255), size)
    return image


def height_scale(low_mm: float, high_mm: float, height: int, width: int = 110) -> np.ndarray:
    """A vertical colour bar of the top view's height colours (viridis), labelled in mm above the table."""
    bar = np.full((height, width, 3), 30, np.uint8)
    top, bottom = 50, height - 50
    ramp = np.linspace(255, 0, max(bottom - top, 2)).astype(np.uint8).reshape(-1, 1)
    bar[top:bottom, 10:40] = cv2.applyColorMap(ramp, cv2.COLORMAP_VIRIDIS)[:, :1, :].repeat(30, axis=1)
    for row, value in ((top, high_mm), ((top + bottom) // 2, (low_mm + high_mm) / 2), (bottom - 1, low_mm)):
        cv2.putText(bar, f"{value:.0f}", (45, row + 6), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    cv2.putText(bar, "height mm", (5, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return bar


def draw_on_left(left: np.ndarray, calib: Calibration, measurement: MeasurementResult) -> np.ndarray:
    """The raw left image with edge, glue path and heel/toe points where the camera saw them (BGR, no caption)."""
    image = cv2.cvtColor(left, cv2.COLOR_GRAY2BGR) if left.ndim == 2 else left.copy()
    transform = measurement.camera_to_table
    if transform is not None:
        _draw_geometry(image, measurement, lambda pts: project_to_left(calib, transform, pts))
    return image


def top_view(reconstruction: ReconstructionResult, measurement: MeasurementResult) -> np.ndarray | None:
    """The sole's points seen from above (+z), coloured by height, with edge, glue path and points."""
    points = reconstruction.sole_points
    if len(points) == 0:
        return None
    # Per column: numpy reduces an N x 2 slice along its rows ~20 times slower (~9 ms here; the same values).
    x, y = points[:, 0], points[:, 1]
    lo = np.array([x.min(), y.min()]) - 10.0
    hi = np.array([x.max(), y.max()]) + 10.0
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


def _draw_geometry(
    image: np.ndarray, measurement: MeasurementResult, to_px: Callable[[np.ndarray], np.ndarray]
) -> None:
    if measurement.outline is not None and len(measurement.outline):
        outline = np.column_stack([measurement.outline, _edge_heights(measurement)])
        cv2.polylines(image, [np.round(to_px(outline)).astype(np.int32)], True, EDGE_BGR, 1, cv2.LINE_AA)
    if isinstance(measurement, SoleMeasurement):
        path = np.round(to_px(measurement.glue_path.points)).astype(np.int32)
        cv2.polylines(image, [path], True, GLUE_BGR, 1, cv2.LINE_AA)
        cv2.circle(image, tuple(int(v) for v in path[0]), 5, GLUE_BGR, 2, cv2.LINE_AA)  # where the path starts
    for point, colour in ((measurement.heel_point, HEEL_BGR), (measurement.toe_point, TOE_BGR)):
        if point is not None:
            centre = np.round(to_px(np.asarray(point, np.float64).reshape(1, 3))[0]).astype(int)
            cv2.drawMarker(image, (int(centre[0]), int(centre[1])), colour, cv2.MARKER_CROSS, 20, 2, cv2.LINE_AA)


def _edge_heights(measurement: MeasurementResult) -> np.ndarray:
    """Height of the top surface along the outline (from the nearest glue path point): the camera sees the
    edge up there, not on the table."""
    outline = measurement.outline
    if outline is None:
        return np.zeros(0)
    if not isinstance(measurement, SoleMeasurement):
        return np.zeros(len(outline))
    path = measurement.glue_path.points
    # The outline's points against the path's in blocks of rows: the whole outline x path matrix (~3k x 350,
    # several 8 MB temporaries) cost ~30 ms, a block that stays in cache ~4 ms. The same distances, bit for bit:
    # np.linalg.norm over two coordinates is sqrt(dx * dx + dy * dy) too.
    nearest = np.empty(len(outline), np.intp)
    for start in range(0, len(outline), _EDGE_ROWS):
        block = outline[start : start + _EDGE_ROWS]
        dx = block[:, 0:1] - path[:, 0]
        dy = block[:, 1:2] - path[:, 1]
        dx *= dx
        dy *= dy
        dx += dy
        nearest[start : start + _EDGE_ROWS] = np.argmin(np.sqrt(dx, out=dx), axis=1)
    return path[nearest, 2]


_EDGE_ROWS = 128  # outline points per block in _edge_heights: 128 x ~350 path points x 8 bytes, ~0.35 MB


def _caption(image: np.ndarray, measurement: MeasurementResult) -> None:
    if isinstance(measurement, SoleMeasurement):
        text = (
            f"length {measurement.length_mm:.1f} mm  heel {measurement.heel_height_mm:.1f} mm  "
            f"toe {measurement.toe_height_mm:.1f} mm"
        )
        colour = (255, 255, 255)
    else:
        text = f"NOT MEASURED: {measurement.reason}"
        colour = (0, 0, 255)
    _put(image, text, (10, int(34 * _text_size(image))), colour, _text_size(image))


def _legend(image: np.ndarray) -> None:
    """Colour swatches of what is drawn, bottom left."""
    size = _text_size(image)
    y = image.shape[0] - int(20 * size)
    x, box = 10, int(22 * size)
    for name, colour in (("edge", EDGE_BGR), ("glue path", GLUE_BGR), ("heel", HEEL_BGR), ("toe", TOE_BGR)):
        cv2.rectangle(image, (x, y - box), (x + box, y), (0, 0, 0), -1)
        cv2.rectangle(image, (x + 3, y - box + 3), (x + box - 3, y - 3), colour, -1)
        _put(image, name, (x + box + 6, y - 2), (255, 255, 255), size * 0.8)
        x += box + 20 + int(15 * size * len(name))


def _text_size(image: np.ndarray) -> float:
    """Font scale for an image: captions keep the same share of the width at any resolution."""
    return max(0.5, image.shape[1] / 1100.0)


def _put(
    image: np.ndarray, text: str, origin: tuple[int, int], colour: tuple[int, int, int], size: float = 0.8
) -> None:
    """Text with a dark outline, legible on any image."""
    thick = max(1, int(round(size * 2.2)))
    # The outline is the same text shifted around, not a thicker stroke: OpenCV spaces thicker text wider.
    x, y = origin
    for dx, dy in ((-1, -1), (1, -1), (-1, 1), (1, 1), (0, 2), (2, 0), (0, -2), (-2, 0)):
        cv2.putText(image, text[:110], (x + dx, y + dy), cv2.FONT_HERSHEY_SIMPLEX, size, (0, 0, 0), thick, cv2.LINE_AA)
    cv2.putText(image, text[:110], origin, cv2.FONT_HERSHEY_SIMPLEX, size, colour, thick, cv2.LINE_AA)
