"""The cell controller service: PLC trigger -> stereo pair -> measurement -> journal -> PLC.

    daemon = Daemon(CellConfig.load("deploy/cell-sim.toml"))
    daemon.run()                 # until daemon.request_stop() (SIGTERM in `cellctl run`)

One cycle, in this order (docs/modbus.md, handshake):
  1. wait for a trigger (PlcLink sets BUSY before it acknowledges the PLC's write);
  2. grab a synchronised pair; a CameraError clears CAMERAS_OK and answers with its error code;
  3. reconstruct and measure; an invalid measurement answers with the matching scene error code;
  4. journal the outcome durably (SQLite commit) - only then
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
STOP_LINGER_S, so the PLC can read that last answer, and closes.

Longer than most modules (~420 lines): the order of one cycle (journal, PLC, listeners, artifacts) and of
start and stop is the service's contract, and it reads best in one place. Recipes, the glue path's frame,
the outcome records and the OPC UA server live in their own modules.
"""

from __future__ import annotations

import logging
import math
import threading
import time

from cellctl.cameras import CameraError, FrameSource, StereoFrame, open_frame_source
from cellctl.cameras.identity import identity_problem
from cellctl.errors import FailureKind
from cellctl.service.artifacts import ArtifactWriter
from cellctl.service.codes import FAILURE_CODES
from cellctl.service.config import CellConfig
from cellctl.service.cycle import Measured, MeasureSettings, Refused, measure_frame
from cellctl.service.events import CellEvents, CellState, CycleDone
from cellctl.service.glue_output import GlueOutput
from cellctl.service.journal import CycleRecord, Journal
from cellctl.service.outcome import OutcomeListener, journal_record, outcome_of
from cellctl.service.quiet_log import RepeatQuietLog
from cellctl.service.recipes import Recipe, RecipeBook
from cellctl.service.sdnotify import SystemdNotifier, check_watchdog
from cellctl.vision.calibration import Calibration
from cellctl.vision.measurement import SoleMeasurement
from cellctl.vision.reconstruction import SoleReconstructor
from cellctl.vision.teach import TaughtTable, TeachError, load_taught
from firmware_io.handshake import Inspection, PathInfo, Trigger
from firmware_io.registers import ErrorCode, FeatureBit
from firmware_io.server import PlcLink

log = logging.getLogger(__name__)

#: How long one wait for a trigger lasts: the loop's tick for stop requests, watchdog pings and probes.
TICK_S = 0.25
#: After a stop request, how long the Modbus link still serves so the PLC can read the last answer.
STOP_LINGER_S = 0.5
#: Cameras that failed are probed this often between cycles so READY comes back without a trigger.
CAMERA_PROBE_PERIOD_S = 1.0
#: The same camera failure is logged again (at warning level) at most this often.
CAMERA_LOG_REPEAT_S = 60.0


class CycleFailed(Exception):
    """A cycle ends with an error code for the PLC."""

    def __init__(self, code: ErrorCode, reason: str) -> None:
        super().__init__(reason)
        self.code = code

    @classmethod
    def of(cls, failure: FailureKind, reason: str) -> CycleFailed:
        """A failure of a kind, answered with the code the table at the service edge gives it."""
        return cls(FAILURE_CODES[failure], reason)


class Daemon:
    """The service; construct, then run() in one thread and request_stop() from any thread."""

    def __init__(
        self,
        config: CellConfig,
        *,
        source: FrameSource | None = None,
        notifier: SystemdNotifier | None = None,
    ) -> None:
        self.config = config
        self.calib, self._calibration_problem = _load_calibration(config)
        if source is None and self.calib is None and config.cameras.backend == "simulated":
            raise ValueError(
                f"simulated cameras render through the calibration, which cannot be used: {self._calibration_problem}"
            )
        self.source = source if source is not None else open_frame_source(config.cameras, self.calib)
        self.notifier = notifier if notifier is not None else SystemdNotifier()
        plc = config.plc
        self.link = PlcLink(
            plc.endpoint(),
            unit_id=plc.unit_id,
            word_order=plc.word_order,
            heartbeat_period_s=plc.heartbeat_period_s,
            liveness_timeout_s=plc.liveness_timeout_s,
            map_version=plc.map_version,
            cycle_timeout_s=plc.cycle_timeout_s,
            limits=plc.limits(),
        )
        self.recipes = RecipeBook.load(config.recipes.directory, config.measure)
        self.glue_output = GlueOutput.from_config(config)
        #: Called with each finished cycle after the PLC has its answer (OPC UA, station); must not block.
        self.listeners: list[OutcomeListener] = []
        self.active_recipe: Recipe | None = self.recipes.get(0)
        self.opcua = None  # the OPC UA server while running, if [opcua] enabled
        self._reconstructor = (
            None
            if self.calib is None
            else SoleReconstructor(self.calib, config.measure.depth_range_mm, taught=_load_taught(config, self.calib))
        )
        # At most one more, for a recipe's own depth range: each matcher keeps its cost volume (~0.5 GB at
        # 1280x1024), so a line switching among several depth ranges re-allocates rather than piling them up.
        self._recipe_reconstructor: SoleReconstructor | None = None
        self._stop = threading.Event()
        self._stop_at = math.inf  # time.monotonic() of the stop request
        self._started = threading.Event()
        self._cameras_ok = False
        self._identity_problem: str | None = None
        self._camera_log = RepeatQuietLog(log, CAMERA_LOG_REPEAT_S)
        self._last_probe = 0.0
        self._journal: Journal | None = None
        self._artifacts = None if self.calib is None else ArtifactWriter(self.calib, config.journal.keep_artifacts)
        self._warmed_up = False
        self.cycles_done = 0
        # Observers (operator station, metrics, image log) subscribe here; the daemon only publishes.
        self.events = CellEvents()
        # Held for every grab: the station's live view grabs between cycles and never during one.
        self.camera_lock = threading.Lock()
        self._busy_cycle: int | None = None

    # ---- lifetime ------------------------------------------------------------------------------

    def request_stop(self) -> None:
        """Finish the running cycle, answer later triggers with CYCLE_ABORTED, then stop (thread-safe)."""
        self._stop_at = min(self._stop_at, time.monotonic())
        self._stop.set()

    def wait_started(self, timeout_s: float) -> bool:
        """True once the Modbus link serves and the service waits for triggers."""
        return self._started.wait(timeout_s)

    def run(self) -> None:
        """Serve until request_stop(); raises if the journal or the Modbus port cannot be opened."""
        # A stuck cycle is answered CYCLE_TIMEOUT, the heartbeat stops liveness_timeout_s later: both must
        # come before systemd's watchdog (pinged between cycles only) restarts the service.
        plc = self.config.plc
        check_watchdog(
            plc.cycle_timeout_s + plc.liveness_timeout_s,
            f"{self.config.source}: [plc] cycle_timeout_s + liveness_timeout_s",
        )
        self._journal = Journal.open(self.config.journal.state_dir)
        try:
            # A restart must not make the PLC's cyclic rewrite of its last cycle number a new cycle.
            self.link.restore_last_cycle(self._journal.last_cycle())
            if orphans := self._journal.prune_orphans():
                log.info("removed %d artifact folders no journal row refers to (left by a crash)", orphans)
            # Cameras first: preparing them may take long (the simulator renders its scenes), and the
            # heartbeat would stop meanwhile (PlcLink's liveness check), alarming the PLC for nothing.
            self._probe_cameras(force=True)
            self._warm_up()
            opcua = self._start_opcua()  # before the link too: asyncua loads its address space for seconds
            try:
                self._serve_link()
            finally:
                if opcua is not None:
                    opcua.stop()
        finally:
            self.source.close()
            self._finish_artifacts()
            self._journal.close()
            log.info("stopped after %d cycles", self.cycles_done)

    def _serve_link(self) -> None:
        self.link.start()
        try:
            self._report_health()
            self.notifier.notify(READY=1, STATUS=self._status_text())
            log.info("ready: Modbus %s, cameras %s", self.link.endpoint, "ok" if self._cameras_ok else "NOT ok")
            self._started.set()
            self._publish_state()
            self._serve()
        finally:
            self.notifier.notify(STOPPING=1, STATUS="stopping")
            self._publish_state("stopping")
            self.link.stop()

    def _start_opcua(self):  # noqa: ANN202 - OpcUaServer | None; asyncua is imported only when enabled
        if not self.config.opcua.enabled:
            return None
        from cellctl.service.opcua import OpcUaServer

        def active() -> tuple[int, str]:
            recipe = self.active_recipe
            return (0, "") if recipe is None else (recipe.number, recipe.name)

        server = OpcUaServer(
            self.config.opcua,
            status=lambda: self.link.status,
            recipes=[(r.number, r.name) for r in self.recipes],
            active_recipe=active,
        )
        server.start()
        self.listeners.append(server.publish)
        self.opcua = server
        return server

    def _serve(self) -> None:
        while not self._stop.is_set():
            self.notifier.notify(WATCHDOG=1)
            self._set_idle(True)
            trigger = self.link.wait_trigger(timeout_s=TICK_S)
            self._set_idle(False)
            if trigger is None:
                self._probe_cameras()
                continue
            self._answer(trigger)
        # Serve a little longer: the PLC reads the last answer, and a trigger arriving now is answered.
        deadline = time.monotonic() + STOP_LINGER_S
        while (left := deadline - time.monotonic()) > 0:
            late = self.link.wait_trigger(timeout_s=left)
            if late is not None:
                self._answer(late)

    def _answer(self, trigger: Trigger) -> None:
        """Measure a trigger accepted before any stop request; abort one accepted after it."""
        if trigger.received_at >= self._stop_at:
            self._abort(trigger)
        else:
            self._cycle(trigger)

    # ---- one cycle -----------------------------------------------------------------------------

    def _cycle(self, trigger: Trigger) -> None:
        self.notifier.notify(STATUS=f"measuring cycle {trigger.cycle}")
        self._busy_cycle = trigger.cycle
        self._publish_state()
        triggered_at = time.time() - (time.monotonic() - trigger.received_at)
        timings: dict[str, float] = {}
        frame: StereoFrame | None = None
        result: Measured | None = None
        recipe = self.recipes.get(trigger.recipe)
        try:
            if recipe is None:
                raise CycleFailed.of(
                    FailureKind.RECIPE_UNKNOWN, f"recipe {trigger.recipe} selected by the PLC is not loaded"
                )
            self.active_recipe = recipe
            frame = self._grab(timings, not_before=trigger.received_at)
            result = self._measure(frame, timings, recipe)
            code, reason = ErrorCode.NONE, None
        except CycleFailed as failure:
            code, reason = failure.code, str(failure)
        except Exception as exc:  # never leave the PLC without an answer
            log.exception("cycle %d: unexpected failure", trigger.cycle)
            code, reason = ErrorCode.INTERNAL_ERROR, f"internal error: {type(exc).__name__}: {exc}"
        cycle_time_ms = (time.monotonic() - trigger.received_at) * 1000.0
        late = f"not published within cycle_timeout_s = {self.config.plc.cycle_timeout_s:g} s (took {cycle_time_ms:.0f} ms)"
        if self.link.timed_out(trigger.cycle):  # the link answered CYCLE_TIMEOUT: the late result is not used
            code, reason, result = ErrorCode.CYCLE_TIMEOUT, late, None
        measurement = None if result is None else result.measurement
        failed = _inspect(recipe, measurement) if code is ErrorCode.NONE else None
        record = journal_record(
            trigger.cycle,
            triggered_at,
            code,
            reason,
            cycle_time_ms,
            timings,
            measurement,
            frame,
            trigger.recipe,
            failed,
        )
        assert self._journal is not None
        self._journal.record(record)  # durable before the PLC hears of it
        if (
            not self._publish(trigger.cycle, code, cycle_time_ms, measurement, recipe, failed)
            and code is not ErrorCode.CYCLE_TIMEOUT
        ):
            # It timed out between the check above and publishing: the journal says what the PLC was told.
            assert record.id is not None
            self._journal.amend_error(record.id, int(ErrorCode.CYCLE_TIMEOUT), late)
            code, reason, result = ErrorCode.CYCLE_TIMEOUT, late, None
            record = journal_record(
                trigger.cycle, triggered_at, code, reason, cycle_time_ms, timings, None, frame, trigger.recipe, None
            )
        self._report_health()
        self._tell_listeners(record, recipe)
        self.cycles_done += 1
        if code is ErrorCode.NONE:
            log.info(
                "cycle %d: length %.2f heel %.2f toe %.2f mm, %d glue points, %.0f ms",
                trigger.cycle,
                record.length_mm,
                record.heel_height_mm,
                record.toe_height_mm,
                len(record.glue_path),
                cycle_time_ms,
            )
        else:
            log.warning("cycle %d: error %d %s: %s (%.0f ms)", trigger.cycle, code, code.name, reason, cycle_time_ms)
        if frame is not None and result is not None and self._artifacts is not None:
            self._artifacts.submit(self._journal, record, frame, result.reconstruction, result.measurement)
        self._busy_cycle = None
        self.events.publish(CycleDone(record, frame, result))
        self._publish_state()
        self.notifier.notify(STATUS=self._status_text())

    # ---- warm-up and artifacts ------------------------------------------------------------------

    def _warm_up(self) -> None:
        """One cycle's work before READY on a grabbed pair: the table plane learnt (when none is taught),
        maps built, matcher buffers allocated. Skipped while the cameras fail (the first cycle then pays)."""
        if self._reconstructor is None or not self._cameras_ok:
            return
        start = time.monotonic()
        try:
            frame = self.source.grab_pair()
        except CameraError as exc:
            log.warning("warm-up skipped, no pair: %s", exc)
            return
        if self._reconstructor.table_plane is None:
            plane = self._reconstructor.learn_table(frame.left, frame.right)
            log.info("table plane %s", "learnt from the warm-up pair" if plane is not None else "NOT found")
        measure = self.config.measure
        result = measure_frame(
            frame, self._reconstructor, MeasureSettings(measure.glue_offset_mm, measure.glue_spacing_mm)
        )
        outcome = "measured" if isinstance(result, Measured) else f"refused ({result.reason})"
        log.info("warmed up in %.1f s: pair %s", time.monotonic() - start, outcome)
        self._warmed_up = True

    def _set_idle(self, idle: bool) -> None:
        """Artifacts are written only while waiting for a trigger; their journal rows from this thread."""
        if self._artifacts is None:
            return
        if idle and self._journal is not None:
            self._artifacts.attach_finished(self._journal)
        self._artifacts.set_idle(idle)

    def _finish_artifacts(self) -> None:
        if self._artifacts is None or self._journal is None:
            return
        if not self._artifacts.flush(timeout_s=10.0):
            log.warning("stopping with artifacts not written")
        self._artifacts.attach_finished(self._journal)
        self._artifacts.close()
        if self._artifacts.dropped:
            log.info("artifacts of %d cycles skipped for lack of idle time", self._artifacts.dropped)

    def _grab(self, timings: dict[str, float], not_before: float) -> StereoFrame:
        start = time.perf_counter()
        try:
            with self.camera_lock:
                frame = self.source.grab_pair(not_before=not_before)  # frames exposed after the trigger only
        except CameraError as exc:
            self._cameras_ok = False
            self._last_probe = time.monotonic()
            raise CycleFailed.of(exc.kind, str(exc)) from exc
        finally:
            timings["grab"] = time.perf_counter() - start
        self._cameras_ok = True
        return frame

    def _measure(self, frame: StereoFrame, timings: dict[str, float], recipe: Recipe) -> Measured:
        if self.calib is None:
            raise CycleFailed.of(FailureKind.CALIBRATION_MISSING, f"no calibration loaded: {self._calibration_problem}")
        if problem := identity_problem(self.calib.cameras, frame.info):
            raise CycleFailed.of(FailureKind.CALIBRATION_MISMATCH, problem)
        reconstructor = self._reconstructor
        if recipe.depth_range_mm != self.config.measure.depth_range_mm or reconstructor is None:
            # The matcher's disparity range follows from the depth range.
            reconstructor = self._recipe_reconstructor
            if reconstructor is None or reconstructor.depth_range_mm != recipe.depth_range_mm:
                self._recipe_reconstructor = None  # release the old buffers before allocating new ones
                taught = None if self._reconstructor is None else self._reconstructor.taught
                reconstructor = SoleReconstructor(self.calib, recipe.depth_range_mm, taught=taught)
                self._recipe_reconstructor = reconstructor
        result = measure_frame(frame, reconstructor, MeasureSettings(recipe.glue_offset_mm, recipe.glue_spacing_mm))
        timings.update(result.timings)
        if isinstance(result, Refused):
            raise CycleFailed.of(result.failure, result.reason)
        return result

    def _publish(
        self,
        cycle: int,
        code: ErrorCode,
        cycle_time_ms: float,
        measurement: SoleMeasurement | None,
        recipe: Recipe | None,
        failed: FeatureBit | None,
    ) -> bool:
        """Answer the PLC (False if the link had answered CYCLE_TIMEOUT already); `failed`: the features out of
        tolerance (None when nothing was checked)."""
        if code is not ErrorCode.NONE or measurement is None or recipe is None:
            return self.link.publish_error(cycle, code, cycle_time_ms=cycle_time_ms)
        out = self.glue_output.prepare(measurement.glue_path.points, measurement.glue_path.normals)
        return self.link.publish_result(
            cycle,
            heel_height_mm=measurement.heel_height_mm,
            toe_height_mm=measurement.toe_height_mm,
            length_mm=measurement.length_mm,
            cycle_time_ms=cycle_time_ms,
            glue_points=out.points,
            path=PathInfo(out.normals, out.frame, out.nozzle_offset_mm, recipe.glue_offset_mm),
            inspection=None if failed is None else Inspection(failed),
        )

    def _tell_listeners(self, record: CycleRecord, recipe: Recipe | None) -> None:
        if not self.listeners:
            return
        outcome = outcome_of(self.config.opcua.cell_name, record, recipe)
        for listener in self.listeners:
            try:
                listener(outcome)
            except Exception:  # a listener's fault never stops the line
                log.exception("cycle %d: result listener %r failed", record.cycle, listener)

    def _abort(self, trigger: Trigger) -> None:
        reason = "the service is stopping"
        cycle_time_ms = (time.monotonic() - trigger.received_at) * 1000.0
        triggered_at = time.time() - (time.monotonic() - trigger.received_at)
        assert self._journal is not None
        code = ErrorCode.CYCLE_ABORTED
        record = journal_record(
            trigger.cycle, triggered_at, code, reason, cycle_time_ms, {}, None, None, trigger.recipe
        )
        self._journal.record(record)
        self.link.publish_error(trigger.cycle, ErrorCode.CYCLE_ABORTED, cycle_time_ms=cycle_time_ms)
        self._tell_listeners(record, self.recipes.get(trigger.recipe))
        self.events.publish(CycleDone(record, None, None))
        log.warning("cycle %d: aborted, %s", trigger.cycle, reason)

    # ---- health --------------------------------------------------------------------------------

    def _probe_cameras(self, force: bool = False) -> None:
        """Open the cameras if they are not known to work (at start, and every few s while failing)."""
        now = time.monotonic()
        if self._cameras_ok or (not force and now - self._last_probe < CAMERA_PROBE_PERIOD_S):
            return
        self._last_probe = now
        try:
            with self.camera_lock:
                self.source.open()
                frame = self.source.grab_pair()
        except CameraError as exc:
            self._camera_log.warning(str(exc), "cameras not ready: %s", exc)
            return
        self._cameras_ok = True
        self._camera_log.reset()
        log.info("cameras ok")
        # At start and after a reconnect: are these the calibrated cameras (a replug may have swapped them)?
        self._identity_problem = identity_problem(self.calib.cameras if self.calib else None, frame.info)
        if self._identity_problem:
            log.error("calibration does not match the cameras: %s", self._identity_problem)
        if not force:
            self._report_health()  # READY at once; the warm-up below only if the start could not do it
            self._publish_state()
            if not self._warmed_up:
                self._warm_up()

    def _report_health(self) -> None:
        calibration_ok = self.calib is not None and self._identity_problem is None
        self.link.set_status(cameras_ok=self._cameras_ok, calibration_ok=calibration_ok)

    def _publish_state(self, phase: str | None = None) -> None:
        if phase is None:
            healthy = self._cameras_ok and self.calib is not None
            phase = "busy" if self._busy_cycle is not None else "ready" if healthy else "error"
        self.events.publish(
            CellState(phase, self._cameras_ok, self.calib is not None, self.cycles_done, self._busy_cycle)
        )

    def _status_text(self) -> str:
        cameras = "cameras ok" if self._cameras_ok else "CAMERAS NOT OK"
        calibration = "calibration ok" if self.calib is not None else "NO CALIBRATION"
        return f"waiting for trigger; {self.cycles_done} cycles; {cameras}; {calibration}"


def _load_calibration(config: CellConfig) -> tuple[Calibration | None, str | None]:
    try:
        return Calibration.load(config.calibration.path), None
    except (OSError, ValueError) as exc:
        log.error("calibration %s not usable: %s", config.calibration.path, exc)
        return None, str(exc)


def _load_taught(config: CellConfig, calib: Calibration) -> TaughtTable | None:
    """The table taught beside the calibration (`cellctl teach`), None if none or unusable (logged)."""
    try:
        taught = load_taught(config.calibration.path, calib)
    except TeachError as exc:
        log.error("taught table not used: %s", exc)
        return None
    log.info("taught table %s", "loaded" if taught is not None else "absent: measuring without (cellctl teach)")
    return taught


def _inspect(recipe: Recipe | None, measurement: SoleMeasurement | None) -> FeatureBit | None:
    """Features of a measured sole outside the recipe's tolerances; None when the recipe checks nothing."""
    if recipe is None or measurement is None or not recipe.checks_tolerances:
        return None
    return recipe.inspect(measurement.length_mm, measurement.heel_height_mm, measurement.toe_height_mm)
