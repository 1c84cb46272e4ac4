"""The cell controller service: PLC trigger -> stereo pair -> measurement -> journal -> PLC.

    daemon = Daemon(CellConfig.load("deploy/cell-sim.toml"))
    daemon.run()                 # until daemon.request_stop() (SIGTERM in `cellctl run`)

One cycle, in this order (docs/modbus.md, handshake):
  1. wait for a trigger (PlcLink sets BUSY before it acknowledges the PLC's write);
  2. grab a synchronised pair; a CameraError clears CAMERAS_OK and answers with its error code;
  3. reconstruct and measure; an invalid measurement answers with the matching scene error code;
  4. journal the outcome durably (SQLite commit; its WAL checkpoints run on a thread of their own between
     cycles, journal.WalCheckpointer) - only then
  5. publish it to the PLC (result or error, one atomic update);
  6. hand the PLY and overlay PNG to the artifact writer, which writes them while the service waits for
     the next trigger (never during a cycle: cellctl.service.artifacts).

Before READY the service warms up: one cycle's work on a grabbed pair (the table plane learnt, rectification
maps built, the matchers' buffers allocated), so the first trigger costs what every other one does.

Every accepted trigger gets exactly one answer. While the cameras are failing the service probes them
between cycles, so CAMERAS_OK and READY come back by themselves when a camera is plugged in again.

Stopping (request_stop, e.g. SIGTERM): a cycle triggered before the stop request is finished and published
(it takes a second or two, far below systemd's stop timeout, and the PLC gets its answer); a trigger that
arrives once stopping has begun is answered with CYCLE_ABORTED. The link then keeps serving for
STOP_LINGER_S, so the PLC can read that last answer, and closes (cellctl.service.stopping).

This module is the wiring and the order of things (start, one cycle, stop). The parts live beside it:
the cameras' health (camera_health), the reconstructors and the warm-up (measuring), the pure cycle
(cycle), journal, PLC and listeners in that order (reporting), the stop request (stopping), recipes, the glue
path's frame, the outcome records, the artifact writer and the OPC UA server.
"""

from __future__ import annotations

import logging
import threading
from typing import TYPE_CHECKING

from cellctl.cameras import FrameSource, open_frame_source
from cellctl.service.artifacts import ArtifactWriter, finish_artifacts
from cellctl.service.camera_health import CameraHealth
from cellctl.service.cell_status import CellStatus
from cellctl.service.codes import CycleFailed
from cellctl.service.config import CellConfig
from cellctl.service.events import CycleDone
from cellctl.service.glue_output import GlueOutput
from cellctl.service.journal import Journal, WalCheckpointer
from cellctl.service.measuring import CellMeasurer
from cellctl.service.outcome import OutcomeListener
from cellctl.service.recipes import Recipe, RecipeBook
from cellctl.service.reporting import CycleReporter, log_cycle
from cellctl.service.sdnotify import SystemdNotifier, check_watchdog
from cellctl.service.stopping import StopRequest
from firmware_io.handshake import Trigger
from firmware_io.server import PlcLink

if TYPE_CHECKING:
    from cellctl.service.opcua import OpcUaServer

__all__ = ["CycleFailed", "Daemon"]

log = logging.getLogger(__name__)

#: How long one wait for a trigger lasts: the loop's tick for stop requests, watchdog pings and probes.
TICK_S = 0.25


class Daemon:
    """The service; construct, then run() in one thread and request_stop() from any thread."""

    def __init__(
        self, config: CellConfig, *, source: FrameSource | None = None, notifier: SystemdNotifier | None = None
    ) -> None:
        self.config = config
        self.measurer = CellMeasurer(config)
        self.calib = self.measurer.calib
        if source is None and self.calib is None and config.cameras.backend == "simulated":
            raise ValueError(
                "simulated cameras render through the calibration, which cannot be used: "
                f"{self.measurer.calibration_problem}"
            )
        self.source = source if source is not None else open_frame_source(config.cameras, self.calib)
        self.cameras = CameraHealth(self.source, self.calib, config.cameras.averaged_frames)
        self.cameras.setup_problem = self.measurer.setup_problem or None  # set: CALIBRATION_OK (and READY) stay off
        self.camera_lock = self.cameras.lock  # held for every grab: the station's live view grabs between cycles
        self.link = _plc_link(config)
        self.status = CellStatus(self.link, self.cameras, notifier if notifier is not None else SystemdNotifier())
        self.events = self.status.events  # observers (operator station, metrics, image log) subscribe here
        self.recipes = RecipeBook.load(config.recipes.directory, config.measure)
        if (note := self.recipes.wall_note()) is not None:
            log.info(note)  # a commissioning hint, not a fault: the defaults refuse what they cannot see
        self.glue_output = GlueOutput.from_config(config)
        self.reporter = CycleReporter(config, self.link, self.glue_output)
        self.listeners: list[OutcomeListener] = self.reporter.listeners  # called after the PLC has its answer
        self.active_recipe: Recipe | None = self.recipes.get(0)
        self.opcua: OpcUaServer | None = None  # the OPC UA server while running, if [opcua] enabled
        self._stop = StopRequest()
        self._started = threading.Event()
        self._artifacts = None if self.calib is None else ArtifactWriter(self.calib, config.journal.keep_artifacts)

    # ---- lifetime ------------------------------------------------------------------------------

    def request_stop(self) -> None:
        """Finish the running cycle, answer later triggers with CYCLE_ABORTED, then stop (thread-safe)."""
        self._stop.request()

    def wait_started(self, timeout_s: float) -> bool:
        """True once the Modbus link serves and the service waits for triggers."""
        return self._started.wait(timeout_s)

    def run(self) -> None:
        """Serve until request_stop(); raises if the journal or the Modbus port cannot be opened."""
        _check_watchdog(self.config)
        journal = Journal.open(self.config.journal.state_dir)
        checkpoints = WalCheckpointer(journal)
        try:
            _resume(journal, self.link)
            # Cameras first: preparing them may take long (the simulator renders its scenes), and the
            # heartbeat would stop meanwhile (PlcLink's liveness check), alarming the PLC for nothing.
            self._probe_cameras(force=True)
            self._warm_up()
            opcua = self._start_opcua()  # before the link too: asyncua loads its address space for seconds
            try:
                self._serve_link(journal, checkpoints)
            finally:
                if opcua is not None:
                    opcua.stop()
        finally:
            self.source.close()
            if self._artifacts is not None:
                finish_artifacts(self._artifacts, journal)
            checkpoints.close()
            journal.close()  # checkpoints what is left
            log.info("stopped after %d cycles", self.status.cycles_done)

    def _serve_link(self, journal: Journal, checkpoints: WalCheckpointer) -> None:
        self.link.start()
        try:
            self.status.ready()
            log.info("ready: Modbus %s, cameras %s", self.link.endpoint, "ok" if self.cameras.ok else "NOT ok")
            self._started.set()
            while not self._stop.requested:
                self.status.notifier.notify(WATCHDOG=1)
                self._set_idle(journal, True)
                checkpoints.idle()
                trigger = self.link.wait_trigger(timeout_s=TICK_S)
                if trigger is None:  # still idle: the artifact writer's settling time runs on across ticks
                    self._probe_cameras()
                    continue
                self._set_idle(journal, False)
                self._answer(journal, trigger)
            self._stop.linger(self.link, lambda late: self._answer(journal, late))
        finally:
            self.status.stopping()
            self.link.stop()

    def _start_opcua(self) -> OpcUaServer | None:
        if not self.config.opcua.enabled:
            return None
        from cellctl.service.opcua import serve_cell  # asyncua is imported only when enabled

        server = serve_cell(self.config.opcua, self.link, self.recipes, lambda: self.active_recipe)
        self.listeners.append(server.publish)
        self.opcua = server
        return server

    # ---- one cycle -----------------------------------------------------------------------------

    def _answer(self, journal: Journal, trigger: Trigger) -> None:
        """Measure a trigger accepted before any stop request; abort one accepted after it."""
        if self._stop.aborts(trigger):
            record = self.reporter.abort(journal, trigger, self.recipes.get(trigger.recipe))
            self.events.publish(CycleDone(record, None, None))
            return
        self.status.busy(trigger.cycle)
        timings: dict[str, float] = {}
        recipe = self.recipes.get(trigger.recipe)
        if recipe is not None:
            self.active_recipe = recipe
        frame, outcome = self.measurer.answer(trigger, recipe, self.cameras, timings)
        record, result = self.reporter.report(journal, trigger, outcome, timings, frame, recipe)
        self.status.report_health()
        self.reporter.tell_listeners(record, recipe)
        self.status.cycles_done += 1
        log_cycle(record)
        if frame is not None and result is not None and self._artifacts is not None:
            self._artifacts.submit(journal, record, frame, result.reconstruction, result.measurement)
        self.status.done(CycleDone(record, frame, result))

    # ---- between cycles ------------------------------------------------------------------------

    def _warm_up(self) -> None:
        """Skipped while the cameras fail (the first cycle then pays)."""
        if self.cameras.ok:
            self.measurer.warm_up(self.source, self.recipes)

    def _set_idle(self, journal: Journal, idle: bool) -> None:
        """Artifacts are written only while waiting for a trigger; their journal rows from this thread."""
        if self._artifacts is None:
            return
        if idle:
            self._artifacts.attach_finished(journal)
        self._artifacts.set_idle(idle)

    def _probe_cameras(self, force: bool = False) -> None:
        """At start (force) and every few s while the cameras fail; READY at once when they are back."""
        if self.cameras.probe(force) and not force:
            self.status.report_health()  # READY at once; the warm-up below only if the start could not do it
            self.status.publish_state()
            if not self.measurer.warmed_up:
                self._warm_up()


def _check_watchdog(config: CellConfig) -> None:
    """A stuck cycle is answered CYCLE_TIMEOUT, the heartbeat stops liveness_timeout_s later: both must come
    before systemd's watchdog (pinged between cycles only) restarts the service."""
    plc = config.plc
    check_watchdog(
        plc.cycle_timeout_s + plc.liveness_timeout_s, f"{config.source}: [plc] cycle_timeout_s + liveness_timeout_s"
    )


def _resume(journal: Journal, link: PlcLink) -> None:
    """After a (re)start: the PLC's cyclic rewrite of its last cycle number must not be a new cycle, and
    artifact folders a crash left without a journal row go."""
    link.restore_last_cycle(journal.last_cycle())
    if orphans := journal.prune_orphans():
        log.info("removed %d artifact folders no journal row refers to (left by a crash)", orphans)


def _plc_link(config: CellConfig) -> PlcLink:
    plc = config.plc
    return PlcLink(
        plc.endpoint(),
        unit_id=plc.unit_id,
        word_order=plc.word_order,
        heartbeat_period_s=plc.heartbeat_period_s,
        liveness_timeout_s=plc.liveness_timeout_s,
        map_version=plc.map_version,
        cycle_timeout_s=plc.cycle_timeout_s,
        limits=plc.limits(),
    )
