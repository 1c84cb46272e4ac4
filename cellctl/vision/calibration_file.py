"""Calibration files: OpenCV FileStorage YAML, read and written here and nowhere else.

Only image_width, image_height, K1, D1, K2, D2, R and T are required, so files written by other OpenCV
tools can be read; R1, R2, P1, P2 and Q are derived when all are absent (cellctl.vision.calibration holds
the geometry and checks it).
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from cellctl.vision.calibration import DERIVED_KEYS, REQUIRED_KEYS, Calibration


def read_calibration(path: str | os.PathLike[str]) -> Calibration:
    """Read a FileStorage YAML calibration; derived keys are recomputed when absent."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"calibration file {path} does not exist: run `cellctl calibrate` first")
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # the Python binding reports parse errors as SystemError
        reason = exc.err if isinstance(exc, cv2.error) else "parse error"
        raise ValueError(f"calibration file {path} is not valid OpenCV FileStorage YAML: {reason}") from None
    if not storage.isOpened():
        raise ValueError(f"calibration file {path} cannot be read as OpenCV FileStorage YAML")
    try:
        return _from_storage(storage, path)
    finally:
        storage.release()


def write_calibration(calib: Calibration, path: str | os.PathLike[str]) -> None:
    """Write the calibration as OpenCV FileStorage YAML (all keys, rms when known)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    if not storage.isOpened():
        raise ValueError(f"cannot write calibration file {path}: check the directory is writable")
    try:
        storage.write("image_width", calib.image_size[0])
        storage.write("image_height", calib.image_size[1])
        for key in ("K1", "D1", "K2", "D2", "R", "T", *DERIVED_KEYS):
            storage.write(key, getattr(calib, key))
        if calib.rms is not None:
            storage.write("rms", calib.rms)
        if calib.cameras is not None:
            storage.write("left_camera", calib.cameras[0])
            storage.write("right_camera", calib.cameras[1])
    finally:
        storage.release()


def _from_storage(storage: cv2.FileStorage, path: Path) -> Calibration:
    missing = [key for key in REQUIRED_KEYS if storage.getNode(key).empty()]
    if missing:
        raise ValueError(
            f"calibration file {path} lacks {', '.join(missing)}: it needs at least {', '.join(REQUIRED_KEYS)}"
        )
    size = (_read_int(storage, "image_width", path), _read_int(storage, "image_height", path))
    base = {key: _read_matrix(storage, key, path) for key in ("K1", "D1", "K2", "D2", "R", "T")}
    rms_node = storage.getNode("rms")
    rms = rms_node.real() if not rms_node.empty() and rms_node.isReal() else None
    cameras = _read_cameras(storage, path)
    present = [key for key in DERIVED_KEYS if not storage.getNode(key).empty()]
    try:
        if not present:
            return replace(Calibration.from_extrinsics(size, rms=rms, **base), cameras=cameras)
        if len(present) != len(DERIVED_KEYS):
            absent = [key for key in DERIVED_KEYS if key not in present]
            raise ValueError(
                f"has {', '.join(present)} but lacks {', '.join(absent)}: "
                "remove all of R1, R2, P1, P2, Q to have them derived, or provide all of them"
            )
        derived = {key: _read_matrix(storage, key, path) for key in DERIVED_KEYS}
        stored = Calibration(size, rms=rms, cameras=cameras, **base, **derived)
        fresh = Calibration.from_extrinsics(size, base["K1"], base["D1"], base["K2"], base["D2"], base["R"], base["T"])
        _check_derived(stored, fresh)
        return stored
    except ValueError as exc:
        if str(path) in str(exc):
            raise
        raise ValueError(f"calibration file {path}: {exc}") from None


def _check_derived(stored: Calibration, fresh: Calibration) -> None:
    """Stored R1, R2, P1, P2, Q must follow from K, D, R, T (the zoom of P1/P2, stereoRectify's alpha, may differ)."""
    problems = [key for key in ("R1", "R2") if not np.allclose(getattr(stored, key), getattr(fresh, key), atol=1e-4)]
    tx = stored.P2[0, 3] / stored.P2[0, 0]
    if not np.isclose(-tx, stored.baseline_mm, rtol=1e-3):
        problems.append(f"P2 (baseline {-tx:g} mm, T says {stored.baseline_mm:g} mm)")
    cx, cy, f = stored.P1[0, 2], stored.P1[1, 2], stored.P1[0, 0]
    q = np.array([[1, 0, 0, -cx], [0, 1, 0, -cy], [0, 0, 0, f], [0, 0, -1 / tx, (cx - stored.P2[0, 2]) / tx]])
    if not np.allclose(stored.Q, q, rtol=1e-4, atol=1e-6):
        problems.append("Q (does not match P1 and P2)")
    if problems:
        raise ValueError(
            f"stored {', '.join(problems)} contradict K1, D1, K2, D2, R, T: remove R1, R2, P1, P2 and Q to have "
            "them derived, or re-calibrate"
        )


def _read_cameras(storage: cv2.FileStorage, path: Path) -> tuple[str, str] | None:
    """The calibrated cameras' identities (left_camera, right_camera), both or neither."""
    nodes = [storage.getNode(key) for key in ("left_camera", "right_camera")]
    if all(node.empty() for node in nodes):
        return None
    if not all(node.isString() and node.string() for node in nodes):
        raise ValueError(
            f"calibration file {path}: left_camera and right_camera must both be camera names "
            "(/dev/v4l/by-id/... names or USB serials), or both be absent"
        )
    return nodes[0].string(), nodes[1].string()


def _read_int(storage: cv2.FileStorage, key: str, path: Path) -> int:
    node = storage.getNode(key)
    if not (node.isInt() or node.isReal()) or node.real() != int(node.real()):
        raise ValueError(f"calibration file {path}: {key} must be an integer number of pixels")
    return int(node.real())


def _read_matrix(storage: cv2.FileStorage, key: str, path: Path) -> np.ndarray:
    try:
        matrix = storage.getNode(key).mat()
    except cv2.error:  # rows x cols disagree with the number of data values
        raise ValueError(
            f"calibration file {path}: {key} has rows/cols that do not match its data: correct or re-calibrate"
        ) from None
    if matrix is None or matrix.size == 0:
        raise ValueError(f"calibration file {path}: {key} is not a matrix (expected an !!opencv-matrix)")
    return np.asarray(matrix)
