"""`cellctl teach`: teach the empty table once at set-up (docs/measurements.md, Teaching the table).

Writes <calib>.table.npz and <calib>.table.json beside the calibration; `cellctl measure` and the service
use them from then on. Exit status: 0 taught, 2 bad input or the table could not be taught.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cellctl.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "teach",
        help="teach the empty table (plane and reference images) beside the calibration",
        description=(
            "Measure the EMPTY fixture from a raw left/right pair and store its table plane, reference images "
            "and reference disparity beside the calibration (<calib>.table.npz and .table.json). Teach again "
            "whenever the table, the fixture or the cameras move, and after every calibration."
        ),
    )
    parser.add_argument("--calib", required=True, type=Path, metavar="calib.yaml", help="stereo calibration")
    parser.add_argument(
        "images",
        type=Path,
        nargs="+",
        metavar="LEFT RIGHT",
        help="one or more left/right pairs of the empty table (several are averaged: less sensor noise)",
    )
    parser.add_argument(
        "--depth-range",
        nargs=2,
        type=float,
        metavar=("MIN", "MAX"),
        help="working distance from the cameras in mm (default 450 650), as for `cellctl measure`",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from cellctl.images import lossy_warning, read_image
    from cellctl.vision.calibration import Calibration
    from cellctl.vision.checks import CALIBRATED_OBLIQUENESS_DEG, too_oblique
    from cellctl.vision.defaults import DEPTH_RANGE_MM
    from cellctl.vision.image_noise import exposure_noise_dn
    from cellctl.vision.reconstruction import SoleReconstructor
    from cellctl.vision.teach import TeachError, average_exposures, save_taught

    calib = Calibration.load(args.calib)
    if len(args.images) % 2:
        raise UserError(f"give the images as LEFT RIGHT pairs, got {len(args.images)} images")
    images = []
    for path in args.images:
        try:
            images.append(read_image(path, what="empty-table image"))
        except ValueError as exc:
            raise UserError(f"{exc}: give the path of a PNG or JPEG of the empty table") from None
        if warning := lossy_warning(path, "empty-table image"):
            print(warning, file=sys.stderr)
    depth_range = tuple(args.depth_range) if args.depth_range else DEPTH_RANGE_MM
    try:
        left, right = average_exposures(images[0::2]), average_exposures(images[1::2])
        # What averaging removed from the last left image: a noisy camera named as such if teaching fails.
        noise = exposure_noise_dn(images[-2], left) if len(images) > 2 else None
        taught = SoleReconstructor(calib, depth_range).teach(left, right, noise)
    except TeachError as exc:
        raise UserError(f"table not taught: {exc}") from None
    arrays, meta = save_taught(taught, args.calib)
    normal, obliqueness = taught.plane.normal, taught.plane.obliqueness_deg()
    print(
        f"taught the empty table: {taught.plane.offset:.1f} mm from the left camera, normal "
        f"({normal[0]:+.4f}, {normal[1]:+.4f}, {normal[2]:+.4f}), the cameras looking "
        f"{obliqueness:.1f} degrees off it; wrote {meta} and {arrays}"
    )
    if too_oblique(obliqueness):
        # Taught all the same: the table is where it is; the cycles say why they refuse (checks.glue_sd_limit).
        print(
            f"warning: the cameras look at the table more than {CALIBRATED_OBLIQUENESS_DEG:g} degrees off its "
            "normal: glue heights are held to a tighter precision there and dark, weakly textured soles will be "
            "refused; mount the cameras square to the table and teach again"
        )
    return 0
