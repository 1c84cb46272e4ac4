"""`cellctl eval middlebury`: score stereo methods on Middlebury scenes (beside the paper's Table 3 on v2)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from cellctl.cli.progress import ProgressBar

# Methods of a run on data other than the four 2001/2003 scenes: ours, the comparison's reference
# (cellctl.eval.comparison.OURS, REFERENCE) and plain HH4 for the time ratio (TIME_REFERENCE).
DEFAULT_METHODS = ("proposed", "opencv-hh4-fill", "opencv-hh4")
RADIOMETRIC_VARIANTS = "gain x0.8, gamma 1.2, offset +20 and all three"


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "eval",
        help="evaluate stereo methods on benchmark data",
        description="Evaluate stereo methods on benchmark data.",
    )
    benchmarks = parser.add_subparsers(dest="benchmark", metavar="BENCHMARK", required=True)
    middlebury_parser = benchmarks.add_parser(
        "middlebury",
        help="Middlebury bad-pixel rates and run times (2001/2003, 2005/2006 or 2014 layout)",
        description="Run stereo methods on Middlebury scenes and print bad-pixel rates (1 px; no disparity "
        "counts as bad) and run times: beside the paper's Table 3 for the four 2001/2003 scenes, and for every "
        "layout ours against OpenCV HH4 + post-processing + background fill, scene by scene.",
    )
    middlebury_parser.add_argument(
        "--data",
        type=Path,
        default=None,
        help="Middlebury folder of scene folders: 2001/2003 (left/right/gt + nonocc/all/disc masks), 2005/2006 "
        "(left/right/gt = 3 x disparity) or 2014 (im0/im1/disp0GT.pfm/calib.txt) (default: $CELLCTL_MIDDLEBURY, "
        "else ../shared/data/middlebury/2001-2003)",
    )
    middlebury_parser.add_argument(
        "--methods",
        nargs="+",
        metavar="METHOD",
        help=f"methods to run (default: all on 2001/2003, else {' '.join(DEFAULT_METHODS)}; an unknown name is "
        "refused with the list)",
    )
    middlebury_parser.add_argument(
        "--scenes", nargs="+", metavar="SCENE", help="scene folder names to run (default: every scene of --data)"
    )
    middlebury_parser.add_argument(
        "--radiometric",
        action="store_true",
        help=f"also run with the right image changed ({RADIOMETRIC_VARIANTS}) and report the means beside "
        "the plain run",
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
    from cellctl.eval import comparison, layouts, middlebury, radiometric
    from cellctl.eval import pictures as middlebury_pictures
    from cellctl.eval import report as middlebury_report
    from cellctl.eval.methods import select_methods

    if args.repeat < 1:
        raise ValueError(f"--repeat must be at least 1, got {args.repeat}")
    if args.out is not None and args.out.exists() and not args.out.is_dir():
        raise ValueError(f"--out {args.out} is a file; give a folder for the tables and pictures")
    data_dir = middlebury.DEFAULT_DATA_DIR if args.data is None else args.data
    if args.data is None:
        middlebury.resolve_data_dir(None)  # the default folder, with its own hint when missing
    scenes = layouts.load_dataset(data_dir, args.scenes)
    classic = all(s.info.layout == layouts.LAYOUT_2001 for s in scenes)
    methods = select_methods(args.methods if args.methods or classic else DEFAULT_METHODS)
    variants = list(radiometric.VARIANTS) if args.radiometric else []
    progress = ProgressBar(len(methods) * len(scenes) * (1 + len(variants)))

    def run_on(chosen: list[middlebury.Scene], label: str) -> list[middlebury.SceneResult]:
        return middlebury.evaluate(
            {m.name: m.compute for m in methods},
            chosen,
            args.repeat,
            on_run=lambda method, scene: progress.advance(f"{method} on {scene.name}{label}"),
        )

    results = run_on(scenes, "")
    runs = {"plain": results}
    for name in variants:
        variant = radiometric.VARIANTS[name]
        runs[name] = run_on([radiometric.apply(s, variant) for s in scenes], f" ({name})")
    progress.finish()
    rows = middlebury_report.build_rows(results)
    infos = {s.name: s.info for s in scenes}
    document = middlebury_report.json_document(rows, data_dir, args.repeat, infos)
    document["comparison"] = comparison.json_summary(results, scenes)
    if variants:
        document["radiometric"] = {
            name: {"variant": vars(radiometric.VARIANTS[name]) if name in radiometric.VARIANTS else None}
            | {"comparison": comparison.json_summary(run, scenes)}
            for name, run in runs.items()
        }
    text = middlebury_report.markdown(rows, args.repeat) + "\n" + comparison.markdown(results, scenes)
    if variants:
        names = [m.name for m in methods]
        text += "\nRadiometric check (right image changed; mean % per set, rise in points):\n\n"
        text += comparison.radiometric_markdown(runs, scenes, names)
    if args.json:
        print(json.dumps(document, indent=2))
    else:
        print(text, end="")
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "middlebury.md").write_text(text)
        (args.out / "middlebury.csv").write_text(middlebury_report.csv_text(rows))
        (args.out / "middlebury.json").write_text(json.dumps(document, indent=2) + "\n")
        pictures = middlebury_pictures.write_scene_grids(scenes, results, args.out)
        print(f"wrote middlebury.md, .csv, .json and {len(pictures)} PNG grid(s) to {args.out}", file=sys.stderr)
    return 0
