"""`cellctl bench-sole`: measurement accuracy and time on simulated soles, plain or over the variation matrix."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from typing import TYPE_CHECKING

from cellctl.errors import UserError

if TYPE_CHECKING:
    from cellctl.sim.matrix import MatrixSole
    from cellctl.sim.render_cache import RenderCache
    from cellctl.sim.scene import SoleScene


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
    parser.add_argument(
        "--matrix",
        action="store_true",
        help="spread the soles over the variation matrix (toe/heel shapes, walls, edges, colours, tables, "
        "shadows, camera gain and gamma, gloss, noise, heights, rig) and print the per-variation table",
    )
    parser.add_argument(
        "--variations",
        metavar="NAME,...",
        help="with --matrix: only these matrix entries (default all; `--variations list` prints them)",
    )
    parser.add_argument(
        "--combined",
        action="store_true",
        help="with --matrix --variations: every sole has all the listed variations at once (colours rotating), "
        "for a combination the matrix draws only by chance",
    )
    parser.add_argument(
        "--only",
        metavar="SEED,...",
        help="with --matrix: measure only these seeds of the --soles/--first-seed matrix (a matrix sole's "
        "variations and colour depend on its place in the matrix, so `--soles 1 --first-seed S` is another sole)",
    )
    parser.add_argument("--first-seed", type=int, default=0, help="seed of the first sole (default 0)")
    parser.add_argument("--calib", metavar="calib.yaml", help="rig to simulate (default: the built-in simulated rig)")
    parser.add_argument(
        "--taught", action="store_true", help="teach each scene's empty table first (as `cellctl teach` at set-up)"
    )
    parser.add_argument(
        "--cache",
        metavar="DIR",
        help="keep every render in DIR and reuse it (keyed by scene, look, rig and the simulator's source)",
    )
    parser.add_argument(
        "--render-only",
        action="store_true",
        help="with --cache: only render the soles (and the empty tables with --taught) into the cache",
    )
    parser.add_argument(
        "--lighting",
        metavar="NAME",
        help="with --matrix: light every sole so, in place of the lights its variations give (bars, shadowed-bars, "
        "ring, overhead, side; the matrix's bars cast no shadow, shadowed-bars are the same bars casting theirs)",
    )
    parser.add_argument(
        "--rig",
        metavar="NAME",
        help="with --matrix: shoot every sole through this simulated rig, in place of the one its variations give "
        "(default, distorted, wide, narrow, coarse: 960 x 768 px, fine: 1600 x 1280 px, near: 420 mm up, far: 750 mm "
        "up; each measured with the depth range a line would set for it)",
    )
    parser.add_argument(
        "--declared-walls",
        action="store_true",
        help="with --matrix: measure each sole with its model's wall stated as a recipe would ([sole] wall: "
        "vertical, or the draft of a wall leaning from the table), as a line that knows its moulds",
    )
    parser.add_argument(
        "--frames",
        type=int,
        metavar="N",
        help="exposures of each sole averaged per measurement (default: as a cycle takes them, the default of "
        "[cameras] averaged_frames)",
    )
    parser.add_argument(
        "--retry-frames",
        type=int,
        metavar="N",
        help="exposures averaged in all when a measurement refused for its glue heights' precision may pass on "
        "more, as a cycle measures once more (default: the default of [cameras] retry_averaged_frames; 0: never)",
    )
    parser.add_argument("--json", action="store_true", help="print JSON instead of markdown")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from cellctl.eval import sole_bench as bench_sole
    from cellctl.sim.rig import default_rig
    from cellctl.sim.scene import SoleScene
    from cellctl.vision.calibration import Calibration

    if args.soles < 1:
        raise UserError(f"--soles must be at least 1, got {args.soles}")
    if args.only and not args.matrix:
        raise UserError("--only needs --matrix")
    if args.variations and not args.matrix:
        raise UserError("--variations needs --matrix")
    if args.combined and (not args.variations or args.variations == "list"):
        raise UserError("--combined needs --matrix --variations NAME,... (the variations every sole combines)")
    if args.declared_walls and not args.matrix:
        raise UserError("--declared-walls needs --matrix")
    if args.lighting is not None:
        from cellctl.sim.look import LIGHTINGS

        if not args.matrix:
            raise UserError("--lighting needs --matrix")
        if args.lighting not in LIGHTINGS:
            raise UserError(f"--lighting must be one of {', '.join(LIGHTINGS)}, got {args.lighting!r}")
    if args.rig is not None:
        from cellctl.sim.look import RIGS

        if not args.matrix:
            raise UserError("--rig needs --matrix")
        if args.rig not in RIGS:
            raise UserError(f"--rig must be one of {', '.join(RIGS)}, got {args.rig!r}")
    from cellctl.cameras.config import frames_option, retry_frames_option

    args.frames = frames_option(args.frames)
    args.retry_frames = retry_frames_option(args.retry_frames)
    if args.render_only and not args.cache:
        raise UserError("--render-only needs --cache DIR (where the renders go)")
    if args.matrix:
        return _run_matrix(args)
    calib = Calibration.load(args.calib) if args.calib else default_rig()
    # Alternate colours over consecutive seeds, so both colours see every kind of shape and pose.
    soles = [(args.first_seed + i, "white" if i % 2 == 0 else "black") for i in range(args.soles)]
    cache = _cache(args)
    if args.render_only:
        assert cache is not None
        scenes = [SoleScene.random(seed, color, calib) for seed, color in soles]
        return _render_only(scenes, cache, args.taught, args.frames)
    rows = bench_sole.bench_soles(
        calib,
        soles,
        progress=lambda text: print(f"  {text}", file=sys.stderr),
        taught=args.taught,
        cache=cache,
        frames=args.frames,
        retry_frames=args.retry_frames,
    )
    if args.json:
        print(json.dumps(bench_sole.as_json(rows), indent=2))
    else:
        command = f"cellctl bench-sole --soles {args.soles} --first-seed {args.first_seed}"
        command += " --taught" if args.taught else ""
        command += _frames_flag(args.frames, args.retry_frames)
        print(bench_sole.to_markdown(rows, command + (f" --calib {args.calib}" if args.calib else "")))
    return 0


def _run_matrix(args: argparse.Namespace) -> int:
    from cellctl.eval import sole_matrix
    from cellctl.sim.look import VARIATIONS
    from cellctl.sim.matrix import combined_soles, matrix_soles
    from cellctl.sim.scene import SoleScene
    from cellctl.vision.calibration import Calibration

    if args.variations == "list":
        for name, variation in VARIATIONS.items():
            print(f"{name:18} {variation.description}")
        return 0
    entries = tuple(args.variations.split(",")) if args.variations else None
    try:
        if args.combined:
            assert entries is not None  # checked in run
            soles = combined_soles(args.soles, args.first_seed, entries)
        else:
            soles = matrix_soles(args.soles, args.first_seed, entries)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    if args.lighting is not None:
        soles = [replace(sole, lighting=args.lighting) for sole in soles]
    if args.rig is not None:
        soles = [replace(sole, rig=args.rig) for sole in soles]
    if args.only:
        soles = _only(soles, args.only)
    calib = Calibration.load(args.calib) if args.calib else None
    cache = _cache(args)
    if args.render_only:
        from cellctl.sim.rig import rig_for

        assert cache is not None
        scenes = [SoleScene.random(s.seed, s.color, calib or rig_for(s.look.rig), s.look) for s in soles]
        return _render_only(scenes, cache, args.taught, args.frames)
    results = sole_matrix.bench_matrix(
        soles,
        calib,
        progress=lambda text: print(f"  {text}", file=sys.stderr),
        taught=args.taught,
        cache=cache,
        declared_walls=args.declared_walls,
        frames=args.frames,
        retry_frames=args.retry_frames,
    )
    if args.json:
        print(json.dumps(sole_matrix.as_json(results), indent=2))
    else:
        command = f"cellctl bench-sole --matrix --soles {args.soles} --first-seed {args.first_seed}"
        command += f" --variations {args.variations}" if args.variations else ""
        command += " --combined" if args.combined else ""
        command += f" --lighting {args.lighting}" if args.lighting else ""
        command += f" --rig {args.rig}" if args.rig else ""
        command += f" --only {args.only}" if args.only else ""
        command += f" --calib {args.calib}" if args.calib else ""
        command += " --taught" if args.taught else ""
        command += " --declared-walls" if args.declared_walls else ""
        command += _frames_flag(args.frames, args.retry_frames)
        print(sole_matrix.matrix_markdown(results, command))
    return 0 if sole_matrix.acceptance(results).passed else 1


def _only(soles: list[MatrixSole], only: str) -> list[MatrixSole]:
    """The matrix soles whose seeds are listed (comma-separated); UserError for a seed not in the matrix."""
    try:
        seeds = [int(text) for text in only.split(",")]
    except ValueError:
        raise UserError(f"--only takes comma-separated seeds, got {only!r}") from None
    by_seed = {sole.seed: sole for sole in soles}
    missing = [seed for seed in seeds if seed not in by_seed]
    if missing:
        first, last = soles[0].seed, soles[-1].seed
        raise UserError(
            f"--only: seed {missing[0]} is not in the matrix ({first}..{last}): check --soles and --first-seed"
        )
    return [by_seed[seed] for seed in seeds]


def _cache(args: argparse.Namespace) -> RenderCache | None:
    from cellctl.sim.render_cache import RenderCache

    if not args.cache:
        return None
    try:
        return RenderCache(args.cache)
    except OSError as exc:
        raise UserError(
            f"cannot use {args.cache} as the render cache ({exc.strerror}): give a writable directory"
        ) from None


def _render_only(scenes: list[SoleScene], cache: RenderCache, taught: bool, frames: int) -> int:
    from cellctl.eval.sole_bench import TEACH_SHOTS
    from cellctl.sim.render_cache import exposure_shots

    for scene in scenes:
        # 0, -1, ...: the scene's exposures; 1...: the empty table's
        shots = exposure_shots(frames) + list(range(1, TEACH_SHOTS + 1 if taught else 1))
        rendered = cache.prefill(scene, shots)
        print(f"  sole {scene.seed} {scene.color}: {rendered} of {len(shots)} renders new", file=sys.stderr)
    return 0


def _frames_flag(frames: int, retry_frames: int) -> str:
    """ " --frames N --retry-frames M" for a report's command line, each unless it is the cycle's default."""
    from cellctl.cameras.config import AVERAGED_FRAMES, MORE_EXPOSURES

    return ("" if frames == AVERAGED_FRAMES else f" --frames {frames}") + (
        "" if retry_frames == MORE_EXPOSURES else f" --retry-frames {retry_frames}"
    )
