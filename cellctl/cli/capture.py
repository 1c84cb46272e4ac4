"""`cellctl capture --config CELL.toml -o DIR`: synchronised calibration pairs from the configured cameras.

Saves left_NN.png / right_NN.png (continuing the numbering already in DIR) every --interval seconds and
prints one line per pair saying whether the checkerboard was found in both images, so the person moving the
board knows at once which poses count. Run it while the service is stopped (it owns the cameras).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from cellctl.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "capture",
        help="capture calibration pairs from the configured cameras, with board detection",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--config", type=Path, required=True, help="cell config (its [cameras] are used)")
    parser.add_argument("-o", "--out", type=Path, required=True, metavar="DIR", help="folder for the pairs")
    parser.add_argument("--board", metavar="COLSxROWS", help="inner corners to detect (default: [station] board)")
    parser.add_argument("--count", type=int, default=10, help="pairs to capture (default 10)")
    parser.add_argument("--interval", type=float, default=2.0, help="seconds between pairs (default 2)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from cellctl.calib.board import Checkerboard
    from cellctl.cli.cameras import opened_cameras
    from cellctl.service.capture import save_pair
    from cellctl.service.config import CellConfig
    from cellctl.vision.calibration import Calibration

    if args.count < 1 or args.interval < 0:
        raise UserError(f"--count must be at least 1 and --interval not negative, got {args.count} and {args.interval}")
    config = CellConfig.load(args.config)
    spec = args.board or config.station.board
    try:
        board = None if spec is None else Checkerboard.from_spec(spec, 1.0)  # the square size does not matter here
    except ValueError as exc:
        raise UserError(f"--board {spec}: {exc}") from None
    calib = Calibration.load(config.calibration.path) if config.cameras.backend == "simulated" else None
    usable = 0
    with opened_cameras(config, calib, "cameras: {}") as source:
        for i in range(args.count):
            if i:
                time.sleep(args.interval)  # the person moves the board meanwhile
            saved, _ = save_pair(source.grab_pair(), args.out, board)
            usable += bool(saved.board_left and saved.board_right)
            print(saved.describe(), flush=True)
    if board is not None:
        print(
            f"{usable} of {args.count} pairs show the whole board in both images; `cellctl calibrate {args.out}` next"
        )
    return 0
