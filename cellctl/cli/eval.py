"""`cellctl eval middlebury`: score stereo methods on Middlebury v2 beside the paper's Table 3."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from cellctl.cli.progress import ProgressBar


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "eval",
        help="evaluate stereo methods on benchmark data",
        description="Evaluate stereo methods on benchmark data.",
    )
    benchmarks = parser.add_subparsers(dest="benchmark", metavar="BENCHMARK", required=True)
    middlebury_parser = benchmarks.add_parser(
        "middlebury",
        help="Middlebury v2 (Tsukuba, Venus, Teddy, Cones) bad-pixel rates and run times",
        description="Run stereo methods on the four Middlebury v2 scenes and print bad-pixel rates (1 px; "
        "nonocc, all, disc; no disparity counts as bad) and run times beside the paper's Table 3.",
    )
    middlebury_parser.add_argument(
        "--data",
        type=Path,
        default=None,
        help="Middlebury folder with tsukuba/ venus/ teddy/ cones/ (default: $CELLCTL_MIDDLEBURY, else "
        "../shared/data/middlebury/2001-2003)",
    )
    middlebury_parser.add_argument(
        "--methods",
        nargs="+",
        metavar="METHOD",
        help="methods to run (default: all; an unknown name is refused with the list)",
    )
    middlebury_parser.add_argument(
        "--scenes",
        nargs="+",
        metavar="SCENE",
        help="scenes to run (default: all): tsukuba venus teddy cones",
    )
    middlebury_parser.add_argument(
        "--repeat", type=int, default=3, help="runs per method and scene; the fastest time is reported (default: 3)"
    )
    middlebury_parser.add_argument("--json", action="store_true", help="print JSON instead of markdown tables")
    middlebury_parser.add_argument(
        "-o", "--out", type=Path, default=None, help="folder for middlebury.md, .csv, .json and one PNG grid per scene"
    )
    middlebury_parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # Imported here, not at the top: `cellctl --help` and the light commands must not load them.
    from cellctl.eval import middlebury
    from cellctl.eval import pictures as middlebury_pictures
    from cellctl.eval import report as middlebury_report
    from cellctl.eval.methods import select_methods

    if args.repeat < 1:
        raise ValueError(f"--repeat must be at least 1, got {args.repeat}")
    if args.out is not None and args.out.exists() and not args.out.is_dir():
        raise ValueError(f"--out {args.out} is a file; give a folder for the tables and pictures")
    data_dir = middlebury.resolve_data_dir(args.data)
    methods = select_methods(args.methods)
    scenes = middlebury.load_scenes(args.scenes, data_dir)
    progress = ProgressBar(len(methods) * len(scenes))
    results = middlebury.evaluate(
        {m.name: m.compute for m in methods},
        scenes,
        args.repeat,
        on_run=lambda method, scene: progress.advance(f"{method} on {scene.name}"),
    )
    progress.finish()
    rows = middlebury_report.build_rows(results)
    document = middlebury_report.json_document(rows, data_dir, args.repeat)
    if args.json:
        print(json.dumps(document, indent=2))
    else:
        print(middlebury_report.markdown(rows, args.repeat), end="")
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "middlebury.md").write_text(middlebury_report.markdown(rows, args.repeat))
        (args.out / "middlebury.csv").write_text(middlebury_report.csv_text(rows))
        (args.out / "middlebury.json").write_text(json.dumps(document, indent=2) + "\n")
        pictures = middlebury_pictures.write_scene_grids(scenes, results, args.out)
        print(f"wrote middlebury.md, .csv, .json and {len(pictures)} PNG grid(s) to {args.out}", file=sys.stderr)
    return 0
