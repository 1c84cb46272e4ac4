"""Cycle time as a multiple of OpenCV StereoSGBM HH4 on the same pair, in the same run (docs/benchmarks.md, 4).

A figure that does not depend on the machine: the cycle's measurement (what the service runs between a
grab and the answer: the mean of the exposures, cellctl.cameras.averaging, then
`cellctl.service.cycle.measure_frame`: reconstruct, then measure_sole) against the time OpenCV StereoSGBM in MODE_HH4 needs to
match the same rectified pair over the cell's whole disparity range. The two are timed alternately, one
cycle then one HH4 match, so both see the same load; the ratio is median cycle / median HH4.

`bench_cycles` runs the cycle in this process on simulated soles (the reconstructor taught on the empty
table and warmed up as the daemon does before READY); `HH4Reference` is the OpenCV side, also used by
`cellctl demo` beside the service's own cycle times.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from cellctl.cameras.averaging import average_frames
from cellctl.cameras.config import AVERAGED_FRAMES
from cellctl.eval.methods import opencv_sgbm
from cellctl.eval.sole_bench import scene_exposures
from cellctl.sim.scene import SoleScene
from cellctl.vision.calibration import Calibration
from cellctl.vision.defaults import GLUE_OFFSET_MM, GLUE_SPACING_MM
from cellctl.vision.measurement import MeasurementResult, SoleMeasurement, measure_sole
from cellctl.vision.reconstruction import DEFAULT_DEPTH_RANGE_MM, SoleReconstructor
from cellctl.vision.runtime import keep_freed_memory, one_blas_thread, settle_garbage_collector

DEFAULT_SOLES: tuple[tuple[int, str], ...] = ((1, "white"), (2, "black"), (3, "white"), (4, "black"))


class HH4Reference:
    """OpenCV StereoSGBM MODE_HH4 (cellctl.eval.methods settings) on a rectified pair over the cell's range."""

    def __init__(self, calib: Calibration, left: np.ndarray, right: np.ndarray, disparities: tuple[int, int]) -> None:
        self.left, self.right = calib.rectify(left, right)
        self.image_size = calib.image_size
        self.disparities = disparities
        self.min_disparity, self.num_disparities = disparities
        self._match = opencv_sgbm(cv2.StereoSGBM_MODE_HH4)
        self.seconds()  # the first call allocates OpenCV's buffers, as our matcher's warm-up does

    def seconds(self) -> float:
        """Wall time of one match of the pair."""
        start = time.perf_counter()
        self._match(self.left, self.right, self.min_disparity, self.num_disparities)
        return time.perf_counter() - start


@dataclass
class CycleBench:
    """Cycle times (first included, in order), per-stage times, HH4 times, and the errors against the truth."""

    image_size: tuple[int, int]
    disparities: tuple[int, int]  # (min, num) of the cell's range: what HH4 matches
    cycles_s: list[float] = field(default_factory=list)
    stages_s: dict[str, list[float]] = field(default_factory=dict)
    hh4_s: list[float] = field(default_factory=list)
    errors_mm: list[dict[str, float]] = field(default_factory=list)  # measured - true, per measured cycle
    refused: list[str] = field(default_factory=list)
    whole_pair: list[str] = field(default_factory=list)  # why a cycle matched the whole pair

    @property
    def median_s(self) -> float:
        return statistics.median(self.cycles_s)

    @property
    def hh4_median_s(self) -> float:
        return statistics.median(self.hh4_s)

    @property
    def ratio(self) -> float:
        return self.median_s / self.hh4_median_s

    def summary(self) -> str:
        """The figure in one paragraph (as `cellctl demo` prints it)."""
        return cycle_summary(self.cycles_s, self.hh4_s, self.image_size, self.disparities)

    def to_markdown(self) -> str:
        lines = [
            self.summary(),
            "",
            "| stage | median ms | max ms |",
            "| :-- | --: | --: |",
        ]
        for name, values in self.stages_s.items():
            lines.append(f"| {name} | {1000 * statistics.median(values):.1f} | {1000 * max(values):.1f} |")
        if self.errors_mm:
            worst = {k: max(abs(e[k]) for e in self.errors_mm) for k in self.errors_mm[0]}
            lines += ["", "largest error (measured - true): " + ", ".join(f"{k} {v:.2f} mm" for k, v in worst.items())]
        lines.append(f"measured {len(self.errors_mm)} of {len(self.cycles_s)} cycles")
        lines += [f"refused: {reason}" for reason in self.refused]
        if self.whole_pair:
            lines.append(
                f"whole pair matched in {len(self.whole_pair)} cycles: " + "; ".join(sorted(set(self.whole_pair)))
            )
        return "\n".join(lines)


def cycle_summary(
    cycles_s: list[float], hh4_s: list[float], image_size: tuple[int, int], disparities: tuple[int, int]
) -> str:
    """Median, max and first cycle beside OpenCV HH4's median on the same pair, and their ratio."""
    median, hh4 = statistics.median(cycles_s), statistics.median(hh4_s)
    width, height = image_size
    return (
        f"cycle over {len(cycles_s)} cycles: median {1000 * median:.0f} ms, max {1000 * max(cycles_s):.0f} ms "
        f"({max(cycles_s) / median:.2f} x median), first {1000 * cycles_s[0]:.0f} ms "
        f"({cycles_s[0] / median:.2f} x median); OpenCV StereoSGBM HH4 on the same {width}x{height} pair, "
        f"{disparities[1]} disparities, same run: median {1000 * hh4:.0f} ms over {len(hh4_s)} matches; "
        f"cycle / HH4 = {median / hh4:.2f}"
    )


def bench_cycles(
    calib: Calibration,
    cycles: int = 20,
    soles: tuple[tuple[int, str], ...] = DEFAULT_SOLES,
    depth_range_mm: tuple[float, float] = DEFAULT_DEPTH_RANGE_MM,
    progress: Callable[[str], None] | None = None,
    whole_pair: bool = False,
    frames: int = AVERAGED_FRAMES,
) -> CycleBench:
    """`cycles` cycles over the rendered soles in turn, each followed by one HH4 match of the first pair.

    whole_pair: the cycle as it was before the search region (no taught table: the table found in every
    cycle, the whole pair matched over the whole range), for comparison. frames: exposures of each sole a cycle
    averages ([cameras] averaged_frames), timed with it.
    """
    if cycles < 1:
        raise ValueError(f"cycles must be at least 1, got {cycles}")
    one_blas_thread()  # as the service does (cellctl.service.measuring)
    keep_freed_memory()  # as the service does
    scenes = [SoleScene.random(seed, color, calib) for seed, color in soles]
    exposures = [scene_exposures(scene, frames) for scene in scenes]
    truths = [scene.sole.truth() for scene in scenes if scene.sole is not None]
    # The simulator draws each scene's table texture from its seed: every scene is its own cell, taught on
    # its own empty table (`cellctl teach`) and warmed up as the daemon does before READY.
    reconstructors = [_reconstructor(calib, depth_range_mm, scene, whole_pair) for scene in scenes]
    disparities = (reconstructors[0].min_disparity, reconstructors[0].num_disparities)

    def cycle(which: int) -> MeasurementResult:
        start = time.perf_counter()
        pair = average_frames(exposures[which])
        averaging = time.perf_counter() - start
        reconstruction = reconstructors[which].reconstruct(
            pair.left, pair.right, pair.averaged, pair.info.get("averaged_frames")
        )
        result = measure_sole(reconstruction, GLUE_OFFSET_MM, GLUE_SPACING_MM)
        result.timings["average"] = averaging  # as the service times it (CameraHealth.grab)
        return result

    for which in range(len(exposures)):
        cycle(which)  # the warm-up
    settle_garbage_collector()  # as the service does after its warm-up
    measured = exposures[0][-1]  # the exposure a cycle matches
    reference = HH4Reference(calib, measured.left, measured.right, disparities)
    bench = CycleBench(calib.image_size, disparities)
    for index in range(cycles):
        which = index % len(exposures)
        start = time.perf_counter()
        result = cycle(which)
        bench.cycles_s.append(time.perf_counter() - start)
        bench.hh4_s.append(reference.seconds())
        for name, seconds in result.timings.items():
            bench.stages_s.setdefault(name, []).append(seconds)
        if reconstructors[which].last_fallback:
            bench.whole_pair.append(reconstructors[which].last_fallback)
        if isinstance(result, SoleMeasurement):
            truth = truths[which]
            bench.errors_mm.append(
                {
                    "length": result.length_mm - truth.length_mm,
                    "heel": result.heel_height_mm - truth.heel_height_mm,
                    "toe": result.toe_height_mm - truth.toe_height_mm,
                }
            )
        else:
            bench.refused.append(f"sole {soles[which][0]}: {result.reason}")
        if progress:
            progress(f"cycle {index + 1}: {1000 * bench.cycles_s[-1]:.0f} ms, HH4 {1000 * bench.hh4_s[-1]:.0f} ms")
    return bench


def _reconstructor(
    calib: Calibration, depth_range_mm: tuple[float, float], scene: SoleScene, whole_pair: bool
) -> SoleReconstructor:
    if whole_pair:
        return SoleReconstructor(calib, depth_range_mm, search_region=False)
    empty = scene.render_empty()
    taught = SoleReconstructor(calib, depth_range_mm).teach(empty.left, empty.right)
    return SoleReconstructor(calib, depth_range_mm, taught=taught)
