"""The `cellctl simulate checkerboard` scene: calibration pairs of a known rig."""

from __future__ import annotations

import argparse
from pathlib import Path

from cellctl.errors import UserError


def configure(parser: argparse.ArgumentParser) -> None:
    """Checkerboard pairs for `cellctl calibrate`, with a few bad pairs it must reject.

    Writes left_NN.png / right_NN.png, the rig's true calibration (true-calib.yaml) and the list of
    deliberately bad pairs (bad-pairs.txt) to the output directory.
    """
    parser.add_argument("-o", "--out", required=True, type=Path, metavar="DIR", help="directory to write the pairs to")
    parser.add_argument("--pairs", type=int, default=16, help="number of good pairs (default 16)")
    parser.add_argument("--board", default="9x6", metavar="COLSxROWS", help="inner corners (default 9x6)")
    parser.add_argument("--square", type=float, default=30.0, metavar="MM", help="square side, mm (default 30)")
    parser.add_argument(
        "--calib",
        "--rig",
        dest="calib",
        type=Path,
        metavar="calib.yaml",
        help="rig to simulate (default: the built-in simulated rig)",
    )
    parser.add_argument("--no-bad", action="store_true", help="leave out the bad pairs")
    parser.add_argument("--seed", type=int, default=0, help="random seed of the board poses and noise")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # Imported here, not at the top: `cellctl --help` and the light commands must not load them.
    from cellctl.calib.board import Checkerboard
    from cellctl.sim.checkerboard import BAD_KINDS, CheckerboardSimulator, write_pairs
    from cellctl.sim.rig import default_rig
    from cellctl.vision.calibration import Calibration

    if args.pairs < 1:
        raise UserError(f"--pairs must be at least 1, got {args.pairs}")
    try:
        board = Checkerboard.from_spec(args.board, args.square)
    except ValueError as exc:
        raise UserError(f"--board/--square: {exc}") from None
    rig = Calibration.load(args.calib) if args.calib else default_rig()
    simulator = CheckerboardSimulator(rig, board, seed=args.seed)
    pairs = simulator.pairs(args.pairs, bad=() if args.no_bad else BAD_KINDS)
    write_pairs(pairs, args.out)
    rig.save(args.out / "true-calib.yaml")
    bad = [f"{pair.name} {pair.kind}" for pair in pairs if pair.kind != "good"]
    (args.out / "bad-pairs.txt").write_text("".join(f"{line}\n" for line in bad))
    print(f"wrote {len(pairs)} pairs to {args.out} ({', '.join(bad) or 'no bad pairs'}); true rig in true-calib.yaml")
    return 0
