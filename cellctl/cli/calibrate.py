"""`cellctl calibrate DIR --board COLSxROWS --square MM -o calib.yaml`: stereo calibration from board pairs."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from cellctl.errors import UserError

if TYPE_CHECKING:
    from cellctl.calib.report import CalibrationResult


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "calibrate",
        help="calibrate the stereo cameras from checkerboard image pairs",
        description="Calibrate both cameras and their relative pose from checkerboard pairs left_NN.png / "
        "right_NN.png (Zhang's method), rejecting pairs whose reprojection error stands out.",
    )
    parser.add_argument("directory", metavar="DIR", type=Path, help="directory with left_NN.png / right_NN.png pairs")
    parser.add_argument("--board", required=True, metavar="COLSxROWS", help="inner corners of the board, e.g. 9x6")
    parser.add_argument("--square", required=True, type=float, metavar="MM", help="side of one square, mm")
    parser.add_argument("-o", "--out", required=True, type=Path, metavar="calib.yaml", help="calibration file to write")
    parser.add_argument(
        "--chart", type=Path, metavar="PNG", help="per-pair error chart (default: NAME-errors.png next to the output)"
    )
    parser.add_argument(
        "--min-pairs", type=int, metavar="N", help="never keep fewer pairs (default: cellctl.calib.zhang.MIN_PAIRS, 6)"
    )
    parser.add_argument(
        "--fit-k3", action="store_true", help="also fit the third radial distortion term (wide-angle lenses)"
    )
    parser.add_argument(
        "--left-camera",
        metavar="ID",
        help="identity of the left camera, recorded in the calibration and checked by the service: its "
        "/dev/v4l/by-id name or USB serial (give --right-camera too)",
    )
    parser.add_argument("--right-camera", metavar="ID", help="identity of the right camera (see --left-camera)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if (args.left_camera is None) != (args.right_camera is None):
        raise UserError("--left-camera and --right-camera go together: give both camera identities or neither")
    # Imported here, not at the top: `cellctl --help` and the light commands must not load them.
    import cv2

    from cellctl.calib.board import Checkerboard
    from cellctl.calib.pairs import find_pairs
    from cellctl.calib.zhang import MIN_PAIRS, calibrate_views, detect_views

    try:
        board = Checkerboard.from_spec(args.board, args.square)
    except ValueError as exc:
        raise UserError(f"--board/--square: {exc}") from None
    pairs = find_pairs(args.directory)
    board_text = f"{board.cols}x{board.rows} inner corners of {board.square_mm:g} mm"
    print(f"{len(pairs)} pairs in {args.directory}, board {board_text}")
    views = detect_views(pairs, board)
    for view in views:
        if not view.usable:
            print(f"skipping pair {view.name}: {view.problem}")
    result = calibrate_views(
        views, board, min_pairs=MIN_PAIRS if args.min_pairs is None else args.min_pairs, fit_k3=args.fit_k3
    )
    print(result.table())
    calibration = result.calibration
    if args.left_camera is not None:
        calibration = replace(calibration, cameras=(args.left_camera, args.right_camera))
    calibration.save(args.out)
    chart = args.chart or args.out.with_name(f"{args.out.stem}-errors.png")
    if not cv2.imwrite(str(chart), result.error_chart()):
        raise UserError(f"cannot write the error chart {chart}: check the directory exists and is writable")
    _write_report(args.out, board_text, result)
    print(f"wrote {args.out} and {chart}")
    return 0


def _write_report(output: Path, board_text: str, result: CalibrationResult) -> None:
    """CAL-report.json beside the calibration: what the operator station shows about it."""
    import json
    from datetime import datetime

    report = {
        "calibrated_at": datetime.now().astimezone().isoformat(timespec="seconds"),
        "board": board_text,
        "pairs_used": len(result.kept),
        "pairs_total": len(result.pairs),
        "rms_px": result.calibration.rms,
        "per_pair": [{"pair": p.name, "status": p.status, "error_px": p.error_px} for p in result.pairs],
    }
    output.with_name(f"{output.stem}-report.json").write_text(json.dumps(report, indent=1), encoding="utf-8")
