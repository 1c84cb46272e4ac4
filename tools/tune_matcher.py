"""Tuning loop for the matcher defaults (not part of the package): score parameter sets on the
union of the 2001/2003 and 2005/2006 Middlebury sets, one set after the other in this process.

    .venv/bin/python tools/tune_matcher.py '{}' '{"p2": 120}' [--radiometric gain|gamma|offset|all]
        [--sets 2001,2005] [--scenes Aloe,Midd1] [--per-scene]

Prints per set: the 2001/2003 Table-3 average (12 numbers), the 2005/2006 mean bad % and the win
count against OpenCV HH4 + post + background fill (its figures cached in /tmp per variant).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cellctl.eval import layouts, middlebury, radiometric  # noqa: E402
from cellctl.eval.methods import METHODS  # noqa: E402
from cellctl.stereo import StereoMatcher  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "middlebury"


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("params", nargs="+")
    ap.add_argument("--radiometric", default="none")
    ap.add_argument("--sets", default="2001,2005")
    ap.add_argument("--scenes", default=None)
    ap.add_argument("--per-scene", action="store_true")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    scenes = []
    if "2001" in args.sets:
        scenes += layouts.load_dataset(DATA / "2001-2003")
    if "2005" in args.sets:
        scenes += layouts.load_dataset(DATA / "2005-2006")
    if args.scenes:
        keep = set(args.scenes.split(","))
        scenes = [s for s in scenes if s.name in keep]
    variant = radiometric.VARIANTS[args.radiometric] if args.radiometric != "none" else None
    if variant is not None:
        scenes = [radiometric.apply(s, variant) for s in scenes]
    ref = reference(scenes, args.radiometric)
    for text in args.params:
        params = json.loads(text)
        t0 = time.perf_counter()
        scores = {}
        for s in scenes:
            m = StereoMatcher(s.info.min_disparity, s.info.num_disparities, threads=args.threads, **params)
            d = m.compute(s.left, s.right)
            scores[s.name] = middlebury.score(d, s).mean_percent
        dt = time.perf_counter() - t0
        t3 = [v for s in scenes if s.info.layout == "2001-2003" for v in [scores[s.name]]]
        s05 = [s.name for s in scenes if s.info.layout == "2005-2006"]
        mean05 = float(np.mean([scores[n] for n in s05])) if s05 else float("nan")
        ref05 = float(np.mean([ref[n] for n in s05])) if s05 else float("nan")
        wins = sum(scores[n] < ref[n] for n in s05)
        print(
            f"T3 {np.mean(t3) if t3 else float('nan'):5.2f}  0506 {mean05:6.2f} (ref {ref05:5.2f}, "
            f"ratio {mean05 / ref05:4.2f}, wins {wins}/{len(s05)})  {dt:5.1f}s  {text}",
            flush=True,
        )
        if args.per_scene:
            print("   " + " ".join(f"{n}:{scores[n]:.1f}/{ref[n]:.1f}" for n in scores))
    return 0


def reference(scenes: list[middlebury.Scene], variant: str) -> dict[str, float]:
    cache = Path(f"/tmp/tune_ref_{variant}.json")
    known: dict[str, float] = json.loads(cache.read_text()) if cache.is_file() else {}
    method = METHODS["opencv-hh4-fill"].compute
    for s in scenes:
        if s.name not in known:
            known[s.name] = middlebury.run_method("ref", method, s).score.mean_percent
    cache.write_text(json.dumps(known))
    return known


if __name__ == "__main__":
    sys.exit(main())
