"""Prometheus metrics of the running cell, served at the station's /metrics.

    metrics = CellMetrics(link=daemon.link, state_dir=config.journal.state_dir)
    daemon.events.subscribe(metrics.on_event)
    metrics.exposition()               # text format, for GET /metrics

One registry per service (not the process-wide default), so tests can run several services in one process.
Counters move on the daemon's events; the Modbus and disk gauges are read when scraped.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector

from cellctl.service.events import CellEvent, CellState, CycleDone
from cellctl.service.measuring import RETRY_STEP
from firmware_io.registers import ErrorCode
from firmware_io.server import PlcLink

# Seconds: the target is below 1 s (docs/modbus.md), a loaded 2-core machine takes a few.
CYCLE_TIME_BUCKETS = (0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 5.0, 8.0, 13.0, 20.0)
DISK_SCAN_PERIOD_S = 30.0  # walking the state directory on every scrape would cost more than it tells


class CellMetrics:
    """The cell's metrics in their own registry."""

    def __init__(self, link: PlcLink | None, state_dir: Path) -> None:
        self.registry = CollectorRegistry()
        self.cycle_time = Histogram(
            "cellctl_cycle_time_seconds",
            "Trigger received to result published",
            buckets=CYCLE_TIME_BUCKETS,
            registry=self.registry,
        )
        self.cycles = Counter(
            "cellctl_cycles", "Cycles by result and PLC error code", ("result", "code"), registry=self.registry
        )
        self.measured_again = Counter(
            "cellctl_cycles_measured_again",
            "Cycles measured once more on more exposures for their glue heights' precision, by result",
            ("result",),
            registry=self.registry,
        )
        self.camera_reconnects = Counter(
            "cellctl_camera_reconnects", "Times the cameras came back after failing", registry=self.registry
        )
        self.cameras_ok = Gauge("cellctl_cameras_ok", "1 while both cameras deliver pairs", registry=self.registry)
        self.disk = Gauge(
            "cellctl_state_dir_bytes",
            "Disk use of the state directory (journal, artifacts, image log)",
            registry=self.registry,
        )
        self._state_dir = state_dir
        self._disk_scanned_at = -DISK_SCAN_PERIOD_S
        self.disk.set_function(self._disk_bytes)
        self._disk_cache = 0.0
        self._cameras_were_ok: bool | None = None
        if link is not None:
            self.registry.register(_LinkCollector(link))

    def on_event(self, event: CellEvent) -> None:
        """Subscriber for Daemon.events."""
        if isinstance(event, CycleDone):
            record = event.record
            self.cycle_time.observe(record.cycle_time_ms / 1000.0)
            self.cycles.labels(record.status, _code_name(record.error_code)).inc()
            if RETRY_STEP in record.timings:
                self.measured_again.labels(record.status).inc()
        elif isinstance(event, CellState) and event.phase != "starting":
            if self._cameras_were_ok is False and event.cameras_ok:
                self.camera_reconnects.inc()
            self._cameras_were_ok = event.cameras_ok
            self.cameras_ok.set(1 if event.cameras_ok else 0)

    def exposition(self) -> bytes:
        return generate_latest(self.registry)

    def _disk_bytes(self) -> float:
        now = time.monotonic()
        if now - self._disk_scanned_at >= DISK_SCAN_PERIOD_S:
            self._disk_scanned_at = now
            self._disk_cache = float(_tree_bytes(self._state_dir))
        return self._disk_cache


class _LinkCollector(Collector):
    """Modbus figures read from the PlcLink at scrape time."""

    def __init__(self, link: PlcLink) -> None:
        self.link = link

    def collect(self):  # noqa: ANN201 - prometheus_client's Collector protocol
        yield GaugeMetricFamily(
            "cellctl_modbus_clients", "Modbus TCP clients connected now", value=self.link.connected_clients
        )
        stalls = CounterMetricFamily(
            "cellctl_heartbeat_stalls", "Times the heartbeat stopped because the controller loop went silent"
        )
        stalls.add_metric([], self.link.heartbeat_stalls)
        yield stalls


def _code_name(code: int) -> str:
    try:
        return ErrorCode(code).name
    except ValueError:
        return str(code)


def _tree_bytes(root: Path) -> int:
    total = 0
    for folder, _dirs, files in os.walk(root):
        for name in files:
            try:
                total += os.lstat(os.path.join(folder, name)).st_size
            except OSError:
                pass
    return total
