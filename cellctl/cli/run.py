"""`cellctl run --config FILE.toml`: the cell controller service (systemd unit deploy/cellctl.service)."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
from pathlib import Path

# syslog priorities for systemd's "<N>" line prefix (SyslogLevelPrefix=, on by default for services).
_PRIORITY = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3, logging.CRITICAL: 2}


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "run",
        help="run the cell controller service (PLC trigger -> cameras -> measurement -> PLC)",
        description=(
            "Serves the robot PLC over Modbus and measures a sole on every trigger, until SIGTERM or "
            "Ctrl-C. The config is checked at start; any problem stops the service with a message."
        ),
    )
    parser.add_argument("--config", type=Path, required=True, help="cell config, e.g. /etc/cellctl/cell.toml")
    parser.add_argument("--state-dir", type=Path, help="override [journal] state_dir (journal, PLY, overlays)")
    parser.add_argument("--port", type=int, help="override [plc] port (TCP)")
    parser.add_argument("--station-port", type=int, metavar="PORT", help="override [station] port (web pages)")
    parser.add_argument("--verbose", action="store_true", help="also log debug messages")
    parser.set_defaults(func=run)


class JournaldFormatter(logging.Formatter):
    """One line per record; under systemd the "<N>" prefix sets the journal priority and journald adds
    the time, elsewhere a timestamp and level name are shown."""

    def __init__(self) -> None:
        self.under_systemd = "JOURNAL_STREAM" in os.environ or "INVOCATION_ID" in os.environ
        super().__init__(
            "%(name)s: %(message)s" if self.under_systemd else "%(asctime)s %(levelname)s %(name)s: %(message)s"
        )

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record).replace("\n", "\n    ")
        if self.under_systemd:
            return f"<{_PRIORITY.get(record.levelno, 6)}>{text}"
        return text


def setup_logging(verbose: bool) -> None:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JournaldFormatter())
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(logging.DEBUG if verbose else logging.INFO)
    logging.getLogger("pymodbus").setLevel(logging.WARNING)


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from cellctl.service.config import CellConfig
    from cellctl.service.daemon import Daemon
    from cellctl.service.station import Station

    setup_logging(args.verbose)
    config = CellConfig.load(args.config)
    if args.state_dir is not None:
        config = replace(config, journal=replace(config.journal, state_dir=args.state_dir.resolve()))
    if args.port is not None:
        config = replace(config, plc=replace(config.plc, port=args.port))
        config.plc.endpoint()  # checks the port range
    if args.station_port is not None:
        config = replace(config, station=replace(config.station, port=args.station_port))
    daemon = Daemon(config)
    station = Station.attach(daemon)  # pages, /metrics and image log share the daemon's state
    if station.url is not None:
        print(f"operator station: {station.url}", file=sys.stderr, flush=True)

    def stop(signum: int, _frame: object) -> None:
        logging.getLogger("cellctl.run").info("%s: stopping after the running cycle", signal.Signals(signum).name)
        daemon.request_stop()

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, stop)
        signal.signal(signal.SIGINT, stop)
    try:
        daemon.run()
    finally:
        station.stop()
    return 0
