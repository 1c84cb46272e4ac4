"""The account of a calibration: how each pair contributed, as a table and a bar chart."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from cellctl.vision.calibration import Calibration


@dataclass
class PairResult:
    """The outcome for one pair: kept, rejected as an outlier, or skipped before calibrating."""

    name: str
    status: str  # "kept", "rejected" or "skipped"
    error_px: float | None  # RMS reprojection error over both images (for rejected pairs: when rejected)
    note: str = ""


@dataclass
class CalibrationResult:
    """A calibration and the account of how each pair contributed to it."""

    calibration: Calibration
    pairs: list[PairResult]
    threshold_px: float  # outlier threshold of the last rejection round

    @property
    def kept(self) -> list[str]:
        return [p.name for p in self.pairs if p.status == "kept"]

    @property
    def rejected(self) -> list[str]:
        """Names of the pairs not used: outliers and pairs without usable corners."""
        return [p.name for p in self.pairs if p.status != "kept"]

    def table(self) -> str:
        """The per-pair table printed by `cellctl calibrate`."""
        lines = [f"{'pair':<8}{'status':<10}{'error px':>9}  note"]
        for pair in self.pairs:
            error = f"{pair.error_px:9.3f}" if pair.error_px is not None else f"{'-':>9}"
            lines.append(f"{pair.name:<8}{pair.status:<10}{error}  {pair.note}".rstrip())
        c = self.calibration
        lines.append(
            f"kept {len(self.kept)} of {len(self.pairs)} pairs; final outlier threshold {self.threshold_px:.3f} px; "
            f"RMS {c.rms:.3f} px; baseline {c.baseline_mm:.2f} mm; "
            f"f {c.K1[0, 0]:.1f}/{c.K2[0, 0]:.1f} px (left/right)"
        )
        return "\n".join(lines)

    def error_chart(self) -> np.ndarray:
        """Bar chart of the per-pair errors with the outlier threshold, as a BGR image."""
        return _draw_error_chart(self.pairs, self.threshold_px)


def _draw_error_chart(pairs: Sequence[PairResult], threshold_px: float) -> np.ndarray:
    colours = {"kept": (80, 170, 60), "rejected": (50, 50, 220), "skipped": (150, 150, 150)}
    bar, gap, left, bottom, top, plot_h = 36, 12, 70, 60, 40, 320
    width = max(480, left + len(pairs) * (bar + gap) + gap + 20)
    chart = np.full((top + plot_h + bottom, width, 3), 255, np.uint8)
    measured = [p.error_px for p in pairs if p.error_px is not None]
    finite_threshold = threshold_px if np.isfinite(threshold_px) else 0.0
    scale_max = max([*measured, finite_threshold, 1e-3])
    if finite_threshold > 0:
        # One wild pair would flatten all the others: clip the axis and label the clipped bars instead.
        scale_max = min(scale_max, 4.0 * finite_threshold)
    scale_max *= 1.1
    base_y = top + plot_h

    def y_of(value: float) -> int:
        return int(round(base_y - value / scale_max * plot_h))

    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(chart, "RMS reprojection error per pair (px)", (left, 25), font, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    for tick in np.linspace(0, scale_max, 5):
        y = y_of(tick)
        cv2.line(chart, (left - 5, y), (width - 10, y), (225, 225, 225), 1)
        cv2.putText(chart, f"{tick:.2f}", (8, y + 5), font, 0.45, (60, 60, 60), 1, cv2.LINE_AA)
    for i, pair in enumerate(pairs):
        x0 = left + gap + i * (bar + gap)
        if pair.error_px is not None:
            clipped = pair.error_px > scale_max
            bar_top = y_of(min(pair.error_px, scale_max))
            cv2.rectangle(chart, (x0, bar_top), (x0 + bar, base_y), colours[pair.status], -1)
            if clipped:
                cv2.putText(chart, f"{pair.error_px:.2f}", (x0, top - 4), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        else:  # skipped: no error to show, mark the slot
            cv2.putText(chart, "x", (x0 + bar // 2 - 6, base_y - 6), font, 0.6, colours["skipped"], 2, cv2.LINE_AA)
        cv2.putText(chart, pair.name[:5], (x0, base_y + 20), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.line(chart, (left, base_y), (width - 10, base_y), (0, 0, 0), 1)
    if finite_threshold > 0:
        y = y_of(finite_threshold)
        for x in range(left, width - 10, 14):  # dashed: OpenCV has no dashed line
            cv2.line(chart, (x, y), (min(x + 8, width - 10), y), (0, 0, 200), 1)
        label = f"threshold {finite_threshold:.3f}"
        cv2.putText(chart, label, (width - 190, y - 6), font, 0.45, (0, 0, 200), 1, cv2.LINE_AA)
    legend = "green: kept   red: rejected   x: no corners (skipped)"
    cv2.putText(chart, legend, (left, base_y + 45), font, 0.45, (60, 60, 60), 1, cv2.LINE_AA)
    return chart
