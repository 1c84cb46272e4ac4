"""`cellctl simulate SCENE ...`: write images of simulated scenes as the cell's cameras would see them."""

from __future__ import annotations

import argparse
import importlib

# Scene name -> "module:function". The function gets the scene's own parser, adds its arguments and sets
# `func` to the code that runs it (like a command's register); its docstring is the scene's help.
# Adding a scene is one line here and a module of its own.
SCENES: dict[str, str] = {
    "checkerboard": "cellctl.cli.simulate_checkerboard:configure",
    "sole": "cellctl.cli.simulate_sole:configure",
}


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "simulate",
        help="write simulated camera images (checkerboard pairs, ...)",
        description="Write images of a simulated scene taken by the simulated stereo rig.",
    )
    scenes = parser.add_subparsers(dest="scene", metavar="SCENE", required=True)
    for name, target in SCENES.items():
        module_name, function_name = target.split(":")
        configure = getattr(importlib.import_module(module_name), function_name)
        doc = (configure.__doc__ or "").strip()
        configure(scenes.add_parser(name, help=doc.splitlines()[0] if doc else None, description=doc or None))
