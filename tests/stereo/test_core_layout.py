"""The C core's layout: one header per unit, and no call cycle between translation units."""

from __future__ import annotations

import re
from pathlib import Path

CSRC = Path(__file__).resolve().parents[2] / "csrc"
PUBLIC_HEADER = "cellctl_core.h"
SHARED_HEADERS = {"common.h"}  # constants and inline helpers only, no unit behind them
DEFINITION = re.compile(r"^(?!static)[A-Za-z_][\w \*]*?\b(cc_\w+)\s*\([^;]*$", re.M)
CALL = re.compile(r"\b(cc_\w+)\s*\(")


def _units() -> dict[str, str]:
    return {p.stem: p.read_text() for p in sorted(CSRC.glob("*.c"))}


def _call_graph() -> dict[str, set[str]]:
    units = _units()
    owner = {name: unit for unit, text in units.items() for name in DEFINITION.findall(text)}
    return {
        unit: {owner[name] for name in CALL.findall(text) if owner.get(name, unit) != unit}
        for unit, text in units.items()
    }


def test_every_unit_has_its_own_header_and_includes_it() -> None:
    headers = {p.name for p in CSRC.glob("*.h")}
    for unit, text in _units().items():
        if unit == "matcher":  # the public entry points: declared in the public header
            assert f'#include "{PUBLIC_HEADER}"' in text or '#include "frame.h"' in text
            continue
        assert f"{unit}.h" in headers, f"csrc/{unit}.c has no csrc/{unit}.h"
        assert f'#include "{unit}.h"' in text, f"csrc/{unit}.c does not include its header"
    units = set(_units())
    for header in headers - {PUBLIC_HEADER} - SHARED_HEADERS:
        assert header[:-2] in units, f"csrc/{header} declares no unit"


def test_no_call_cycle_between_translation_units() -> None:
    graph = _call_graph()
    assert graph["passes"] >= {"cost", "aggregate", "select"}  # the parser sees real calls

    def reaches(start: str, goal: str, seen: set[str]) -> bool:
        for nxt in graph[start]:
            if nxt == goal or (nxt not in seen and reaches(nxt, goal, seen | {nxt})):
                return True
        return False

    cyclic = sorted(unit for unit in graph if reaches(unit, unit, set()))
    assert not cyclic, f"units in a call cycle: {cyclic} (graph {graph})"
