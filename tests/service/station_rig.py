"""A service with its operator station for tests: Daemon in a thread on simulated 640x512 cameras, the
station's web server on a free port, and helpers to run cycles and make one fail for real."""

from __future__ import annotations

import threading
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np

from cellctl.cameras.base import StereoFrame
from cellctl.service.config import CellConfig
from cellctl.service.daemon import Daemon
from cellctl.service.events import CellEvent, CycleDone
from cellctl.service.station import Station
from firmware_io.plc_sim import CycleReading, PlcSimulator
from tests.sim_rig import HALF_RIG_MEASURE, write_half_size_rig

TOKEN = "test-token-0123"


def write_station_config(directory: Path, *, every_nth_good: int = 0) -> CellConfig:
    calib = write_half_size_rig(directory)
    path = directory / "cell.toml"
    path.write_text(
        f'[cameras]\nbackend = "simulated"\n[cameras.simulated]\nseeds = [1]\n'
        f'[calibration]\npath = "{calib}"\n[plc]\nport = 0\n'
        f'[journal]\nstate_dir = "{directory / "state"}"\nkeep_artifacts = 3\n'
        f'[station]\nport = 0\ntoken = "{TOKEN}"\nboard = "9x6"\n'
        f"[image_log]\nevery_nth_good = {every_nth_good}\nkeep_cycles = 20\n"
        f"{HALF_RIG_MEASURE}"
    )
    return CellConfig.load(path)


class StationService:
    """Daemon + Station as `cellctl run` wires them, in this process."""

    def __init__(self, config: CellConfig) -> None:
        self.daemon = Daemon(config)
        self.station = Station.attach(self.daemon, port=0)
        # Subscribed after the station: when this hears of a cycle, the hub, metrics and image log have it.
        self._done: set[int] = set()
        self._done_changed = threading.Condition()
        self.daemon.events.subscribe(self._on_event)
        assert self.station.url is not None
        self.url = self.station.url.rstrip("/")
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()
        assert self.daemon.wait_started(120), f"service did not start: {self.error}"
        self.plc = PlcSimulator(self.daemon.link.endpoint, heartbeat_limit_s=30.0)
        self.plc.connect()

    def _run(self) -> None:
        try:
            self.daemon.run()
        except BaseException as exc:  # reported by the test
            self.error = exc

    def _on_event(self, event: CellEvent) -> None:
        if isinstance(event, CycleDone):
            with self._done_changed:
                self._done.add(event.record.cycle)
                self._done_changed.notify_all()

    def cycle(self) -> CycleReading:
        """One PLC cycle, returned once the service's observers (image log, metrics, hub) have it too."""
        reading = self.plc.run_cycle(timeout_s=120.0)
        with self._done_changed:
            assert self._done_changed.wait_for(lambda: reading.cycle in self._done, timeout=60.0)
        assert self.station.context.image_log.wait_written(60.0)
        return reading

    def failing_cycle(self) -> CycleReading:
        """A cycle on an empty, featureless view (as if the table were covered): refused by the real
        measurement, with a frame, so its pictures are logged."""
        source = self.daemon.source
        original = source.grab_exposures
        frame = source.grab_pair()

        def empty_table(count: int, not_before: float | None = None) -> list[StereoFrame]:
            source.grab_exposures = original  # type: ignore[method-assign]
            rng = np.random.default_rng(0)
            grey = np.full_like(frame.left, 90)
            noisy = np.clip(grey + rng.normal(0, 2, grey.shape), 0, 255).astype(np.uint8)
            info = {"backend": "test", "scene": "empty"}
            return [StereoFrame(noisy, noisy.copy(), frame.t_left, frame.t_right, info)]

        source.grab_exposures = empty_table  # type: ignore[method-assign]
        return self.cycle()

    def get(self, path: str, headers: dict[str, str] | None = None, method: str = "GET") -> tuple[int, bytes]:
        request = urllib.request.Request(self.url + path, headers=headers or {}, method=method)
        try:
            with urllib.request.urlopen(request, timeout=60) as reply:
                return reply.status, reply.read()
        except urllib.error.HTTPError as error:
            return error.code, error.read()

    def stop(self) -> None:
        self.plc.close()
        self.daemon.request_stop()
        self.thread.join(60)
        self.station.stop()
        assert not self.thread.is_alive() and self.error is None, self.error
