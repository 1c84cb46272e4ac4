"""Tables of a Middlebury evaluation run: markdown, CSV and JSON, with the paper's Table 3 beside ours."""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from cellctl.eval import paper_table3
from cellctl.eval.methods import METHODS
from cellctl.eval.middlebury import BAD_PIXEL_THRESHOLD, REGIONS, SCENES, SceneInfo, SceneResult, average_percent

AVERAGE = "average"
TIME_REFERENCE = "opencv-hh4"  # run times are also given relative to this method


@dataclass(frozen=True)
class Row:
    """One line of the tables: a method (ours or the paper's) on one scene or on average."""

    source: str  # "ours" or "paper"
    method: str
    scene: str  # scene name or "average"
    mean_percent: float  # per scene: mean of the regions; average: mean of all region rates
    seconds: float  # per scene: run time; average: mean run time per scene
    bad_percent: dict[str, float] | None = None  # region -> %, ours only
    invalid_percent: float | None = None  # ours only
    time_vs_reference: float | None = None  # seconds / the reference method's, averages only


def build_rows(results: list[SceneResult]) -> list[Row]:
    """Rows per scene (Middlebury's scene order) and then averages; the paper's rows after ours."""
    scenes = list(dict.fromkeys(r.scene for r in results))
    methods = list(dict.fromkeys(r.method for r in results))
    rows: list[Row] = []
    for scene in scenes:
        rows += [_scene_row(r) for r in results if r.scene == scene]
        for column in paper_table3.COLUMNS if scene in SCENES else ():
            cell = paper_table3.TABLE3[column][scene]
            rows.append(Row("paper", column, scene, cell.mismatch_percent, cell.seconds))
    averages = [_average_row(m, [r for r in results if r.method == m]) for m in methods]
    reference = next((row.seconds for row in averages if row.method == TIME_REFERENCE), None)
    for row in averages:
        ratio = row.seconds / reference if reference else None
        rows.append(replace(row, time_vs_reference=ratio))
    if set(scenes) == set(SCENES):  # the paper's averages are over exactly its four scenes
        for column in paper_table3.COLUMNS:
            # As printed where printed; Reference [18] has none, so the mean of its scenes.
            mean = paper_table3.PRINTED_AVERAGE[column] or paper_table3.average(column)
            rows.append(Row("paper", column, AVERAGE, mean.mismatch_percent, mean.seconds))
    return rows


def _scene_row(result: SceneResult) -> Row:
    score = result.score
    return Row(
        "ours",
        result.method,
        result.scene,
        score.mean_percent,
        result.seconds,
        dict(score.bad_percent),
        score.invalid_percent,
    )


def _average_row(method: str, results: list[SceneResult]) -> Row:
    bad = {
        region: float(np.mean([r.score.bad_percent[region] for r in results]))
        for region in REGIONS
        if all(region in r.score.bad_percent for r in results)
    }
    return Row(
        "ours",
        method,
        AVERAGE,
        average_percent(results),
        float(np.mean([r.seconds for r in results])),
        bad,
        float(np.mean([r.score.invalid_percent for r in results])),
    )


def _label(row: Row) -> str:
    return row.method if row.source == "ours" else f"paper: {row.method}"


def _number(value: float | None, digits: int) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def markdown(rows: list[Row], repeat: int = 1) -> str:
    """Two markdown tables: per scene, then averages (ours, then the paper's Table 3)."""
    header = ["scene", "method", *(f"{r} %" for r in REGIONS), "mean %", "invalid %", "time s"]
    per_scene = [
        [
            row.scene,
            _label(row),
            *_region_cells(row),
            _number(row.mean_percent, 2),
            _number(row.invalid_percent, 2),
            _number(row.seconds, 3),
        ]
        for row in rows
        if row.scene != AVERAGE
    ]
    average_header = [
        "method",
        *(f"{r} %" for r in REGIONS),
        "average %",
        "invalid %",
        "time s / scene",
        f"time / {TIME_REFERENCE}",
    ]
    averages = [
        [
            _label(row),
            *_region_cells(row),
            _number(row.mean_percent, 2),
            _number(row.invalid_percent, 2),
            _number(row.seconds, 3),
            _number(row.time_vs_reference, 2),
        ]
        for row in rows
        if row.scene == AVERAGE
    ]
    notes = (
        f"Bad pixels: |d - gt| > {BAD_PIXEL_THRESHOLD:g} px or no disparity, over mask pixels = 255 "
        "(2005/2006: known ground truth outside the left band of ndisp px, shown as all). "
        "Per scene, mean % is the mean of nonocc, all and disc (the paper's per-scene mismatch rate); "
        "average % is the mean of all region rates (12 numbers over four scenes). "
        f"Our times are wall-clock seconds per scene, the fastest of {repeat} run(s). "
        "Paper times are Matlab on an i5-4200H; the paper's Reference [18] average is not printed "
        "in its table, shown here as the mean of its scenes."
    )
    tables = [_markdown_table(header, per_scene, 2), _markdown_table(average_header, averages, 1)]
    return "\n\n".join([*tables, notes]) + "\n"


def _region_cells(row: Row) -> list[str]:
    return [_number(None if row.bad_percent is None else row.bad_percent.get(r), 2) for r in REGIONS]


def _markdown_table(header: list[str], body: list[list[str]], text_columns: int) -> str:
    """A table whose first `text_columns` columns are left-aligned text and the rest numbers."""
    rule = ["---"] * text_columns + ["---:"] * (len(header) - text_columns)
    return "\n".join("| " + " | ".join(cells) + " |" for cells in [header, rule, *body])


CSV_FIELDS = (
    "source",
    "method",
    "scene",
    *(f"{r}_percent" for r in REGIONS),
    "mean_percent",
    "invalid_percent",
    "seconds",
    "time_vs_reference",
)


def _record(row: Row) -> dict[str, Any]:
    regions = {f"{r}_percent": None if row.bad_percent is None else row.bad_percent.get(r) for r in REGIONS}
    return {
        "source": row.source,
        "method": row.method,
        "scene": row.scene,
        **regions,
        "mean_percent": row.mean_percent,
        "invalid_percent": row.invalid_percent,
        "seconds": row.seconds,
        "time_vs_reference": row.time_vs_reference,
    }


def csv_text(rows: list[Row]) -> str:
    """All rows as CSV (empty cells where a paper row has no value)."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=CSV_FIELDS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: "" if v is None else v for k, v in _record(row).items()})
    return buffer.getvalue()


def json_document(
    rows: list[Row], data_dir: Path, repeat: int = 1, infos: dict[str, SceneInfo] | None = None
) -> dict[str, Any]:
    """The run as a JSON-ready dict: settings, methods, scenes and every row."""
    methods = list(dict.fromkeys(row.method for row in rows if row.source == "ours"))
    return {
        "benchmark": "middlebury-v2",
        "data_dir": str(data_dir),
        "threshold_px": BAD_PIXEL_THRESHOLD,
        "time_reference": TIME_REFERENCE,
        "timing": f"wall-clock seconds per scene, fastest of {repeat} run(s)",
        "scenes": {
            name: {
                "set": info.layout,
                "min_disparity": info.min_disparity,
                "num_disparities": info.num_disparities,
                "scale": info.scale,
            }
            for name, info in (infos if infos is not None else SCENES).items()
            if any(row.scene == name for row in rows)
        },
        "methods": {
            name: {"summary": METHODS[name].summary, "paper_column": METHODS[name].paper_column}
            for name in methods
            if name in METHODS
        },
        "rows": [_record(row) for row in rows],
    }
