"""The `cellctl` command line.

Each sub-command lives in its own module in this package (cellctl.cli) and exposes
`register(subparsers)`; this file only wires them together, so adding a command
never touches another command's code.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from cellctl.errors import UserError

# Modules under cellctl.cli, in the order they appear in --help.
COMMAND_MODULES: tuple[str, ...] = (
    "bench",
    "demo",
    "eval",
    "plc_sim",
    "calibrate",
    "rectify",
    "simulate",
    "measure",
    "bench_sole",
    "results",
    "run",
    "teach_robot",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="cellctl", description="Sole-gluing stereo cell controller")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(f"cellctl.cli.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (UserError, ValueError, FileNotFoundError) as exc:
        print(f"cellctl {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
