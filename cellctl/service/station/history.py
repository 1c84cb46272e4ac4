"""The history page's data: journal rows filtered, as CSV, and trend plots (server-side SVG, no JS library)."""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from dataclasses import dataclass
from html import escape

from cellctl.service.journal import SUMMARY_FIELDS, CycleRecord
from cellctl.service.timefmt import iso_time

# The summary with the trigger time, in ISO 8601, named "time" as the station has always called it.
CSV_FIELDS = tuple("time" if name == "triggered_at" else name for name in SUMMARY_FIELDS)


@dataclass(frozen=True)
class HistoryFilter:
    """What the history table shows: status 'all' | 'ok' | 'error', an error code, the newest N."""

    status: str = "all"
    code: int | None = None
    last: int = 200

    @classmethod
    def from_query(cls, query: dict[str, str]) -> HistoryFilter:
        status = query.get("status", "all")
        code_text = query.get("code", "").strip()
        last_text = query.get("last", "200").strip()
        return cls(
            status=status if status in ("all", "ok", "error") else "all",
            code=int(code_text) if code_text.isdigit() else None,
            last=max(1, min(int(last_text), 100_000)) if last_text.isdigit() else 200,
        )

    def apply(self, records: Sequence[CycleRecord]) -> list[CycleRecord]:
        kept = [
            r
            for r in records
            if (self.status == "all" or r.status == self.status) and (self.code is None or r.error_code == self.code)
        ]
        return kept[-self.last :]


def to_csv(records: Sequence[CycleRecord]) -> str:
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=CSV_FIELDS, lineterminator="\n")
    writer.writeheader()
    for r in records:
        row = {name: getattr(r, name, None) for name in CSV_FIELDS}
        row["time"] = iso_time(r.triggered_at)
        writer.writerow(row)
    return out.getvalue()


def trend_svg(values: Sequence[float | None], title: str, unit: str, width: int = 560, height: int = 170) -> str:
    """A line plot of the values (None: a failed cycle, marked red on the axis), min/max labelled."""
    pad_l, pad_r, pad_t, pad_b = 52, 10, 26, 22
    known = [v for v in values if v is not None]
    parts = [
        f'<svg class="trend" viewBox="0 0 {width} {height}" role="img" aria-label="{escape(title)}">',
        f'<rect x="0" y="0" width="{width}" height="{height}" class="bg"/>',
        f'<text x="8" y="17" class="title">{escape(title)} ({escape(unit)})</text>',
    ]
    if not known:
        parts.append(f'<text x="{width // 2 - 40}" y="{height // 2}" class="label">no data yet</text></svg>')
        return "".join(parts)
    low, high = min(known), max(known)
    if high - low < 1e-9:
        low, high = low - 1.0, high + 1.0
    span_x = max(len(values) - 1, 1)

    def xy(i: int, v: float) -> tuple[float, float]:
        x = pad_l + (width - pad_l - pad_r) * i / span_x
        y = pad_t + (height - pad_t - pad_b) * (high - v) / (high - low)
        return x, y

    points = " ".join(f"{x:.1f},{y:.1f}" for i, v in enumerate(values) if v is not None for x, y in [xy(i, v)])
    parts += [
        f'<line x1="{pad_l}" y1="{pad_t}" x2="{pad_l}" y2="{height - pad_b}" class="axis"/>',
        f'<line x1="{pad_l}" y1="{height - pad_b}" x2="{width - pad_r}" y2="{height - pad_b}" class="axis"/>',
        f'<text x="4" y="{pad_t + 4}" class="label">{high:.1f}</text>',
        f'<text x="4" y="{height - pad_b}" class="label">{low:.1f}</text>',
        f'<text x="{pad_l}" y="{height - 5}" class="label">{len(values)} cycles, newest right</text>',
        f'<polyline points="{points}" class="line"/>',
    ]
    for i, v in enumerate(values):
        if v is None:
            x, _ = xy(i, low)
            parts.append(
                f'<line x1="{x:.1f}" y1="{height - pad_b - 6}" x2="{x:.1f}" y2="{height - pad_b}" class="fail"/>'
            )
        elif len(values) <= 60:
            x, y = xy(i, v)
            parts.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="2.5" class="dot"/>')
    parts.append("</svg>")
    return "".join(parts)


def trends(records: Sequence[CycleRecord]) -> list[str]:
    """Length, heel, toe and cycle time over the given cycles, as SVG snippets."""
    return [
        trend_svg([r.length_mm for r in records], "Length", "mm"),
        trend_svg([r.heel_height_mm for r in records], "Heel height", "mm"),
        trend_svg([r.toe_height_mm for r in records], "Toe height", "mm"),
        trend_svg([r.cycle_time_ms for r in records], "Cycle time", "ms"),
    ]
