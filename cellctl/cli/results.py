"""`cellctl results`: list or export the journaled cycles (text, JSON or CSV)."""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

from cellctl.service.journal import ADDED_COLUMNS, SUMMARY_FIELDS, CycleRecord, Journal
from cellctl.service.timefmt import iso_time, local_time

CSV_FIELDS = (*SUMMARY_FIELDS, "glue_points", "ply_path", "overlay_path", *ADDED_COLUMNS)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "results",
        help="list or export journaled cycles",
        description="Reads the cycle journal of a running or stopped service (read only). Text shows local "
        "times with their zone; CSV and JSON give triggered_at in ISO 8601 with the UTC offset.",
    )
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--config", type=Path, help="the service's config file (its [journal] state_dir)")
    where.add_argument("--state-dir", type=Path, help="the service's state directory")
    form = parser.add_mutually_exclusive_group()
    form.add_argument("--json", action="store_true", help="one JSON array, glue paths included")
    form.add_argument("--csv", action="store_true", help="CSV with one row per cycle (no glue path points)")
    parser.add_argument("--last", type=int, metavar="N", help="only the newest N cycles")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.last is not None and args.last < 1:
        raise ValueError(f"--last {args.last} must be at least 1")
    if args.state_dir is not None:
        state_dir = args.state_dir
    else:
        from cellctl.service.config import CellConfig  # checks the whole config: numpy, pymodbus

        state_dir = CellConfig.load(args.config).journal.state_dir
    journal = Journal.open(state_dir, readonly=True)
    try:
        records = journal.last(args.last)
    finally:
        journal.close()
    if args.json:
        json.dump([{**r.to_dict(), "triggered_at": iso_time(r.triggered_at)} for r in records], sys.stdout, indent=1)
        print()
    elif args.csv:
        _write_csv(records)
    else:
        for record in records:
            print(describe(record))
    return 0


def describe(record: CycleRecord) -> str:
    when = local_time(record.triggered_at)
    head = f"{when} cycle {record.cycle}: "
    if record.status == "ok":
        return (
            head
            + f"ok length={record.length_mm:.2f} heel={record.heel_height_mm:.2f} toe={record.toe_height_mm:.2f} mm "
            f"points={len(record.glue_path)} {record.cycle_time_ms:.0f} ms" + _verdict(record)
        )
    return head + f"error {record.error_code} ({record.reason}) {record.cycle_time_ms:.0f} ms"


def _write_csv(records: list[CycleRecord]) -> None:
    writer = csv.DictWriter(sys.stdout, fieldnames=CSV_FIELDS, lineterminator="\n")
    writer.writeheader()
    for record in records:
        row = {name: getattr(record, name, None) for name in CSV_FIELDS}
        row["glue_points"] = len(record.glue_path)
        row["triggered_at"] = iso_time(record.triggered_at)
        row["failed_features"] = "|".join(record.failed_features)
        writer.writerow(row)


def _verdict(record: CycleRecord) -> str:
    """' recipe=N pass' or ' recipe=N FAIL LENGTH|...' when tolerances were checked; '' for recipe 0 unchecked."""
    if record.in_tolerance is None:
        return f" recipe={record.recipe}" if record.recipe else ""
    verdict = "pass" if record.in_tolerance else "FAIL " + "|".join(record.failed_features)
    return f" recipe={record.recipe} {verdict}"
