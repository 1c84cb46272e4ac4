"""`cellctl rectify calib.yaml LEFT RIGHT -o DIR`: rectify a pair and measure how well its rows line up."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from cellctl.errors import UserError

if TYPE_CHECKING:
    import numpy as np


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "rectify",
        help="rectify a stereo pair and measure its residual vertical disparity",
        description="Write the rectified pair, side-by-side views with equally spaced rows before and after "
        "rectification, and print the vertical disparity left over between matched features.",
    )
    parser.add_argument(
        "--calib", required=True, metavar="calib.yaml", type=Path, help="calibration file from `cellctl calibrate`"
    )
    parser.add_argument("left", metavar="LEFT", type=Path, help="left camera image")
    parser.add_argument("right", metavar="RIGHT", type=Path, help="right camera image")
    parser.add_argument("-o", "--out", required=True, type=Path, metavar="DIR", help="directory for the images")
    parser.add_argument("--lines", type=int, default=16, help="number of horizontal lines in the side-by-side views")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # Imported here, not at the top: `cellctl --help` and the light commands must not load them.
    import cv2

    from cellctl.vision.calibration import Calibration
    from cellctl.vision.rectification import side_by_side, vertical_disparity

    calibration = Calibration.load(args.calib)
    left, right = _read(args.left), _read(args.right)
    for name, image in ((args.left, left), (args.right, right)):
        try:
            calibration.check_image(image)
        except ValueError as exc:
            raise UserError(f"{name}: {exc}") from None
    rect_left, rect_right = calibration.rectify(left, right)
    args.out.mkdir(parents=True, exist_ok=True)
    outputs = {
        "rectified_left.png": rect_left,
        "rectified_right.png": rect_right,
        "side_by_side.png": side_by_side(rect_left, rect_right, args.lines),
        "side_by_side_raw.png": side_by_side(left, right, args.lines),
    }
    for name, image in outputs.items():
        if not cv2.imwrite(str(args.out / name), image):
            raise UserError(f"cannot write {args.out / name}: check the directory is writable")
    print(f"wrote {', '.join(outputs)} to {args.out}")
    print(vertical_disparity(rect_left, rect_right).summary())
    return 0


def _read(path: Path) -> np.ndarray:
    import cv2

    from cellctl.images import read_image

    try:
        image = read_image(path, cv2.IMREAD_UNCHANGED)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    return image
