"""Spreading simulated soles over the variation matrix, deterministically from the seeds.

Sole i of a run gets the matrix entry i (mod the number of entries) as its primary variation, so every
entry is visited before any repeats; colours rotate over white, black and mid-grey, shifted by one each
round so that each entry meets every colour; half of the soles also get a toe or heel shape, and about a
third one more variation of another kind, so that ends and variations are mixed, not seen alone only.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from cellctl.errors import FailureKind
from cellctl.sim.look import VARIATIONS, SceneLook, fair_refusals, look_for, rig_refusals

MATRIX_COLOURS = ("white", "black", "grey")
MATRIX_ENTRIES = tuple(name for name, v in VARIATIONS.items() if v.in_matrix)
END_VARIATIONS = tuple(name for name in MATRIX_ENTRIES if set(VARIATIONS[name].fields) & {"toe", "heel"})


@dataclass(frozen=True)
class MatrixSole:
    """One sole of a matrix run: its seed, colour and variations (the first is the primary one)."""

    seed: int
    color: str
    variations: tuple[str, ...]
    # The scene's lights in place of those its variations give (look.LIGHTINGS; None: theirs): the same soles relit,
    # e.g. with the bars' own shadows, which the matrix does not trace.
    lighting: str | None = None
    # The rig that shoots it in place of its variations' (look.RIGS; None: theirs): the same soles through other
    # cameras, e.g. with fewer or more pixels.
    rig: str | None = None

    @property
    def primary(self) -> str:
        return self.variations[0]

    @property
    def look(self) -> SceneLook:
        look = look_for(self.variations, self.seed)
        look = look if self.lighting is None else replace(look, lighting=self.lighting)
        return look if self.rig is None else replace(look, rig=self.rig)

    @property
    def fair_refusals(self) -> frozenset[FailureKind]:
        # A rig in place of the variations' own brings its own fair refusals (the coarse rig's surface).
        return fair_refusals(self.variations) | (frozenset() if self.rig is None else rig_refusals(self.rig))

    @property
    def label(self) -> str:
        return "+".join(self.variations)


def matrix_soles(count: int, first_seed: int = 0, entries: tuple[str, ...] | None = None) -> list[MatrixSole]:
    """`count` soles spread over the matrix `entries` (default: MATRIX_ENTRIES), colours and ends mixed."""
    names = tuple(entries or MATRIX_ENTRIES)
    for name in names:
        if name not in VARIATIONS:
            raise ValueError(f"unknown variation {name!r}: choose from {', '.join(VARIATIONS)}")
    soles = []
    for i in range(count):
        seed = first_seed + i
        rng = np.random.default_rng([seed, 29])
        primary = names[i % len(names)]
        round_ = i // len(names)
        chosen = [primary]
        if rng.random() < 0.5:
            _add_compatible(chosen, END_VARIATIONS, rng)
        if rng.random() < 0.35:
            _add_compatible(chosen, tuple(n for n in MATRIX_ENTRIES if n not in END_VARIATIONS), rng)
        colour = MATRIX_COLOURS[(i % len(names) + round_) % len(MATRIX_COLOURS)]
        soles.append(MatrixSole(seed, colour, tuple(c for c in chosen if c != "plain" or c == primary)))
    return soles


def combined_soles(count: int, first_seed: int, entries: tuple[str, ...]) -> list[MatrixSole]:
    """`count` soles that each combine all of `entries`, colours rotating over MATRIX_COLOURS: a class of soles
    the matrix draws together only by chance (a flat sole with a leaning wall: about one in 400). ValueError for
    an unknown variation or two that set the same field of the look."""
    look_for(entries, first_seed)  # refused here, before anything is rendered
    return [MatrixSole(first_seed + i, MATRIX_COLOURS[i % len(MATRIX_COLOURS)], entries) for i in range(count)]


def _add_compatible(chosen: list[str], candidates: tuple[str, ...], rng: np.random.Generator) -> None:
    """Append one candidate whose fields none of the chosen variations sets (nothing if none fits)."""
    taken = {f for name in chosen for f in VARIATIONS[name].fields}
    fitting = [n for n in candidates if n not in chosen and not (set(VARIATIONS[n].fields) & taken) and n != "plain"]
    if fitting:
        chosen.append(fitting[int(rng.integers(len(fitting)))])
