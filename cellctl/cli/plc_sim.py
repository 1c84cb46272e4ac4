"""`cellctl plc-sim`: act as the robot PLC against a running controller and print what it receives."""

from __future__ import annotations

import argparse
import json
import logging
import sys

from firmware_io.endpoints import DEFAULT_TCP_PORT, Endpoint, SerialEndpoint, TcpEndpoint


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "plc-sim",
        help="trigger cycles over Modbus like the robot PLC and print the results",
        description=(
            "Connects to the controller's Modbus server (TCP, or RTU with --serial), triggers "
            "--cycles measurement cycles and prints one line per cycle. Fails (exit 1) when the "
            "handshake breaks: no result in time, refused trigger, heartbeat stuck, no connection."
        ),
    )
    parser.add_argument("--host", default="127.0.0.1", help="controller address (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=DEFAULT_TCP_PORT, help=f"TCP port (default {DEFAULT_TCP_PORT})")
    parser.add_argument("--serial", metavar="DEVICE", help="use Modbus RTU on this serial device instead of TCP")
    parser.add_argument("--baudrate", type=int, default=19200, help="RTU baud rate (default 19200)")
    parser.add_argument("--parity", choices=("N", "E", "O"), default="E", help="RTU parity (default E)")
    parser.add_argument("--unit", type=int, default=1, help="Modbus unit id (default 1)")
    parser.add_argument(
        "--word-order",
        default="high_first",
        metavar="{high_first,low_first}",  # checked in run(): firmware_io.registers loads numpy and pymodbus
        help="float32 word order, must match the controller (default high_first)",
    )
    parser.add_argument("--cycles", type=int, default=10, help="number of cycles to run (default 10)")
    parser.add_argument("--interval", type=float, default=0.5, help="seconds between cycles (default 0.5)")
    parser.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for each result (default 5)")
    parser.add_argument(
        "--heartbeat-limit", type=float, default=1.5, help="fail if the heartbeat is stuck this long (default 1.5 s)"
    )
    parser.add_argument(
        "--map-version",
        type=int,
        choices=(1, 2),
        help="register map version this PLC is programmed for (default: the one the controller announces)",
    )
    parser.add_argument("--recipe", type=int, help="map v2: write this recipe number (register 7) before every trigger")
    parser.add_argument("--json", action="store_true", help="print one JSON object per cycle instead of text")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from firmware_io.plc_sim import PlcSimError, PlcSimulator, describe  # pymodbus: only when it runs
    from firmware_io.registers import WordOrder

    if args.word_order not in {w.value for w in WordOrder}:
        raise ValueError(f"--word-order {args.word_order!r} is not one of {', '.join(w.value for w in WordOrder)}")

    endpoint = _endpoint(args)
    if args.cycles < 1:
        raise ValueError(f"--cycles {args.cycles} must be at least 1")
    if args.interval < 0:
        raise ValueError(f"--interval {args.interval} must not be negative")
    if args.timeout <= 0:
        raise ValueError(f"--timeout {args.timeout} must be positive")
    if args.recipe is not None and not 0 <= args.recipe <= 0xFFFF:
        raise ValueError(f"--recipe {args.recipe} must be 0..65535")
    # pymodbus logs a failed connect itself; the one line below says it, with the remedy.
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    simulator = PlcSimulator(
        endpoint,
        unit_id=args.unit,
        word_order=WordOrder(args.word_order),
        heartbeat_limit_s=args.heartbeat_limit,
        map_version=args.map_version,
    )
    try:
        with simulator:
            for index in range(args.cycles):
                if index:
                    simulator.watch_heartbeat(args.interval)
                reading = simulator.run_cycle(timeout_s=args.timeout, recipe=args.recipe)
                print(json.dumps(reading.as_dict()) if args.json else describe(reading), flush=True)
    except PlcSimError as exc:
        print(f"cellctl plc-sim: handshake failed: {exc}", file=sys.stderr)
        return 1
    return 0


def _endpoint(args: argparse.Namespace) -> Endpoint:
    if args.serial:
        return SerialEndpoint(args.serial, baudrate=args.baudrate, parity=args.parity)
    return TcpEndpoint(args.host, args.port)
