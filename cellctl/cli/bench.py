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
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # Imported here, not at the top: `cellctl --help` and the light commands must not load them.
    from cellctl.eval import matcher_bench as benchmark

    if args.threads < 1:
        raise ValueError("--threads must be at least 1")
    if args.runs is not None and args.runs < 1:
        raise ValueError("--runs must be at least 1")
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
