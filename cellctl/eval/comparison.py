"""Ours against a reference method, scene by scene, per data set; and the radiometric check.

The headline figure of a scene is its `Score.mean_percent`: the mean of nonocc/all/disc on
2001/2003 (the paper's mismatch rate), the bad % over known ground truth outside the left band
on 2005/2006, the mean of nonocc and all on 2014.  A scene is won by the lower figure (a tie is
no win).  Time ratios are mean seconds per scene, ours over the time reference, same run.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from cellctl.eval.middlebury import Scene, SceneResult

OURS = "proposed"
REFERENCE = "opencv-hh4-fill"  # OpenCV HH4 + its post-processing + background fill
TIME_REFERENCE = "opencv-hh4"


@dataclass(frozen=True)
class SceneComparison:
    scene: str
    layout: str
    ours_percent: float
    ours_invalid_percent: float
    reference_percent: float

    @property
    def won(self) -> bool:
        return self.ours_percent < self.reference_percent


@dataclass(frozen=True)
class SetSummary:
    """One data set (layout) of the run."""

    layout: str
    scenes: int
    ours_mean: float
    reference_mean: float
    wins: int
    time_ratio: float | None  # ours / TIME_REFERENCE (or the reference when that did not run)

    @property
    def ratio(self) -> float:
        return self.ours_mean / self.reference_mean if self.reference_mean > 0 else float("inf")


def _by(results: list[SceneResult], method: str) -> dict[str, SceneResult]:
    return {r.scene: r for r in results if r.method == method}


def compare(
    results: list[SceneResult], scenes: list[Scene], ours: str = OURS, reference: str = REFERENCE
) -> list[SceneComparison]:
    """Per scene (in the scenes' order) where both methods ran."""
    mine, theirs = _by(results, ours), _by(results, reference)
    return [
        SceneComparison(
            s.name,
            s.info.layout,
            mine[s.name].score.mean_percent,
            mine[s.name].score.invalid_percent,
            theirs[s.name].score.mean_percent,
        )
        for s in scenes
        if s.name in mine and s.name in theirs
    ]


def summarise(
    results: list[SceneResult], scenes: list[Scene], ours: str = OURS, reference: str = REFERENCE
) -> list[SetSummary]:
    rows = compare(results, scenes, ours, reference)
    timer = TIME_REFERENCE if any(r.method == TIME_REFERENCE for r in results) else reference
    summaries = []
    for layout in dict.fromkeys(r.layout for r in rows):
        part = [r for r in rows if r.layout == layout]
        names = {r.scene for r in part}
        mine = [r.seconds for r in results if r.method == ours and r.scene in names]
        base = [r.seconds for r in results if r.method == timer and r.scene in names]
        summaries.append(
            SetSummary(
                layout,
                len(part),
                float(np.mean([r.ours_percent for r in part])),
                float(np.mean([r.reference_percent for r in part])),
                sum(r.won for r in part),
                float(np.mean(mine) / np.mean(base)) if mine and base and np.mean(base) > 0 else None,
            )
        )
    return summaries


def markdown(results: list[SceneResult], scenes: list[Scene], ours: str = OURS, reference: str = REFERENCE) -> str:
    """Per-scene table and per-set summary of ours against the reference."""
    rows = compare(results, scenes, ours, reference)
    if not rows:
        return ""
    lines = [
        f"| set | scene | {ours} bad % | {ours} invalid % | {reference} bad % | better |",
        "| --- | --- | ---: | ---: | ---: | --- |",
    ]
    for r in rows:
        winner = ours if r.won else (reference if r.reference_percent < r.ours_percent else "tie")
        lines.append(
            f"| {r.layout} | {r.scene} | {r.ours_percent:.2f} | {r.ours_invalid_percent:.2f} "
            f"| {r.reference_percent:.2f} | {winner} |"
        )
    timer = TIME_REFERENCE if any(r.method == TIME_REFERENCE for r in results) else reference
    lines += [
        "",
        f"| set | scenes | {ours} mean % | {reference} mean % | ratio | {ours} better on | time {ours} / {timer} |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for s in summarise(results, scenes, ours, reference):
        time_text = "–" if s.time_ratio is None else f"{s.time_ratio:.2f}"
        lines.append(
            f"| {s.layout} | {s.scenes} | {s.ours_mean:.2f} | {s.reference_mean:.2f} | {s.ratio:.2f} "
            f"| {s.wins} of {s.scenes} | {time_text} |"
        )
    return "\n".join(lines) + "\n"


def radiometric_markdown(runs: dict[str, list[SceneResult]], scenes: list[Scene], methods: list[str]) -> str:
    """Mean figure per set and method for the plain run and each radiometric variant (rise in points)."""
    layouts = list(dict.fromkeys(s.info.layout for s in scenes))
    variants = list(runs)
    header = "| set | method | " + " | ".join(variants) + " |"
    lines = [header, "| --- | --- |" + " ---: |" * len(variants)]
    for layout in layouts:
        names = {s.name for s in scenes if s.info.layout == layout}
        for method in methods:
            means = {v: _mean(runs[v], method, names) for v in variants}
            plain = means[variants[0]]
            cells = [f"{means[variants[0]]:.2f}"] + [f"{means[v]:.2f} ({means[v] - plain:+.2f})" for v in variants[1:]]
            lines.append(f"| {layout} | {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _mean(results: list[SceneResult], method: str, names: set[str]) -> float:
    values = [r.score.mean_percent for r in results if r.method == method and r.scene in names]
    return float(np.mean(values)) if values else float("nan")


def json_summary(results: list[SceneResult], scenes: list[Scene]) -> dict[str, Any]:
    """The comparison as JSON-ready data."""
    return {
        "ours": OURS,
        "reference": REFERENCE,
        "scenes": [
            {
                "scene": r.scene,
                "set": r.layout,
                "ours_percent": r.ours_percent,
                "ours_invalid_percent": r.ours_invalid_percent,
                "reference_percent": r.reference_percent,
                "won": r.won,
            }
            for r in compare(results, scenes)
        ],
        "sets": [
            {
                "set": s.layout,
                "scenes": s.scenes,
                "ours_mean": s.ours_mean,
                "reference_mean": s.reference_mean,
                "ratio": s.ratio,
                "wins": s.wins,
                "time_ratio": s.time_ratio,
            }
            for s in summarise(results, scenes)
        ],
    }
