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
from firmware_io.endpoints import LinkStartError

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
    "teach",
    "bench_sole",
    "results",
    "run",
    "capture",
    "check",
    "teach_robot",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="cellctl", description="Sole-gluing stereo cell controller")
    parser.add_argument("--version", action=_VersionAction, nargs=0, help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(f"cellctl.cli.{name}").register(sub)
    return parser


class _VersionAction(argparse.Action):
    """--version, looked up only when asked (reading the installed metadata costs ~0.1 s at every start)."""

    def __call__(self, parser: argparse.ArgumentParser, *_: object) -> None:
        print(f"cellctl {_version()}")
        parser.exit()


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("cellctl")
    except PackageNotFoundError:  # running from a source tree that was never installed
        return "unknown (not installed)"


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
