"""What a cycle leaves for people and robot tools: the sole's cloud as PLY with normals, the glue path as CSV
and PLY polyline (table frame, cellctl.vision.export), and the left image with the glue path drawn.

Written after the PLC has its answer; a failure here is logged and never fails the cycle.
"""

from __future__ import annotations

import logging

import cv2

from cellctl.cameras.base import StereoFrame
from cellctl.service.journal import CycleRecord, Journal
from cellctl.vision.calibration import Calibration
from cellctl.vision.export import cloud_normals, write_cloud_ply, write_glue_csv, write_glue_ply
from cellctl.vision.measurement import SoleMeasurement
from cellctl.vision.overlay import draw_on_left
from cellctl.vision.reconstruction import Reconstruction

log = logging.getLogger(__name__)

# Huffman coding only: lossless, ~20 % faster and smaller than zlib level 1 on camera images
# (63 vs 79 ms for 1280x1024); the next trigger may be waiting for this.
PNG_FAST = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY]


def keep_artifacts(
    journal: Journal,
    record: CycleRecord,
    frame: StereoFrame,
    calib: Calibration,
    reconstruction: Reconstruction,
    measurement: SoleMeasurement,
    keep: int,
) -> None:
    """PLY and overlay PNG of the cycle in its artifact folder, then prune to the newest `keep` cycles."""
    if keep == 0 or record.id is None:
        return
    try:
        folder = journal.artifact_dir(record.id)
        folder.mkdir(parents=True, exist_ok=True)
        ply = folder / f"cycle-{record.cycle}.ply"
        points = reconstruction.sole_points
        write_cloud_ply(ply, points, cloud_normals(points), reconstruction.sole_colors[:, ::-1], frame="table")
        path = measurement.glue_path
        if path is not None:
            write_glue_csv(folder / f"cycle-{record.cycle}-glue.csv", path.points, path.normals)
            write_glue_ply(folder / f"cycle-{record.cycle}-glue.ply", path.points, path.normals, "table", path.closed)
        overlay = folder / f"cycle-{record.cycle}-overlay.png"
        if not cv2.imwrite(str(overlay), draw_on_left(frame.left, calib, measurement), PNG_FAST):
            raise OSError(f"cannot write {overlay}")
        journal.attach_artifacts(record.id, ply, overlay)
        journal.prune_artifacts(keep)
    except Exception as exc:
        log.warning("cycle %d: artifacts not kept: %s", record.cycle, exc)
