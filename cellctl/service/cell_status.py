"""What the cell says about itself, to each audience: the PLC's status bits (cameras, calibration), systemd's
status line and readiness, and the observers' CellState (cellctl.service.events)."""

from __future__ import annotations

from cellctl.service.camera_health import CameraHealth
from cellctl.service.events import CellEvents, CellState, CycleDone
from cellctl.service.sdnotify import SystemdNotifier
from firmware_io.server import PlcLink


class CellStatus:
    """The service's phase (ready, busy, error, stopping) and cycle count, told to everyone who listens."""

    def __init__(self, link: PlcLink, cameras: CameraHealth, notifier: SystemdNotifier) -> None:
        self.link, self.cameras, self.notifier = link, cameras, notifier
        self.events = CellEvents()  # observers (operator station, metrics, image log) subscribe here
        self.cycles_done = 0
        self.busy_cycle: int | None = None

    def ready(self) -> None:
        """The link serves and the service waits for triggers."""
        self.report_health()
        self.notifier.notify(READY=1, STATUS=self.text())
        self.publish_state()

    def busy(self, cycle: int) -> None:
        self.notifier.notify(STATUS=f"measuring cycle {cycle}")
        self.busy_cycle = cycle
        self.publish_state()

    def done(self, event: CycleDone) -> None:
        """A cycle answered: its outcome to the observers, then the phase after it."""
        self.busy_cycle = None
        self.events.publish(event)
        self.publish_state()
        self.notifier.notify(STATUS=self.text())

    def stopping(self) -> None:
        self.notifier.notify(STOPPING=1, STATUS="stopping")
        self.publish_state("stopping")

    def report_health(self) -> None:
        """CAMERAS_OK and CALIBRATION_OK (hence READY) for the PLC."""
        self.link.set_status(cameras_ok=self.cameras.ok, calibration_ok=self.cameras.calibration_ok)

    def publish_state(self, phase: str | None = None) -> None:
        ok, calibrated = self.cameras.ok, self.cameras.calibration_ok  # as the PLC's CALIBRATION_OK bit
        if phase is None:
            phase = "busy" if self.busy_cycle is not None else "ready" if ok and calibrated else "error"
        self.events.publish(CellState(phase, ok, calibrated, self.cycles_done, self.busy_cycle))

    def text(self) -> str:
        cameras = "cameras ok" if self.cameras.ok else "CAMERAS NOT OK"
        calibration = "calibration ok" if self.cameras.calibration_ok else "CALIBRATION NOT OK"
        return f"waiting for trigger; {self.cycles_done} cycles; {cameras}; {calibration}"
