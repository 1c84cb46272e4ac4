"""Accuracy and time of the sole measurement on simulated soles of known geometry (Table 4 of the paper).

Each sole is rendered (not timed), then reconstructed and measured exactly as `cellctl measure` does
(timed: rectify, match, segment, measure). Errors are measured minus true, in mm. The glue path is
checked in the simulator's frame: how far inside the true outline it runs (nominal 2 mm), how far its
points are from the true top surface, and the angle of its normals to the true ones.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import cv2
import numpy as np

from cellctl.cameras.averaging import average_frames
from cellctl.cameras.base import StereoFrame
from cellctl.cameras.config import AVERAGED_FRAMES
from cellctl.sim.render_cache import RenderCache, exposure_shots, render_exposures
from cellctl.sim.scene import SoleScene
from cellctl.vision.calibration import Calibration
from cellctl.vision.checks import MIN_GLUE_NZ
from cellctl.vision.closed_path import outward_normals
from cellctl.vision.defaults import GLUE_OFFSET_MM, MORE_EXPOSURES
from cellctl.vision.edge_checks import LOW_WALL_QUANTILE, WALL_HEIGHT_INSET_MM
from cellctl.vision.image_noise import exposure_noise_dn
from cellctl.vision.measurement import MeasurementRefused, MeasurementResult, SoleMeasurement, measure_sole
from cellctl.vision.reconstruction import DEFAULT_DEPTH_RANGE_MM, SoleReconstructor
from cellctl.vision.teach import NoisyTeachError, TeachError, average_exposures

CRASHED = "measurement raised"  # reason and failure of a sole whose measurement raised an exception


@dataclass
class SoleBenchRow:
    seed: int
    color: str
    length_true_mm: float
    valid: bool
    reason: str | None
    length_error_mm: float | None
    heel_error_mm: float | None
    toe_error_mm: float | None
    glue_inset_error_max_mm: float | None  # |distance inside the true outline - nominal offset|, max over the path
    glue_height_error_max_mm: float | None
    glue_normal_error_max_deg: float | None
    seconds: float
    variations: str = "plain"  # matrix variations of the scene, "+"-joined (cellctl.sim.look)
    failure: str | None = None  # FailureKind value of a refusal
    half_area_difference_true: float | None = None  # the truth's (toe half - heel half) / area
    # Share of the true glue line (GLUE_OFFSET_MM inside the true outline) on a surface steeper than the glue
    # contract allows (checks.MIN_GLUE_NZ: 60 degrees from vertical), e.g. a sloped side wall: no valid result
    # can hold the true glue path there.
    glue_line_steep_true: float | None = None
    # A refusal's outline (where the measurement got that far): its farthest point from the true outline, mm.
    # Says whether an "outline inconsistent" refusal's claim is true, whatever the variations say.
    outline_error_max_mm: float | None = None
    # The sole's true wall height where it stands highest (the true top 6 mm inside the true outline, its 90th
    # percentile, as edge_checks.check_wall_height reads the measured one): below the check's limit the cell
    # cannot confirm the outline as the foot, and a `wall_too_low` refusal is the right answer.
    wall_height_true_mm: float | None = None
    # Where a refusal on the bench's --frames exposures named more that may pass and the bench measured once more
    # on this many, as the cycle does ([cameras] retry_averaged_frames): the row is that second measurement's.
    retried_on: int | None = None


def bench_soles(
    calib: Calibration,
    soles: list[tuple[int, str]],
    progress: Callable[[str], None] | None = None,
    taught: bool = False,
    cache: RenderCache | None = None,
    frames: int = AVERAGED_FRAMES,
    retry_frames: int = MORE_EXPOSURES,
) -> list[SoleBenchRow]:
    """Measure each (seed, colour) plain sole once and compare with its truth.

    taught: teach each scene's empty table first (not timed), as a cell does once at set-up
    (cellctl.vision.teach); else measure without a taught table. cache: renders kept on disk. frames, retry_frames:
    exposures averaged per measurement, and in all where it may pass on more (`measure_scene`).
    """
    reconstructor = SoleReconstructor(calib)
    rows = []
    for seed, color in soles:
        scene = SoleScene.random(seed, color, calib)
        chosen = taught_reconstructor(calib, scene, cache) if taught else reconstructor
        label = "plain" + fallback_note(taught, chosen)
        rows.append(measure_scene(chosen, scene, label, cache, frames=frames, retry_frames=retry_frames))
        if progress:
            progress(_row_text(rows[-1]))
    return rows


def fallback_note(taught: bool, reconstructor: SoleReconstructor) -> str:
    """ "+untaught" for a row asked to be taught whose table could not be (`taught_reconstructor`): the result is
    the untaught cell's, and a reader of the table must see that."""
    return "+untaught" if taught and reconstructor.taught is None else ""


def retried_note(rows: list[SoleBenchRow]) -> str:
    """A sentence for a report whose rows include soles measured once more on more exposures (`measure_scene`)."""
    retried = [r for r in rows if r.retried_on is not None]
    if not retried:
        return ""
    measured = sum(r.valid for r in retried)
    seeds = ", ".join(str(r.seed) for r in retried)
    return (
        f" {len(retried)} of them refused for their glue heights' precision and measured again on "
        f"{retried[0].retried_on} exposures, {measured} valid then: {seeds}."
    )


def untaught_note(rows: list[SoleBenchRow]) -> str:
    """A sentence for a report whose rows include soles measured untaught although asked taught (`fallback_note`)."""
    fallen = [str(r.seed) for r in rows if r.variations.endswith("+untaught")]
    if not fallen:
        return ""
    return f" {len(fallen)} of them measured untaught, their empty table not taught: {', '.join(fallen)}."


TEACH_SHOTS = 4  # exposures of the empty table averaged for teaching, as `cellctl teach` takes several pairs
# When a noisy table cannot be taught, the refusal asks for more pairs (NoisyTeachError); the bench follows it once.
NOISY_TEACH_SHOTS = 4 * TEACH_SHOTS


def empty_table_pair(
    scene: SoleScene, cache: RenderCache | None = None, shots: int = TEACH_SHOTS
) -> tuple[np.ndarray, np.ndarray, float]:
    """`shots` exposures of the scene's empty table, averaged per camera, and what the averaging removed from the
    last left one (`exposure_noise_dn`): what `cellctl teach` gets and reads."""
    numbers = list(range(1, shots + 1))
    pairs = cache.render_empties(scene, numbers) if cache else scene.render_empties(numbers)
    left = average_exposures([s.left for s in pairs])
    return left, average_exposures([s.right for s in pairs]), exposure_noise_dn(pairs[-1].left, left)


def taught_reconstructor(
    calib: Calibration,
    scene: SoleScene,
    cache: RenderCache | None = None,
    depth_range_mm: tuple[float, float] = DEFAULT_DEPTH_RANGE_MM,
) -> SoleReconstructor:
    """A reconstructor with the scene's empty table taught from its own exposures (new sensor noise): TEACH_SHOTS
    of them, NOISY_TEACH_SHOTS where the refusal says the images are too noisy to teach from fewer.

    If the table cannot be taught all the same, the reconstructor is an untaught one, as the service runs without
    a taught table; the row's variations then say "+untaught" (`fallback_note`).
    """
    for shots in (TEACH_SHOTS, NOISY_TEACH_SHOTS):
        left, right, noise = empty_table_pair(scene, cache, shots)
        try:
            taught = SoleReconstructor(calib, depth_range_mm).teach(left, right, noise)
            return SoleReconstructor(calib, depth_range_mm, taught=taught)
        except NoisyTeachError:
            continue
        except TeachError:
            break
    return SoleReconstructor(calib, depth_range_mm)


def scene_exposures(
    scene: SoleScene, frames: int = AVERAGED_FRAMES, cache: RenderCache | None = None
) -> list[StereoFrame]:
    """`frames` exposures of the scene as a cycle grabs them, the scene's own render (shot 0) last: the exposure the
    outline is found on is the one every run before averaging measured."""
    pairs = cache.render_exposures(scene, frames) if cache else render_exposures(scene, exposure_shots(frames))
    return [StereoFrame(p.left, p.right, 0.0, 0.0) for p in reversed(pairs)]


def scene_frame(scene: SoleScene, frames: int = AVERAGED_FRAMES, cache: RenderCache | None = None) -> StereoFrame:
    """What a cycle of the cell measures: the last of the scene's exposures with the mean of all
    (`scene_exposures`, cellctl.cameras.averaging)."""
    return average_frames(scene_exposures(scene, frames, cache))


def measure_scene(
    reconstructor: SoleReconstructor,
    scene: SoleScene,
    variations: str = "plain",
    cache: RenderCache | None = None,
    declared_wall: bool = False,
    frames: int = AVERAGED_FRAMES,
    retry_frames: int = MORE_EXPOSURES,
) -> SoleBenchRow:
    """Render one scene (not timed) in `frames` exposures averaged as a cycle takes them (`scene_frame`), measure it
    like `cellctl measure` (timed) and compare with its truth; declared_wall: with the sole model's wall stated as a
    recipe would (`declared_draft`). A refusal that names more exposures that may pass is measured once more on
    `retry_frames` of them (the first `frames` among them), as the cycle does (cellctl.service.measuring); the
    time is both measurements'."""
    assert scene.sole is not None
    draft = declared_draft(scene) if declared_wall else None
    result, seconds = _measure_pair(reconstructor, scene_frame(scene, frames, cache), draft)
    retried_on = None
    if isinstance(result, MeasurementRefused) and result.more_exposures is not None and retry_frames > frames:
        result, again = _measure_pair(reconstructor, scene_frame(scene, retry_frames, cache), draft)
        seconds, retried_on = seconds + again, retry_frames
    reason, failure = (
        (result, CRASHED)
        if isinstance(result, str)
        else (result.reason, result.failure.value)
        if isinstance(result, MeasurementRefused)
        else (None, None)
    )
    truth = scene.sole.truth()
    row = SoleBenchRow(
        scene.seed,
        scene.color,
        truth.length_mm,
        isinstance(result, SoleMeasurement),
        reason,
        None,
        None,
        None,
        None,
        None,
        None,
        seconds,
        variations,
        failure,
        truth.half_area_difference,
        glue_line_steep(scene),
        wall_height_true_mm=wall_height_true(scene),
        retried_on=retried_on,
    )
    if isinstance(result, SoleMeasurement):
        row.length_error_mm = result.length_mm - truth.length_mm
        row.heel_error_mm = result.heel_height_mm - truth.heel_height_mm
        row.toe_error_mm = result.toe_height_mm - truth.toe_height_mm
        transform = scene.table_from_measured(result.camera_to_table)
        points = result.glue_path.points @ transform[:3, :3].T + transform[:3, 3]
        normals = result.glue_path.normals @ transform[:3, :3].T
        inset, height, normal = glue_truth(scene, points[:, :2])
        row.glue_inset_error_max_mm = float(np.abs(inset - GLUE_OFFSET_MM).max())
        row.glue_height_error_max_mm = float(np.abs(points[:, 2] - height).max())
        cosines = np.clip(np.sum(normals * normal, axis=1), -1.0, 1.0)
        row.glue_normal_error_max_deg = float(np.degrees(np.arccos(cosines)).max())
    elif isinstance(result, MeasurementRefused):
        row.outline_error_max_mm = outline_error(scene, result)
    return row


def _measure_pair(
    reconstructor: SoleReconstructor, pair: StereoFrame, draft: float | None
) -> tuple[MeasurementResult | str, float]:
    """The measurement of one averaged pair, or the words of the exception it raised, and its time (s)."""
    start = time.perf_counter()
    result: MeasurementResult | str
    try:
        reconstruction = reconstructor.reconstruct(
            pair.left, pair.right, pair.averaged, pair.info.get("averaged_frames")
        )
        result = measure_sole(reconstruction, wall_draft_deg=draft)
    except Exception as exc:  # noqa: BLE001 - a crash is a finding of the benchmark, not the end of the run
        result = f"{CRASHED}: {type(exc).__name__}: {exc}"
    return result, time.perf_counter() - start


def declared_draft(scene: SoleScene) -> float | None:
    """The sole model's wall as its recipe would state it (measure_sole's wall_draft_deg): 0 for a vertical wall,
    its draft for a wall leaning from the table; None (unknown) for a lean that starts above a vertical foot, which
    a draft does not describe."""
    slope, foot = scene.look.wall_slope_deg, scene.look.wall_foot_mm
    if slope == 0.0:
        return 0.0
    return slope if foot == 0.0 else None


def outline_error(scene: SoleScene, refused: MeasurementRefused) -> float | None:
    """The refused result's outline: its farthest point from the true footprint outline (mm), or None."""
    assert scene.sole is not None
    if refused.outline is None or refused.camera_to_table is None or len(refused.outline) == 0:
        return None
    transform = scene.table_from_measured(refused.camera_to_table)
    xy = np.asarray(refused.outline, dtype=np.float64) @ transform[:2, :2].T + transform[:2, 3]
    truth = scene.sole.footprint_table().astype(np.float32).reshape(-1, 1, 2)
    return float(max(abs(cv2.pointPolygonTest(truth, (float(x), float(y)), True)) for x, y in xy))


def glue_truth(scene: SoleScene, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """At table points: distance inside the true footprint outline, true top height and true surface normal."""
    assert scene.sole is not None
    outline = scene.sole.footprint_table().astype(np.float32).reshape(-1, 1, 2)
    inset = np.array([cv2.pointPolygonTest(outline, (float(x), float(y)), True) for x, y in xy])
    return inset, scene.sole.top_height_at(xy), scene.sole.top_normal_at(xy)


GLUE_LINE_TRUTH_STEP_MM = 0.5  # spacing of the true glue line's samples


def glue_line_steep(scene: SoleScene) -> float:
    """Share of the true glue line (GLUE_OFFSET_MM inside the true outline) whose true surface normal is more
    than the glue contract allows from vertical (checks.MIN_GLUE_NZ): from the model, not the measuring code."""
    assert scene.sole is not None
    line = true_inset_line(scene, GLUE_OFFSET_MM)
    if not len(line):
        return 0.0
    return float(np.mean(scene.sole.top_normal_at(line)[:, 2] < MIN_GLUE_NZ))


def wall_height_true(scene: SoleScene) -> float:
    """The true top WALL_HEIGHT_INSET_MM inside the true outline, its LOW_WALL_QUANTILE (mm above the table): the
    wall height edge_checks.check_wall_height reads on the measured top."""
    assert scene.sole is not None
    line = true_inset_line(scene, WALL_HEIGHT_INSET_MM)
    return float(np.quantile(scene.sole.top_height_at(line), LOW_WALL_QUANTILE)) if len(line) else 0.0


def true_inset_line(scene: SoleScene, offset_mm: float) -> np.ndarray:
    """Points `offset_mm` inside the true outline, GLUE_LINE_TRUTH_STEP_MM apart: the outline's points moved
    along the inward normal; those that do not land `offset_mm` inside (where the offset crosses itself at a
    pointed end) are left out."""
    assert scene.sole is not None
    outline = scene.sole.footprint_table().astype(np.float64)
    step = np.linalg.norm(np.diff(outline, axis=0), axis=1).mean()
    outline = outline[:: max(1, int(round(GLUE_LINE_TRUTH_STEP_MM / step)))]
    line = outline - offset_mm * outward_normals(outline)
    polygon = outline.astype(np.float32).reshape(-1, 1, 2)
    inset = np.array([cv2.pointPolygonTest(polygon, (float(x), float(y)), True) for x, y in line])
    return line[np.abs(inset - offset_mm) < 0.1 * offset_mm]


def _row_text(row: SoleBenchRow) -> str:
    if not row.valid:
        return f"sole {row.seed} {row.color} {row.variations}: NOT MEASURED: {row.reason}"
    return (
        f"sole {row.seed} {row.color} {row.variations}: length {row.length_error_mm:+.2f}, heel {row.heel_error_mm:+.2f}, "
        f"toe {row.toe_error_mm:+.2f} mm, {row.seconds:.2f} s"
    )


def summary(rows: list[SoleBenchRow]) -> dict[str, dict[str, float]]:
    """Mean |error|, max |error| (and mean signed error) per quantity over the measured soles."""
    measured = [r for r in rows if r.valid]
    out: dict[str, dict[str, float]] = {}
    for name in (
        "length_error_mm",
        "heel_error_mm",
        "toe_error_mm",
        "glue_inset_error_max_mm",
        "glue_height_error_max_mm",
        "glue_normal_error_max_deg",
    ):
        values = np.array([getattr(r, name) for r in measured], dtype=np.float64)
        if values.size:
            out[name] = {
                "mean_abs": float(np.abs(values).mean()),
                "max_abs": float(np.abs(values).max()),
                "mean": float(values.mean()),
            }
    times = np.array([r.seconds for r in rows])
    out["seconds"] = {"mean": float(times.mean()), "max": float(times.max()), "min": float(times.min())}
    return out


def to_markdown(rows: list[SoleBenchRow], command: str) -> str:
    stats = summary(rows)
    measured = sum(r.valid for r in rows)
    lines = [
        f"{measured} of {len(rows)} simulated soles measured "
        f"({sum(r.color == 'white' for r in rows)} white, {sum(r.color == 'black' for r in rows)} black). Command: `{command}`"
        + untaught_note(rows)
        + retried_note(rows),
        "",
        "| Error (measured - true) | mean abs | max abs | mean (signed) |",
        "| :-- | --: | --: | --: |",
    ]
    labels = {
        "length_error_mm": "length_mm (toe-heel distance), mm",
        "heel_error_mm": "heel_height_mm, mm",
        "toe_error_mm": "toe_height_mm, mm",
        "glue_inset_error_max_mm": "glue path inset (2 mm nominal), worst point per sole, mm",
        "glue_height_error_max_mm": "glue path height, worst point per sole, mm",
        "glue_normal_error_max_deg": "glue path normal, worst point per sole, degrees",
    }
    for key, label in labels.items():
        if key in stats:
            s = stats[key]
            lines.append(f"| {label} | {s['mean_abs']:.2f} | {s['max_abs']:.2f} | {s['mean']:+.2f} |")
    t = stats["seconds"]
    lines += [
        "",
        f"Time per measurement (rectify, match, segment, measure; 1280x1024): mean {t['mean']:.2f} s, "
        f"min {t['min']:.2f} s, max {t['max']:.2f} s.",
        "",
        "| sole | colour | true length | length err | heel err | toe err | glue inset | glue z | glue normal | time |",
        "| --: | :-- | --: | --: | --: | --: | --: | --: | --: | --: |",
    ]
    for r in rows:
        if r.valid:
            lines.append(
                f"| {r.seed} | {r.color} | {r.length_true_mm:.1f} | {r.length_error_mm:+.2f} | {r.heel_error_mm:+.2f} | "
                f"{r.toe_error_mm:+.2f} | {r.glue_inset_error_max_mm:.2f} | {r.glue_height_error_max_mm:.2f} | "
                f"{r.glue_normal_error_max_deg:.1f} | {r.seconds:.2f} s |"
            )
        else:
            lines.append(
                f"| {r.seed} | {r.color} | {r.length_true_mm:.1f} | not measured: {r.reason} | | | | | | {r.seconds:.2f} s |"
            )
    return "\n".join(lines)


def as_json(rows: list[SoleBenchRow]) -> dict[str, object]:
    return {"soles": [asdict(r) for r in rows], "summary": summary(rows)}
