"""What a cycle leaves for people: the sole's cloud as PLY and the left image with the glue path drawn.

Written after the PLC has its answer; a failure here is logged and never fails the cycle. The files go to
a staging folder that the journal renames into place in the same transaction that records them, so no
folder is left that no row refers to (Journal.prune_orphans cleans up after a crash at the next start).
"""

from __future__ import annotations

import logging
import shutil

import cv2

from cellctl.cameras.base import StereoFrame
from cellctl.service.journal import CycleRecord, Journal
from cellctl.vision.calibration import Calibration
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
        folder = journal.staging_dir(record.id)  # renamed into place by attach_artifacts
        folder.mkdir(parents=True, exist_ok=True)
        ply = folder / f"cycle-{record.cycle}.ply"
        import open3d as o3d

        if not o3d.io.write_point_cloud(str(ply), reconstruction.point_cloud(), write_ascii=False):
            raise OSError(f"Open3D could not write {ply}")
        overlay = folder / f"cycle-{record.cycle}-overlay.png"
        if not cv2.imwrite(str(overlay), draw_on_left(frame.left, calib, measurement), PNG_FAST):
            raise OSError(f"cannot write {overlay}")
        journal.attach_artifacts(record.id, ply.name, overlay.name)
        journal.prune_artifacts(keep)
    except Exception as exc:
        log.warning("cycle %d: artifacts not kept: %s", record.cycle, exc)
        shutil.rmtree(journal.staging_dir(record.id), ignore_errors=True)
