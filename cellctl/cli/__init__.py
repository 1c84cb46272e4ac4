"""The `cellctl` command line.

Each sub-command lives in its own module in this package (cellctl.cli) and exposes
`register(subparsers)`; this file only wires them together, so adding a command
never touches another command's code.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from cellctl.errors import UserError
from firmware_io.server import LinkStartError

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
    except BrokenPipeError:  # e.g. `cellctl results --json | head`: the reader has all it wanted
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
        return 141
    except (UserError, ValueError, FileNotFoundError, LinkStartError) as exc:
        print(f"cellctl {args.command}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except OSError as exc:  # a file or device the command needs: unreadable, missing, no permission
        print(f"cellctl {args.command}: error: {_one_line(exc)}: check the path and its permissions", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())
