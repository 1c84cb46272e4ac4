"""Speed benchmark of the matcher against OpenCV's StereoSGBM, in one process.

Each method is created once (buffers kept, as a running cell would), run once
to warm up, then timed over several runs; the median is reported with the
throughput in million disparity evaluations per second (MDE/s = width x height
x disparities / time) and the peak resident memory the method added.  This is
a benchmark that prints figures, not a test: it asserts nothing.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from cellctl.eval.methods import sgbm_create
from cellctl.eval.middlebury import resolve_data_dir
from cellctl.stereo import StereoMatcher


@dataclass(frozen=True)
class Case:
    name: str
    left: np.ndarray
    right: np.ndarray
    num_disparities: int
    runs: int

    @property
    def cells(self) -> int:
        h, w = self.left.shape[:2]
        return w * h * self.num_disparities


@dataclass(frozen=True)
class Timing:
    case: str
    method: str
    size: str
    disparities: int
    median_ms: float
    min_ms: float
    mde_per_s: float
    peak_mib: float
    runs: int


def teddy_case(data_dir: Path | None = None, runs: int = 9) -> Case:
    d = resolve_data_dir(data_dir) / "teddy"
    left, right = cv2.imread(str(d / "left.png")), cv2.imread(str(d / "right.png"))
    if left is None or right is None:
        raise FileNotFoundError(f"Teddy images not found in {d}; pass --data with the Middlebury 2001-2003 folder")
    return Case("teddy", left, right, 64, runs)


def synthetic_case(
    width: int = 1280, height: int = 1024, num_disparities: int = 192, runs: int = 5, seed: int = 0
) -> Case:
    """A textured pair with a smooth disparity field spanning most of the range."""
    rng = np.random.default_rng(seed)
    texture = cv2.GaussianBlur(rng.integers(0, 256, (height, width + num_disparities), np.uint8), (0, 0), 1.2)
    texture = cv2.normalize(texture, np.empty_like(texture), 0, 255, cv2.NORM_MINMAX)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    disparity = 0.1 * num_disparities + 0.8 * num_disparities * (0.5 + 0.5 * np.sin(xx / 211.0) * np.cos(yy / 157.0))
    # left(x) = right(x - d): sample the right texture at x - d.
    right = texture[:, num_disparities:].copy()
    left = cv2.remap(texture, xx + num_disparities - disparity, yy, cv2.INTER_LINEAR)
    return Case(
        f"synthetic {width}x{height}",
        cv2.cvtColor(left, cv2.COLOR_GRAY2BGR),
        cv2.cvtColor(right, cv2.COLOR_GRAY2BGR),
        num_disparities,
        runs,
    )


def _sgbm(mode: int, num_disparities: int) -> cv2.StereoSGBM:
    return sgbm_create(mode, 0, num_disparities, channels=3)  # colour input, as OpenCV users feed it


def methods(case: Case, ours: StereoMatcher) -> dict[str, Callable[[], object]]:
    """Each method's compute bound to the case; OpenCV's SGBM needs a multiple of 16 disparities."""
    nd = -(-case.num_disparities // 16) * 16
    hh4, three_way = _sgbm(cv2.StereoSGBM_MODE_HH4, nd), _sgbm(cv2.StereoSGBM_MODE_SGBM_3WAY, nd)
    return {
        "ours": lambda: ours.compute(case.left, case.right),
        "opencv-hh4": lambda: hh4.compute(case.left, case.right),
        "opencv-3way": lambda: three_way.compute(case.left, case.right),
    }


def _rss_peak_reset() -> bool:
    """Reset the kernel's peak-RSS mark (Linux clear_refs 5); False where not possible."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def _status_kib(key: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    return 0


def time_method(case: Case, name: str, run: Callable[[], object]) -> Timing:
    base = _status_kib("VmRSS")
    can_reset = _rss_peak_reset()
    run()  # warm-up: buffers allocated and touched, as in a running cell
    times = []
    for _ in range(case.runs):
        t0 = time.perf_counter()
        run()
        times.append(time.perf_counter() - t0)
    peak = (_status_kib("VmHWM") - base) / 1024 if can_reset else float("nan")
    med = statistics.median(times)
    h, w = case.left.shape[:2]
    return Timing(
        case.name,
        name,
        f"{w}x{h}",
        case.num_disparities,
        med * 1e3,
        min(times) * 1e3,
        case.cells / med / 1e6,
        peak,
        case.runs,
    )


def run_benchmark(
    cases: list[Case], threads: int = 2, progress: Callable[[str], None] | None = None
) -> tuple[list[Timing], dict[str, str]]:
    """Times every method on every case with `threads` threads for everyone; also returns, per case,
    the core's own buffers after our timed runs."""
    cv2.setNumThreads(threads)
    results, buffers = [], {}
    for case in cases:
        ours = StereoMatcher(0, case.num_disparities, threads=threads)
        for name, run in methods(case, ours).items():
            if progress:
                progress(f"{case.name}: {name}")
            results.append(time_method(case, name, run))
        total = ours.buffer_bytes
        buffers[case.name] = f"{total / 2**20:.0f} MiB = {total / case.cells:.2f} B/cell"
    return results, buffers


def ratios(results: list[Timing]) -> dict[str, dict[str, float]]:
    """ours / OpenCV time per case (below 1.0: ours is faster)."""
    out: dict[str, dict[str, float]] = {}
    for case in dict.fromkeys(r.case for r in results):
        by = {r.method: r.median_ms for r in results if r.case == case}
        out[case] = {f"ours/{m}": by["ours"] / by[m] for m in ("opencv-hh4", "opencv-3way")}
    return out


def to_markdown(results: list[Timing], threads: int, core_bytes: dict[str, str]) -> str:
    lines = [
        f"threads: {threads}",
        "",
        "| case | method | size | disparities | median ms | min ms | MDE/s | peak MiB |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in results:
        lines.append(
            f"| {r.case} | {r.method} | {r.size} | {r.disparities} | {r.median_ms:.1f} | "
            f"{r.min_ms:.1f} | {r.mde_per_s:.0f} | {r.peak_mib:.0f} |"
        )
    lines += ["", "| case | ours/opencv-hh4 | ours/opencv-3way | core buffers (ours) |", "| --- | ---: | ---: | --- |"]
    for case, rs in ratios(results).items():
        lines.append(
            f"| {case} | {rs['ours/opencv-hh4']:.2f} | {rs['ours/opencv-3way']:.2f} | {core_bytes.get(case, '')} |"
        )
    return "\n".join(lines)


def as_json(results: list[Timing], threads: int, summaries: dict[str, str]) -> dict:
    return {
        "threads": threads,
        "results": [asdict(r) for r in results],
        "ratios": ratios(results),
        "core_buffers": summaries,
    }
