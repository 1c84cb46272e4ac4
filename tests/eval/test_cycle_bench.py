"""The cycle bench: cycles and OpenCV HH4 timed alternately on the same pair, figures consistent, no timing asserted."""

from __future__ import annotations

import statistics

import pytest

from cellctl.eval.cycle_bench import bench_cycles
from cellctl.sim.rig import default_rig

pytestmark = pytest.mark.slow  # renders, teaches and measures (the 1280x1024 rig: teaching needs its noise level)


def test_cycles_and_hh4_alternate_and_the_ratio_is_of_their_medians() -> None:
    bench = bench_cycles(default_rig(), cycles=3, soles=((1, "white"),))
    assert len(bench.cycles_s) == len(bench.hh4_s) == 3
    assert bench.ratio == pytest.approx(statistics.median(bench.cycles_s) / statistics.median(bench.hh4_s))
    assert bench.image_size == (1280, 1024) and bench.disparities[1] > 40
    assert not bench.refused and len(bench.errors_mm) == 3
    assert not bench.whole_pair  # the taught table's search region held the sole every time
    assert all(abs(v) < 1.3 for errors in bench.errors_mm for v in errors.values())
    assert {"rectify", "coarse", "match", "reproject"} <= set(bench.stages_s)
    text = bench.to_markdown()
    assert f"cycle / HH4 = {bench.ratio:.2f}" in text and "| match |" in text
