"""The calibration page's facts: what the loaded calibration file says, and what `cellctl calibrate` left
beside it (CAL-report.json: board, pairs used, per-pair errors; CAL-errors.png: the error chart)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cellctl.service.timefmt import local_time
from cellctl.vision.calibration import Calibration


@dataclass(frozen=True)
class CalibrationFacts:
    path: Path
    loaded: bool
    written_at: str | None  # the file's modification time, local
    image_size: tuple[int, int] | None = None
    rms_px: float | None = None
    baseline_mm: float | None = None
    focal_px: float | None = None
    report: dict[str, Any] = field(default_factory=dict)  # from CAL-report.json, when present
    chart: Path | None = None


def report_path(calibration: Path) -> Path:
    return calibration.with_name(f"{calibration.stem}-report.json")


def chart_path(calibration: Path) -> Path:
    return calibration.with_name(f"{calibration.stem}-errors.png")


def calibration_facts(calib: Calibration | None, path: Path) -> CalibrationFacts:
    written = local_time(path.stat().st_mtime) if path.is_file() else None
    try:
        report = json.loads(report_path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        report = {}
    chart = chart_path(path) if chart_path(path).is_file() else None
    if calib is None:
        return CalibrationFacts(path, False, written, report=report, chart=chart)
    return CalibrationFacts(
        path,
        True,
        written,
        image_size=calib.image_size,
        rms_px=calib.rms,
        baseline_mm=calib.baseline_mm,
        focal_px=calib.focal_px,
        report=report if isinstance(report, dict) else {},
        chart=chart,
    )
