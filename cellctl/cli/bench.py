"""`cellctl bench`: our matcher against OpenCV StereoSGBM (HH4 and 3-way), same process, same threads."""

from __future__ import annotations

import argparse
import json
import sys


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("bench", help="time the matcher against OpenCV StereoSGBM", description=__doc__)
    p.add_argument("--threads", type=int, default=2, help="threads for every method (default 2)")
    p.add_argument("--data", help="Middlebury 2001-2003 folder (default ../shared/data/middlebury/2001-2003)")
    p.add_argument("--runs", type=int, default=None, help="timed runs per method (default 9 Teddy, 5 synthetic)")
    p.add_argument("--json", action="store_true", help="print JSON instead of markdown")
    p.add_argument(
        "--cycle",
        action="store_true",
        help="instead: the cell's measurement cycle on simulated soles against OpenCV HH4 on the same pair",
    )
    p.add_argument("--cycles", type=int, default=20, help="with --cycle: cycles to time (default 20)")
    p.add_argument(
        "--whole-pair",
        action="store_true",
        help="with --cycle: no taught table, the whole pair matched (the cycle before the search region)",
    )
    p.add_argument(
        "--frames",
        type=int,
        metavar="N",
        help="with --cycle: exposures each cycle averages (default: the default of [cameras] averaged_frames)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # Imported here, not at the top: `cellctl --help` and the light commands must not load them.
    from cellctl.eval import matcher_bench as benchmark

    if args.threads < 1:
        raise ValueError("--threads must be at least 1")
    if args.runs is not None and args.runs < 1:
        raise ValueError("--runs must be at least 1")
    if args.frames is not None and not args.cycle:
        raise ValueError("--frames needs --cycle")
    if args.cycle:
        return run_cycle(args.cycles, args.whole_pair, args.frames)
    teddy = benchmark.teddy_case(args.data, runs=args.runs or 9)
    synthetic = benchmark.synthetic_case(runs=args.runs or 5)
    results, summaries = benchmark.run_benchmark(
        [teddy, synthetic], args.threads, progress=lambda s: print(f"  {s}", file=sys.stderr)
    )
    if args.json:
        print(json.dumps(benchmark.as_json(results, args.threads, summaries), indent=2))
    else:
        print(benchmark.to_markdown(results, args.threads, summaries))
    return 0


def run_cycle(cycles: int, whole_pair: bool, frames: int | None = None) -> int:
    """`cellctl bench --cycle`: cellctl.eval.cycle_bench on the simulated rig of deploy/sim-calib.yaml."""
    from cellctl.cameras.config import frames_option
    from cellctl.cli.demo_cell import DEFAULT_CONFIG
    from cellctl.eval.cycle_bench import bench_cycles
    from cellctl.vision.calibration import Calibration

    if cycles < 1:
        raise ValueError(f"--cycles {cycles} must be at least 1")
    frames = frames_option(frames)
    calib = Calibration.load(DEFAULT_CONFIG.parent / "sim-calib.yaml")
    bench = bench_cycles(
        calib,
        cycles,
        progress=lambda s: print(f"  {s}", file=sys.stderr, flush=True),
        whole_pair=whole_pair,
        frames=frames,
    )
    print(bench.to_markdown())
    return 0
