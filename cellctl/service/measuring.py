"""The cell's reconstructors: the configured depth range's, and at most one more for a recipe's own range.

Each matcher keeps its cost volume (~0.5 GB at 1280x1024), so a line switching among several depth ranges
re-allocates rather than piling them up. A recipe's reconstructor starts from the table plane the cell's
own one learnt (or the taught table), so it searches only the sole's region from its first cycle instead of
finding the table again. The warm-up does one cycle's work before READY (the table plane learnt when none is
taught, rectification maps built, the matchers' buffers allocated) for the cell's range and each recipe's,
so the first trigger of any recipe costs what every other one does.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable
from dataclasses import replace

from cellctl.cameras import CameraError, FrameSource, StereoFrame
from cellctl.cameras.identity import identity_problem
from cellctl.errors import FailureKind
from cellctl.service.camera_health import CameraHealth
from cellctl.service.codes import CycleFailed
from cellctl.service.config import CellConfig
from cellctl.service.cycle import Measured, MeasureSettings, Refused, measure_frame
from cellctl.service.recipes import Recipe
from cellctl.vision.calibration import Calibration
from cellctl.vision.reconstruction import SoleReconstructor
from cellctl.vision.runtime import keep_freed_memory, one_blas_thread, settle_garbage_collector, warm_heap
from cellctl.vision.teach import TaughtTable, TeachError, load_taught
from firmware_io.handshake import Trigger
from firmware_io.registers import ErrorCode

log = logging.getLogger("cellctl.service.daemon")  # the service's one log, as operators know it

#: A cycle refused for its glue heights' precision measures once more on more exposures only where the cycle so far,
#: taken twice (the retry repeats its measurement), stays within this share of [plc] cycle_timeout_s.
RETRY_TIME_SHARE = 0.8
#: The cycle's timing step of that second measurement (its further grab and its measurement), in the journal.
RETRY_STEP = "retry"


class CellMeasurer:
    """Measures a grabbed pair with the reconstructor of the recipe's depth range."""

    def __init__(self, config: CellConfig) -> None:
        self.config = config
        # numpy's BLAS on one thread: its thread team made single products of a cycle take up to 30 x their
        # time when a core was busy (cellctl.vision.runtime); the same numbers on one thread.
        one_blas_thread()
        keep_freed_memory()  # the memory a cycle frees stays for the next: no page faults (same module)
        self.calib, self.calibration_problem = load_calibration(config)
        self.taught_problem = "no calibration"
        self.reconstructor = None
        if self.calib is not None:
            taught, self.taught_problem = load_taught_table(config, self.calib)
            self.reconstructor = SoleReconstructor(self.calib, config.measure.depth_range_mm, taught=taught)
        self._recipe_reconstructor: SoleReconstructor | None = None
        self.warmed_up = False

    @property
    def setup_problem(self) -> str:
        """Why this cell refuses every cycle for want of its taught table ([measure] require_taught_table), or ""."""
        return self.taught_problem if self.config.measure.require_taught_table else ""

    def warm_up(self, source: FrameSource, recipes: Iterable[Recipe] = ()) -> None:
        """One cycle's work on a grabbed pair (not locked: nothing else grabs before READY), with the cell's
        reconstructor and then with each other depth range the recipes ask for."""
        if self.reconstructor is None:
            return
        start = time.monotonic()
        try:
            frame = source.grab_pair()
        except CameraError as exc:
            log.warning("warm-up skipped, no pair: %s", exc)
            return
        if self.reconstructor.table_plane is None:
            plane = self.reconstructor.learn_table(frame.left, frame.right)
            log.info("table plane %s", "learnt from the warm-up pair" if plane is not None else "NOT found")
        measure = self.config.measure
        settings = self._settings(Recipe.default(measure))  # recipe 0: the cell's own [measure] settings
        result = measure_frame(frame, self.reconstructor, settings)
        outcome = "measured" if isinstance(result, Measured) else f"refused ({result.reason})"
        log.info("warmed up in %.1f s: pair %s", time.monotonic() - start, outcome)
        for depth_range in sorted({r.depth_range_mm for r in recipes} - {measure.depth_range_mm}):
            start = time.monotonic()
            reconstructor = self._reconstructor_for(depth_range)
            measure_frame(frame, reconstructor, settings)
            log.info("warmed up depth range %g..%g mm in %.1f s", *depth_range, time.monotonic() - start)
        warm_heap()  # every thread of the cycles allocates from it (one arena): a larger sole finds its pages mapped
        settle_garbage_collector()
        self.warmed_up = True

    def answer(
        self, trigger: Trigger, recipe: Recipe | None, cameras: CameraHealth, timings: dict[str, float]
    ) -> tuple[StereoFrame | None, tuple[ErrorCode, str | None, Measured | None]]:
        """Grab and measure for a trigger: the frame (None if none was grabbed) and the code, reason and result
        for the PLC; never raises (the PLC always gets an answer)."""
        frame: StereoFrame | None = None
        try:
            if recipe is None:
                raise CycleFailed.of(
                    FailureKind.RECIPE_UNKNOWN, f"recipe {trigger.recipe} selected by the PLC is not loaded"
                )
            exposures = cameras.grab_exposures(timings, not_before=trigger.received_at)
            frame = cameras.averaged(exposures, timings)
            result = self.measure(frame, timings, recipe)
            if more := self._more_exposures(result, len(exposures), trigger):
                again = self._measure_again(exposures, more, cameras, timings, recipe, trigger.cycle)
                frame, result = again or (frame, result)
            if isinstance(result, Refused):
                raise CycleFailed.of(result.failure, result.reason)
            return frame, (ErrorCode.NONE, None, result)
        except CycleFailed as failure:
            return frame, (failure.code, str(failure), None)
        except Exception as exc:  # never leave the PLC without an answer
            log.exception("cycle %d: unexpected failure", trigger.cycle)
            return frame, (ErrorCode.INTERNAL_ERROR, f"internal error: {type(exc).__name__}: {exc}", None)

    def measure(self, frame: StereoFrame, timings: dict[str, float], recipe: Recipe) -> Measured | Refused:
        """The sole in `frame`, measured as `recipe` asks, or why not; CycleFailed where the cell cannot measure
        at all (no calibration, other cameras, no taught table)."""
        if self.calib is None:
            raise CycleFailed.of(FailureKind.CALIBRATION_MISSING, f"no calibration loaded: {self.calibration_problem}")
        if problem := identity_problem(self.calib.cameras, frame.info):
            raise CycleFailed.of(FailureKind.CALIBRATION_MISMATCH, problem)
        if self.setup_problem:
            raise CycleFailed.of(
                FailureKind.TABLE_NOT_TAUGHT,
                f"this cell measures against a taught table: {self.setup_problem}; clear the fixture and teach "
                "the empty table (cellctl teach), then restart the service",
            )
        reconstructor = self.reconstructor
        if recipe.depth_range_mm != self.config.measure.depth_range_mm or reconstructor is None:
            reconstructor = self._reconstructor_for(recipe.depth_range_mm)
        result = measure_frame(frame, reconstructor, self._settings(recipe))
        timings.update(result.timings)
        return result

    def _more_exposures(self, result: Measured | Refused, grabbed: int, trigger: Trigger) -> int:
        """How many more pairs a cycle refused after `grabbed` grabs to measure the sole once more (0: none): where
        its glue heights' precision may pass on more exposures ([cameras] retry_averaged_frames in all), and the
        cycle so far, taken twice, leaves RETRY_TIME_SHARE of cycle_timeout_s (a retry must not turn a refusal
        into a CYCLE_TIMEOUT the PLC cannot tell from a hung cell)."""
        wanted = self.config.cameras.retry_averaged_frames
        if not isinstance(result, Refused) or result.more_exposures is None or wanted <= grabbed:
            return 0
        taken = time.monotonic() - trigger.received_at
        timeout = self.config.plc.cycle_timeout_s
        if 2.0 * taken > RETRY_TIME_SHARE * timeout:
            log.info(
                "cycle %d: not measured again on %d exposures: the cycle has taken %.1f s of cycle_timeout_s = %g s",
                trigger.cycle,
                wanted,
                taken,
                timeout,
            )
            return 0
        return wanted - grabbed

    def _measure_again(
        self,
        exposures: list[StereoFrame],
        more: int,
        cameras: CameraHealth,
        timings: dict[str, float],
        recipe: Recipe,
        cycle: int,
    ) -> tuple[StereoFrame, Measured | Refused] | None:
        """The sole measured once more on `exposures` and up to `more` further pairs of it, averaged together (the
        mean leaves out any that moved); timed as RETRY_STEP. A refusal on them says it was measured again. None where
        the cameras have no further pairs of it (stored pairs)."""
        start = time.perf_counter()
        further = cameras.grab_further(more, timings)
        if not further:
            return None
        frame = cameras.averaged(exposures + further, timings)
        count = frame.info.get("averaged_frames", 1)
        log.info(
            "cycle %d: glue heights too coarse on %d exposures; measuring again on %d", cycle, len(exposures), count
        )
        result = self.measure(frame, timings, recipe)
        timings[RETRY_STEP] = time.perf_counter() - start
        if isinstance(result, Refused):
            result = replace(result, reason=f"{result.reason} (measured again on the mean of {count} exposures)")
        return frame, result

    def _settings(self, recipe: Recipe) -> MeasureSettings:
        """What a cycle measuring for `recipe` needs: its glue path and wall, the cell's glue height tolerance."""
        tolerance = self.config.measure.glue_height_tolerance_mm  # the cell's dispenser, not the sole model's
        return MeasureSettings(recipe.glue_offset_mm, recipe.glue_spacing_mm, tolerance, recipe.wall_draft_deg)

    def _reconstructor_for(self, depth_range_mm: tuple[float, float]) -> SoleReconstructor:
        """The reconstructor of a recipe's own depth range (the matcher's disparity range follows from it),
        holding the cell's table plane or taught table."""
        assert self.calib is not None  # measure() and warm_up() refuse first without a calibration
        held = self._recipe_reconstructor
        if held is not None and held.depth_range_mm == depth_range_mm:
            return held
        self._recipe_reconstructor = None  # release the old buffers before allocating new ones
        own = self.reconstructor  # its taught table, or else the plane it learnt (None: found per cycle)
        self._recipe_reconstructor = SoleReconstructor(
            self.calib,
            depth_range_mm,
            table_plane=None if own is None else own.table_plane,
            taught=None if own is None else own.taught,
        )
        return self._recipe_reconstructor


def load_calibration(config: CellConfig) -> tuple[Calibration | None, str | None]:
    """The calibration and None, or None and why it cannot be used (logged)."""
    try:
        return Calibration.load(config.calibration.path), None
    except (OSError, ValueError) as exc:
        log.error("calibration %s not usable: %s", config.calibration.path, exc)
        return None, str(exc)


def load_taught_table(config: CellConfig, calib: Calibration) -> tuple[TaughtTable | None, str]:
    """The table taught beside the calibration (`cellctl teach`), or None and why not ("" when loaded; logged)."""
    try:
        taught = load_taught(config.calibration.path, calib)
    except TeachError as exc:
        log.error("taught table not used: %s", exc)
        return None, f"the taught table is not usable ({exc})"
    if taught is None:
        if config.measure.require_taught_table:
            log.warning("taught table absent: every cycle refused until the empty table is taught (cellctl teach)")
        else:
            log.info("taught table absent: measuring without (cellctl teach)")
        return None, "no table has been taught beside the calibration"
    log.info("taught table loaded")
    return taught, ""
