"""`cellctl bench-sole`: measurement accuracy and time on simulated white and black soles."""

from __future__ import annotations

import argparse
import json
import sys

from cellctl.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "bench-sole",
        help="accuracy and time of the sole measurement on simulated soles",
        description=(
            "Render simulated soles of known geometry (half white, half black; shape and pose from the seed), "
            "measure each like `cellctl measure` and print the error table (mean and max per measurement) and "
            "the time per measurement."
        ),
    )
    parser.add_argument("--soles", type=int, default=20, help="number of soles (default 20)")
    parser.add_argument("--first-seed", type=int, default=0, help="seed of the first sole (default 0)")
    parser.add_argument("--calib", metavar="calib.yaml", help="rig to simulate (default: the built-in simulated rig)")
    parser.add_argument(
        "--taught", action="store_true", help="teach each scene's empty table first (as `cellctl teach` at set-up)"
    )
    parser.add_argument("--json", action="store_true", help="print JSON instead of markdown")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from cellctl.eval import sole_bench as bench_sole
    from cellctl.sim.rig import default_rig
    from cellctl.vision.calibration import Calibration

    if args.soles < 1:
        raise UserError(f"--soles must be at least 1, got {args.soles}")
    calib = Calibration.load(args.calib) if args.calib else default_rig()
    # Alternate colours over consecutive seeds, so both colours see every kind of shape and pose.
    soles = [(args.first_seed + i, "white" if i % 2 == 0 else "black") for i in range(args.soles)]
    rows = bench_sole.bench_soles(
        calib, soles, progress=lambda text: print(f"  {text}", file=sys.stderr), taught=args.taught
    )
    if args.json:
        print(json.dumps(bench_sole.as_json(rows), indent=2))
    else:
        command = f"cellctl bench-sole --soles {args.soles} --first-seed {args.first_seed}"
        command += " --taught" if args.taught else ""
        print(bench_sole.to_markdown(rows, command + (f" --calib {args.calib}" if args.calib else "")))
    return 0
