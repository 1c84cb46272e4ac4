"""The station's parts without a running service: operator texts, config tables, image log retention,
metrics from events, history filter and trend plots."""

from __future__ import annotations

import dataclasses
import re
import socket
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from prometheus_client.parser import text_string_to_metric_families
from starlette.applications import Starlette

from cellctl.cameras.base import CameraError, StereoFrame
from cellctl.cameras.replay import ReplayCameras
from cellctl.service.config import CellConfig, ConfigError, ImageLogConfig
from cellctl.service.events import CellState, CycleDone
from cellctl.service.imagelog import ImageLog
from cellctl.service.journal import CycleRecord
from cellctl.service.metrics import CellMetrics
from cellctl.service.operator_text import OPERATOR_TEXT, describe_code
from cellctl.service.png_bands import BAND_ROWS, write_png_in_bands
from cellctl.service.station.history import HistoryFilter, trend_svg
from cellctl.service.station.live import LiveView, Preview, measured_region
from cellctl.service.station.server import WebServer
from firmware_io.registers import ErrorCode
from tests.sim_rig import half_size_rig

DOCS = Path(__file__).resolve().parents[2] / "docs"
DEPLOY = Path(__file__).resolve().parents[2] / "deploy"


def test_operator_texts_are_the_table_of_docs_modbus() -> None:
    rows = re.findall(r"^\| (\d+) \| `(\w+)` \| ([^|]+) \| ([^|]+) \|$", (DOCS / "modbus.md").read_text(), re.M)
    documented = {ErrorCode(int(code)): (meaning.strip(), action.strip()) for code, name, meaning, action in rows}
    assert documented == OPERATOR_TEXT
    assert set(OPERATOR_TEXT) == set(ErrorCode)
    assert describe_code(31)[0] == "SOLE_AT_BORDER" and "marked area" in describe_code(31)[2]
    assert describe_code(77)[0] == "77"  # an unknown code still gets words


def config_text(extra: str) -> str:
    return f'[cameras]\nbackend = "simulated"\n[calibration]\npath = "{DEPLOY / "sim-calib.yaml"}"\n[journal]\nstate_dir = "/tmp/x"\n{extra}'


def test_station_and_image_log_tables_default_and_read(tmp_path: Path) -> None:
    path = tmp_path / "cell.toml"
    path.write_text(config_text(""))
    config = CellConfig.load(path)
    assert (config.station.bind, config.station.port, config.station.token) == ("127.0.0.1", 8080, None)
    assert config.image_log == ImageLogConfig()
    path.write_text(
        config_text(
            '[station]\nbind = "0.0.0.0"\nport = 9000\ntoken = "long-enough"\n[image_log]\nevery_nth_good = 5\n'
        )
    )
    config = CellConfig.load(path)
    assert (config.station.bind, config.station.port, config.image_log.every_nth_good) == ("0.0.0.0", 9000, 5)


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        ('[station]\ntoken = "short"\n', "token: too short"),
        ('[station]\nboard = "9 by 6"\n', "COLSxROWS"),
        ("[station]\nport = 70000\n", "port"),
        ("[image_log]\nkeep = 3\n", "unknown key"),
        ("[image_log]\nmax_mb = -1\n", "max_mb"),
    ],
)
def test_bad_station_settings_are_named(tmp_path: Path, extra: str, words: str) -> None:
    path = tmp_path / "cell.toml"
    path.write_text(config_text(extra))
    with pytest.raises(ConfigError, match=words):
        CellConfig.load(path)


def record(row_id: int, ok: bool) -> CycleRecord:
    return CycleRecord(
        cycle=row_id,
        triggered_at=1.7e9 + row_id,
        status="ok" if ok else "error",
        error_code=0 if ok else 30,
        cycle_time_ms=800.0 + row_id,
        reason=None if ok else "no sole in view",
        length_mm=250.0 if ok else None,
        id=row_id,
    )


def frame(value: int, averaged: bool = False) -> StereoFrame:
    """A pair; `averaged`: with the mean of the cycle's exposures beside it (its images' halves)."""
    rng = np.random.default_rng(value)
    left = rng.integers(0, 255, (64, 80, 3), dtype=np.uint8)
    right = left[:, ::-1].copy()
    return StereoFrame(left, right, 0.0, 0.0, averaged=(left // 2, right // 2) if averaged else None)


def test_image_log_keeps_failures_and_every_nth_good_and_replays(tmp_path: Path) -> None:
    log = ImageLog(tmp_path / "images", None, ImageLogConfig(every_nth_good=2, keep_cycles=100, max_mb=100))
    for i, ok in enumerate([True, False, True, True, True], start=1):
        log.on_event(CycleDone(record(i, ok), frame(i, averaged=i == 3), None))
    assert log.wait_written()
    assert [e.row_id for e in log.entries()] == [2, 3, 5]  # the failure, and the 2nd and 4th good cycles
    assert log.find(2) is not None and log.find(2).meta()["reason"] == "no sole in view"  # type: ignore[union-attr]
    replay = ReplayCameras(tmp_path / "images")
    first, second = replay.grab_pair(), replay.grab_pair()
    assert np.array_equal(first.left, frame(2).left) and np.array_equal(first.right, frame(2).right)
    assert first.averaged is None and second.averaged is not None  # cycle 3 averaged its exposures
    for logged, made in zip(second.averaged, frame(3, averaged=True).averaged or (), strict=True):
        assert np.array_equal(logged, made)
    log.on_event(CycleDone(record(6, False), None, None))  # no frame (camera error): nothing to log
    assert log.wait_written()
    assert [e.row_id for e in log.entries()] == [2, 3, 5]


def test_image_log_retention_by_count_and_by_disk(tmp_path: Path) -> None:
    log = ImageLog(tmp_path / "images", None, ImageLogConfig(keep_cycles=3, max_mb=100))
    for i in range(1, 7):
        log.on_event(CycleDone(record(i, False), frame(i, averaged=True), None))
    assert log.wait_written()
    assert [e.row_id for e in log.entries()] == [4, 5, 6]
    assert len(list((tmp_path / "images").iterdir())) == 3 * 6  # pair, mean pair, overlay, meta: the pruned all gone
    one_entry = sum(p.stat().st_size for p in (tmp_path / "images").iterdir()) / 3
    log.config = ImageLogConfig(keep_cycles=100, max_mb=1.5 * one_entry / 1e6)
    assert log.prune() == 2
    assert [e.row_id for e in log.entries()] == [6]


def test_metrics_count_cycles_by_result_and_camera_reconnects(tmp_path: Path) -> None:
    (tmp_path / "file").write_bytes(b"x" * 1000)
    metrics = CellMetrics(None, tmp_path)
    for event in (
        CellState("ready", True, True),
        CycleDone(record(1, True), None, None),
        CycleDone(record(2, False), None, None),
        CycleDone(dataclasses.replace(record(3, True), timings={"match": 0.2, "retry": 1.1}), None, None),
        CellState("error", False, True),
        CellState("ready", True, True),
    ):
        metrics.on_event(event)
    samples = {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for family in text_string_to_metric_families(metrics.exposition().decode())
        for s in family.samples
    }
    assert samples[("cellctl_cycles_total", (("code", "NONE"), ("result", "ok")))] == 2
    assert samples[("cellctl_cycles_measured_again_total", (("result", "ok"),))] == 1  # cycle 3 only
    assert samples[("cellctl_cycles_total", (("code", "NO_SOLE"), ("result", "error")))] == 1
    assert samples[("cellctl_camera_reconnects_total", ())] == 1
    assert samples[("cellctl_cycle_time_seconds_count", ())] == 3
    assert samples[("cellctl_state_dir_bytes", ())] >= 1000


def test_history_filter_and_trend() -> None:
    records = [record(i, i % 3 != 0) for i in range(1, 10)]
    assert [r.id for r in HistoryFilter.from_query({"status": "error"}).apply(records)] == [3, 6, 9]
    assert [r.id for r in HistoryFilter.from_query({"last": "2"}).apply(records)] == [8, 9]
    assert HistoryFilter.from_query({"status": "drop table", "last": "x"}) == HistoryFilter()
    svg = trend_svg([r.length_mm for r in records], "Length", "mm")
    assert svg.startswith("<svg") and svg.count('class="fail"') == 3 and "<polyline" in svg
    assert "no data yet" in trend_svg([None, None], "Heel", "mm")


class CountingSource:
    """A FrameSource that counts grabs."""

    def __init__(self) -> None:
        self.grabs = 0

    def open(self) -> None:
        pass

    def grab_pair(self) -> StereoFrame:
        self.grabs += 1
        return frame(self.grabs)

    def close(self) -> None:
        pass


def test_live_view_never_grabs_during_a_cycle() -> None:
    source, lock = CountingSource(), threading.Lock()
    state = {"now": CellState("busy", True, True, cycle=7)}
    live = LiveView(source, lock, lambda: state["now"], None, (450.0, 650.0))
    assert live.preview().note.startswith("paused: cycle 7") and source.grabs == 0
    with pytest.raises(CameraError, match="measuring cycle 7"):
        live.grab_idle()
    state["now"] = CellState("ready", True, True)
    with lock:  # the daemon is grabbing: the preview does not wait for it
        live._last = Preview(None, "", 0.0)
        assert live.preview().note.startswith("paused") and source.grabs == 0
    live._last = Preview(None, "", 0.0)
    shown = live.preview()
    assert shown.note == "" and shown.frame is not None and source.grabs == 1
    assert live.panel_jpeg("left")[:2] == b"\xff\xd8"  # a JPEG, from the cached preview
    assert source.grabs == 1


def test_measured_region_lies_in_the_image_and_shrinks_by_the_disparity() -> None:
    rig = half_size_rig()
    width, height = rig.image_size
    for side in ("left", "right"):
        region = measured_region(rig, (450.0, 650.0), side)
        assert region[:, 0].min() > -5 and region[:, 0].max() < width + 5
        assert region[:, 1].min() > -5 and region[:, 1].max() < height + 5
        span = region[:, 0].max() - region[:, 0].min()
        assert span < width - 0.5 * rig.focal_px * rig.baseline_mm / 450.0  # the unmatched strip is left out


def test_the_web_server_names_a_busy_port() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        server = WebServer(Starlette(), "127.0.0.1", busy.getsockname()[1])
        with pytest.raises(ValueError, match=r"cannot listen on 127\.0\.0\.1.*\[station\]"):
            server.start()


def test_image_log_writes_between_cycles_only(tmp_path: Path) -> None:
    """The image log's writer starts no step while the daemon measures (its CellState is busy): three PNGs
    beside a cycle took ~0.3 s off it on 2 cores."""
    log = ImageLog(tmp_path / "images", None, ImageLogConfig(every_nth_good=1))
    log.on_event(CellState(phase="busy", cycle=7))
    waited = threading.Event()
    writer = threading.Thread(target=lambda: (log._wait_between_cycles(), waited.set()))
    writer.start()
    assert not waited.wait(0.3)  # held back while the cycle runs
    log.on_event(CellState(phase="ready"))
    assert waited.wait(5.0)
    writer.join()


def test_the_image_logs_writer_sets_up_its_text_when_the_log_is_made_not_at_its_first_picture(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """OpenCV sets up its fonts per thread at the first cv2.putText (~22 ms): the writer's thread does that while
    the service starts, not in its first overlay, which it draws between cycles; the log is returned only once
    that is done. No writer without a log."""
    writers: list[str] = []

    def slow_put_text(*args: object, **kwargs: object) -> None:
        time.sleep(0.2)  # a set-up that takes a while: the log must not be returned before it is done
        writers.append(threading.current_thread().name)

    monkeypatch.setattr(cv2, "putText", slow_put_text)
    ImageLog(tmp_path / "none", None, ImageLogConfig(keep_cycles=0))
    assert writers == []
    ImageLog(tmp_path / "images", None, ImageLogConfig())
    assert writers == ["image-log"]


@pytest.mark.parametrize("shape", [(70, 50), (130, 40, 3), (64, 9, 4), (1, 1)])
def test_png_in_bands_reads_back_the_same_pixels_and_pauses_before_every_band(tmp_path: Path, shape: tuple) -> None:
    """The image log's PNG writer: any reader gets the pixels back, and it pauses before each band of rows."""
    image = np.random.default_rng(len(shape)).integers(0, 256, shape, dtype=np.uint8)
    pauses: list[int] = []
    write_png_in_bands(tmp_path / "x.png", image, lambda: pauses.append(1))
    assert np.array_equal(cv2.imread(str(tmp_path / "x.png"), cv2.IMREAD_UNCHANGED), image)
    assert len(pauses) == -(-shape[0] // BAND_ROWS)
    with pytest.raises(ValueError, match="8-bit"):
        write_png_in_bands(tmp_path / "y.png", image.astype(np.uint16), lambda: None)


def test_a_png_writers_held_buffers_stay_out_of_mallocs_heap() -> None:
    # Held across cycles, a writer's picture in the heap splits it and glibc grows it under a later cycle.
    import ctypes

    from cellctl.service.png_bands import held_copy

    mallinfo2 = getattr(ctypes.CDLL(None), "mallinfo2", None)
    if mallinfo2 is None:
        pytest.skip("not glibc 2.33+: no mallinfo2 to see the heap")

    class MallInfo2(ctypes.Structure):
        _fields_ = [
            (name, ctypes.c_size_t)
            for name in (
                "arena",
                "ordblks",
                "smblks",
                "hblks",
                "hblkhd",
                "usmblks",
                "fsmblks",
                "uordblks",
                "fordblks",
                "keepcost",
            )
        ]

    mallinfo2.restype = MallInfo2
    picture = np.full((1024, 1280, 3), 7, np.uint8)
    before = mallinfo2()
    held = held_copy(picture)
    after = mallinfo2()
    assert np.array_equal(held, picture)
    # malloc hands out none of the 3.9 MB: neither from its heap (uordblks) nor as a mapping of its own (hblkhd).
    assert (after.uordblks + after.hblkhd) - (before.uordblks + before.hblkhd) < 1 << 20


def test_the_image_logs_overlay_waits_between_its_parts_while_a_cycle_runs(monkeypatch: pytest.MonkeyPatch) -> None:
    """The overlay's two drawings (left image, top view) each start only between cycles, like the PNG bands."""
    import types

    import cellctl.vision.overlay as overlay

    calls: list[str] = []
    left = np.zeros((200, 80, 3), np.uint8)  # tall enough for the height scale beside it
    monkeypatch.setattr(overlay, "draw_on_left", lambda image, calib, measurement: calls.append("left") or left.copy())
    monkeypatch.setattr(overlay, "_caption", lambda image, measurement: None)
    monkeypatch.setattr(overlay, "_legend", lambda image: None)
    monkeypatch.setattr(overlay, "top_view", lambda rec, measurement: calls.append("top") or left[:, :40].copy())
    log = ImageLog(Path("unused"), object(), ImageLogConfig())  # type: ignore[arg-type]  # the calib is not read
    monkeypatch.setattr(log, "_wait_between_cycles", lambda: calls.append("wait"))
    measured = types.SimpleNamespace(
        reconstruction=types.SimpleNamespace(sole_points=np.array([[0.0, 0.0, 1.0], [1.0, 1.0, 9.0]])), measurement=None
    )
    picture = log._overlay(record(1, True), frame(1), measured)  # type: ignore[arg-type]
    assert calls == ["left", "wait", "top", "wait"]
    assert picture.shape[0] == 200
