"""The cell demo: `cellctl run` on simulated cameras in a child process, driven by the PLC simulator.

Kept apart from the `demo` command module so it can be reused (and because demo.py is the CLI wiring).

Beside the cycle times the demo prints the machine-independent figure of docs/benchmarks.md (section 4):
the time OpenCV StereoSGBM HH4 needs to match the same simulated pair over the cell's disparity range,
measured in this run (HH4_RUNS matches while the service idles before the cycles, as many after it
stopped), and the ratio of the median cycle to it.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from cellctl.eval.cycle_bench import HH4Reference, cycle_summary
from cellctl.service.config import CellConfig
from cellctl.service.journal import Journal
from firmware_io.endpoints import TcpEndpoint
from firmware_io.plc_sim import CycleReading, PlcSimError, PlcSimulator

DEFAULT_CONFIG = Path(__file__).resolve().parents[2] / "deploy" / "cell-sim.toml"
START_TIMEOUT_S = 300.0  # the simulated cameras render all scenes (a few s each) and the service warms up
HH4_RUNS = 5  # OpenCV HH4 matches timed before the cycles and again after them


def run_cell_demo(config: Path | None, port: int, cycles: int, out: Path, station_port: int | None = None) -> int:
    if cycles < 1:
        raise ValueError(f"--cycles {cycles} must be at least 1")
    config = DEFAULT_CONFIG if config is None else config
    station = _station_url(config, station_port)
    state = (out / "cell-state").resolve()
    shutil.rmtree(state, ignore_errors=True)  # a fresh journal, so the table below is this run's
    command = [
        sys.executable,
        "-m",
        "cellctl",
        "run",
        "--config",
        str(config),
        "--state-dir",
        str(state),
        "--port",
        str(port),
        *([] if station_port is None else ["--station-port", str(station_port)]),
    ]
    print(f"starting the service: {' '.join(command[2:])}", flush=True)
    if station:
        print(f"operator station (live while the demo runs): {station}", flush=True)
    # As deploy/cellctl.service runs it: numpy's BLAS single-threaded (why: in the unit file).
    environment = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    service = subprocess.Popen(command, stderr=subprocess.PIPE, text=True, env=environment)
    hh4_s: list[float] = []
    try:
        reference = _hh4_reference(config)  # rendered while the service renders its scenes
        readings = _drive(service, port, cycles, lambda: hh4_s.extend(_time(reference)))
    finally:
        service.send_signal(signal.SIGTERM)
        try:
            _, log = service.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            service.kill()
            _, log = service.communicate()
    if readings is None:
        print(log, file=sys.stderr)
        return 1
    hh4_s.extend(_time(reference))  # the service has stopped: nothing else of ours runs
    _report(readings, state, reference, hh4_s)
    if station:
        print(
            f"operator station: {station}  (it stopped with the demo; to browse these cycles run\n"
            f"  cellctl run --config {config} --state-dir {state}\n  and open {station})"
        )
    return 0 if all(r.ok for r in readings) else 1


def _station_url(config: Path, station_port: int | None) -> str | None:
    """Where the service's operator station will listen, from the config (None if disabled)."""
    from cellctl.service.config import CellConfig

    station = CellConfig.load(config).station
    if not station.enabled:
        return None
    host = "127.0.0.1" if station.bind in ("0.0.0.0", "") else station.bind
    return f"http://{host}:{station.port if station_port is None else station_port}/"


def _hh4_reference(config: Path) -> HH4Reference | None:
    """OpenCV HH4 on the simulated cameras' first pair over the cell's range (None for real cameras)."""
    from cellctl.cameras.simulated import SimulatedCameras
    from cellctl.vision.calibration import Calibration
    from cellctl.vision.cloud import disparity_range

    cell = CellConfig.load(config)
    if cell.cameras.backend != "simulated":
        return None
    calib = Calibration.load(cell.calibration.path)
    simulated = cell.cameras.simulated
    pair, _ = SimulatedCameras(calib, simulated.seeds, simulated.color).scene_for(simulated.seeds[0])
    return HH4Reference(calib, pair.left, pair.right, disparity_range(calib, cell.measure.depth_range_mm))


def _time(reference: HH4Reference | None) -> list[float]:
    return [] if reference is None else [reference.seconds() for _ in range(HH4_RUNS)]


def _drive(
    service: subprocess.Popen[str], port: int, cycles: int, before_cycles: Callable[[], None]
) -> list[CycleReading] | None:
    plc = PlcSimulator(TcpEndpoint("127.0.0.1", port), heartbeat_limit_s=1.5)
    deadline = time.monotonic() + START_TIMEOUT_S
    while not _listening(port):  # the port opens once the scenes are rendered
        if service.poll() is not None:
            print(f"the service exited with status {service.returncode} before serving:", file=sys.stderr)
            return None
        if time.monotonic() > deadline:
            print(f"the service did not serve Modbus on port {port} within {START_TIMEOUT_S:.0f} s", file=sys.stderr)
            return None
        time.sleep(0.5)
    try:
        plc.connect()
        before_cycles()
        readings = []
        for _ in range(cycles):
            reading = plc.run_cycle(timeout_s=15.0)
            print(f"  PLC: cycle {reading.cycle} answered in {reading.latency_s * 1000:.0f} ms", flush=True)
            readings.append(reading)
        return readings
    except PlcSimError as exc:
        print(f"PLC simulator: {exc}", file=sys.stderr)
        return None
    finally:
        plc.close()


def _listening(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
        return True
    except OSError:
        return False


def _report(readings: list[CycleReading], state: Path, reference: HH4Reference | None, hh4_s: list[float]) -> None:
    journal = Journal.open(state, readonly=True)
    print()
    print("cycle  scene  what        PLC received   simulated truth   error")
    worst = 0.0
    for reading in readings:
        record = journal.find(reading.cycle)
        if not reading.ok or record is None:
            print(f"{reading.cycle:5d}  error {reading.error_code}: {record.reason if record else 'not journaled'}")
            continue
        truth = record.source.get("truth", {})
        for i, (name, label) in enumerate(
            (("length_mm", "length"), ("heel_height_mm", "heel height"), ("toe_height_mm", "toe height"))
        ):
            got, true = getattr(reading, name), truth.get(name)
            error = "" if true is None else f"{got - true:+6.2f} mm"
            worst = max(worst, 0.0 if true is None else abs(got - true))
            head = f"{reading.cycle:5d}  {record.source.get('seed', '-'):>5}" if i == 0 else " " * 12
            true_text = "-" if true is None else f"{true:8.2f} mm"
            print(f"{head}  {label:<11} {got:8.2f} mm   {true_text:>15}   {error}")
        print(f"{'':12}  glue path   {len(reading.glue_points)} points, cycle time {reading.cycle_time_ms:.0f} ms")
    ok = [r for r in readings if r.ok]
    print(f"\n{len(ok)}/{len(readings)} cycles measured; largest error {worst:.2f} mm; {os.cpu_count()} cores")
    service_ms = statistics.median(r.cycle_time_ms for r in readings)
    print(f"service's own cycle time (trigger received to answer published): median {service_ms:.0f} ms")
    stages = _stage_medians(journal, readings)
    if stages:
        print("per stage, median ms: " + ", ".join(f"{name} {ms:.0f}" for name, ms in stages.items()))
    latencies = [r.latency_s for r in readings]  # the PLC's trigger write to its reading of the result
    if reference is not None and hh4_s:
        print("PLC " + cycle_summary(latencies, hh4_s, reference.image_size, reference.disparities))
    print(f"journal, PLY and overlay PNGs: {state}  (cellctl results --state-dir {state})")
    journal.close()


def _stage_medians(journal: Journal, readings: list[CycleReading]) -> dict[str, float]:
    """Median ms of each stage the service journaled for these cycles."""
    per_stage: dict[str, list[float]] = {}
    for reading in readings:
        record = journal.find(reading.cycle)
        for name, seconds in (record.timings if record else {}).items():
            per_stage.setdefault(name, []).append(1000.0 * seconds)
    return {name: statistics.median(values) for name, values in per_stage.items()}
