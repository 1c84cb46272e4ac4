"""How times are shown to people and written for programs (one home for both formats)."""

from __future__ import annotations

from datetime import datetime


def local_time(unix_s: float) -> str:
    """Wall-clock time in the machine's zone, with the zone named (what the operator's watch shows)."""
    return datetime.fromtimestamp(unix_s).astimezone().strftime("%Y-%m-%d %H:%M:%S %Z")


def iso_time(unix_s: float) -> str:
    """ISO 8601 with the UTC offset, for CSV and JSON that other programs read."""
    return datetime.fromtimestamp(unix_s).astimezone().isoformat(timespec="milliseconds")
