"""The operator station's web app (Starlette, server-rendered Jinja2 pages, SSE for live updates).

Pages: / (cell), /history, /cycle/{id}, /cameras, /calibration; /metrics for Prometheus. Everything that
only reads is open; actions (POST /api/...) need the [station] token as `Authorization: Bearer TOKEN`.
"""

from __future__ import annotations

import asyncio
import hmac
import json
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, PlainTextResponse, Response, StreamingResponse
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles
from starlette.templating import Jinja2Templates

from cellctl.cameras.base import CameraError
from cellctl.service.imagelog import ImageLog
from cellctl.service.journal import CycleRecord, Journal
from cellctl.service.metrics import CellMetrics
from cellctl.service.operator_text import describe_code
from cellctl.service.station.actions import CameraActions
from cellctl.service.station.calibration_info import calibration_facts
from cellctl.service.station.history import HistoryFilter, to_csv, trends
from cellctl.service.station.hub import StationHub
from cellctl.service.station.live import LiveView
from cellctl.service.timefmt import local_time

HERE = Path(__file__).parent
SSE_POLL_S = 0.25  # how often a live page's stream looks for news; events are rare, the check is cheap
SSE_KEEPALIVE_S = 15.0
HISTORY_SCAN = 5000  # newest journal rows the history page filters; older ones: `cellctl results --csv`


@dataclass
class StationContext:
    """What the pages read: the daemon's shared objects, passed in by start_station()."""

    hub: StationHub
    metrics: CellMetrics
    image_log: ImageLog
    live: LiveView
    actions: CameraActions
    state_dir: Path
    calibration_path: Path
    token: str | None
    plc: Any  # firmware_io PlcLink (connected clients, heartbeat), or None in page tests
    cell_name: str


def create_app(ctx: StationContext) -> Starlette:
    templates = Jinja2Templates(directory=str(HERE / "templates"))
    templates.env.globals.update(local_time=local_time, describe_code=describe_code)

    def page(request: Request, name: str, **values: Any) -> Response:
        return templates.TemplateResponse(request, name, {"ctx": ctx, "cell": _cell_view(ctx), **values})

    async def cell(request: Request) -> Response:
        return page(request, "cell.html", active="cell")

    async def last_fragment(request: Request) -> Response:
        return page(request, "_last.html")

    async def state(request: Request) -> Response:
        return JSONResponse(_cell_view(ctx))

    async def events(request: Request) -> Response:
        return StreamingResponse(
            _sse(ctx, request), media_type="text/event-stream", headers={"Cache-Control": "no-store"}
        )

    async def last_overlay(request: Request) -> Response:
        png = await run_in_threadpool(ctx.hub.last_overlay_png)
        return _png(png)

    async def history(request: Request) -> Response:
        wanted = HistoryFilter.from_query(dict(request.query_params))
        records = wanted.apply(await run_in_threadpool(_journal_rows, ctx.state_dir))
        logged = {e.row_id for e in ctx.image_log.entries()}
        return page(
            request, "history.html", active="history", records=list(reversed(records)), wanted=wanted,
            trends=trends(records), logged=logged,
        )  # fmt: skip

    async def history_csv(request: Request) -> Response:
        wanted = HistoryFilter.from_query(dict(request.query_params))
        records = wanted.apply(await run_in_threadpool(_journal_rows, ctx.state_dir))
        headers = {"Content-Disposition": 'attachment; filename="cellctl-history.csv"'}
        return PlainTextResponse(to_csv(records), media_type="text/csv", headers=headers)

    async def cycle(request: Request) -> Response:
        row_id = int(request.path_params["row_id"])
        record = await run_in_threadpool(_journal_row, ctx.state_dir, row_id)
        if record is None:
            return PlainTextResponse(f"no journaled cycle with id {row_id}", status_code=404)
        entry = ctx.image_log.find(row_id)
        return page(request, "cycle.html", active="history", r=record, entry=entry, meta=entry.meta() if entry else {})

    async def cycle_picture(request: Request) -> Response:
        row_id, kind = int(request.path_params["row_id"]), request.path_params["kind"]
        if kind == "artifact":
            record = await run_in_threadpool(_journal_row, ctx.state_dir, row_id)
            path = None if record is None or record.overlay_path is None else Path(record.overlay_path)
        elif kind in ("left", "right", "overlay") and (entry := ctx.image_log.find(row_id)) is not None:
            path = entry.path(kind)
        else:
            path = None
        if path is None or not path.is_file():
            return PlainTextResponse("no such picture (not logged, or removed by retention)", status_code=404)
        return FileResponse(path, media_type="image/png")

    async def cameras(request: Request) -> Response:
        return page(request, "cameras.html", active="cameras", board=ctx.actions.board)

    async def camera_snapshot(request: Request) -> Response:
        side = _side(request)
        jpeg = await run_in_threadpool(ctx.live.panel_jpeg, side)
        return Response(jpeg, media_type="image/jpeg", headers={"Cache-Control": "no-store"})

    async def camera_stream(request: Request) -> Response:
        side = _side(request)
        return StreamingResponse(
            _mjpeg(ctx, side, request), media_type="multipart/x-mixed-replace; boundary=frame",
            headers={"Cache-Control": "no-store"},
        )  # fmt: skip

    async def capture(request: Request) -> Response:
        if (refusal := _refuse(ctx, request)) is not None:
            return refusal
        try:
            saved = await run_in_threadpool(ctx.actions.capture)
        except (CameraError, OSError) as exc:
            return JSONResponse({"error": str(exc)}, status_code=409)
        return JSONResponse(
            {
                "name": saved.name,
                "folder": str(saved.left.parent),
                "line": saved.describe(),
                "board_left": saved.board_left,
                "board_right": saved.board_right,
            }
        )

    async def capture_preview(request: Request) -> Response:
        last = ctx.actions.last_capture
        if last is None:
            return PlainTextResponse("no pair captured yet", status_code=404)
        return Response(last[1], media_type="image/jpeg", headers={"Cache-Control": "no-store"})

    async def calibration(request: Request) -> Response:
        facts = calibration_facts(ctx.hub.calib, ctx.calibration_path)
        return page(
            request, "calibration.html", active="calibration", facts=facts, check=ctx.actions.last_rectification
        )

    async def calibration_chart(request: Request) -> Response:
        chart = calibration_facts(ctx.hub.calib, ctx.calibration_path).chart
        if chart is None:
            return PlainTextResponse("no per-pair error chart next to the calibration file", status_code=404)
        return FileResponse(chart, media_type="image/png")

    async def rectify_check(request: Request) -> Response:
        try:
            summary = await run_in_threadpool(ctx.actions.rectification_check)
        except (CameraError, ValueError) as exc:
            return JSONResponse({"error": str(exc)}, status_code=409)
        return JSONResponse({"summary": summary})

    async def rectified_picture(request: Request) -> Response:
        check = ctx.actions.last_rectification
        if check is None:
            return PlainTextResponse("no rectification check run yet", status_code=404)
        return Response(check[1], media_type="image/jpeg", headers={"Cache-Control": "no-store"})

    async def metrics(request: Request) -> Response:
        body = await run_in_threadpool(ctx.metrics.exposition)
        return Response(body, media_type="text/plain; version=0.0.4; charset=utf-8")

    routes = [
        Route("/", cell),
        Route("/fragments/last", last_fragment),
        Route("/api/state", state),
        Route("/events", events),
        Route("/last/overlay.png", last_overlay),
        Route("/history", history),
        Route("/history.csv", history_csv),
        Route("/cycle/{row_id:int}", cycle),
        Route("/cycle/{row_id:int}/{kind}.png", cycle_picture),
        Route("/cameras", cameras),
        Route("/cameras/{side}.jpg", camera_snapshot),
        Route("/cameras/{side}.mjpg", camera_stream),
        Route("/api/capture", capture, methods=["POST"]),
        Route("/captures/last.jpg", capture_preview),
        Route("/calibration", calibration),
        Route("/calibration/errors.png", calibration_chart),
        Route("/api/rectification-check", rectify_check, methods=["POST"]),
        Route("/calibration/rectified.jpg", rectified_picture),
        Route("/metrics", metrics),
        Mount("/static", StaticFiles(directory=str(HERE / "static")), name="static"),
    ]
    return Starlette(routes=routes)


def _cell_view(ctx: StationContext) -> dict[str, Any]:
    """The state panel's facts, as the page and /api/state show them."""
    s = ctx.hub.state
    plc = ctx.plc
    view: dict[str, Any] = {
        "phase": s.phase,
        "cameras_ok": s.cameras_ok,
        "calibration_ok": s.calibration_ok,
        "cycles_done": s.cycles_done,
        "cycle": s.cycle,
        "plc_clients": None if plc is None else plc.connected_clients,
        "heartbeat_ok": None if plc is None else not plc.heartbeat_stalled,
        "state_version": ctx.hub.state_version,
        "cycle_version": ctx.hub.cycle_version,
        "last": None,
    }
    last = ctx.hub.last
    if last is not None:
        r = last.record
        name, meaning, action = describe_code(r.error_code)
        view["last"] = {
            "row_id": r.id,
            "cycle": r.cycle,
            "time": local_time(r.triggered_at),
            "ok": r.status == "ok",
            "cycle_time_ms": round(r.cycle_time_ms),
            "length_mm": r.length_mm,
            "heel_height_mm": r.heel_height_mm,
            "toe_height_mm": r.toe_height_mm,
            "glue_points": len(r.glue_path),
            "error_code": r.error_code,
            "error_name": name,
            "error_meaning": meaning,
            "error_action": action,
            "reason": r.reason,
            "has_picture": last.frame is not None,
        }
    return view


async def _sse(ctx: StationContext, request: Request) -> AsyncIterator[str]:
    """Server-sent events: the cell view whenever the state or the last cycle changes."""
    seen: tuple[int, int] | None = None
    quiet = 0.0
    while not await request.is_disconnected():
        now = (ctx.hub.state_version, ctx.hub.cycle_version)
        if now != seen:
            seen, quiet = now, 0.0
            yield f"data: {json.dumps(_cell_view(ctx))}\n\n"
        elif quiet >= SSE_KEEPALIVE_S:
            quiet = 0.0
            yield ": keep-alive\n\n"
        await asyncio.sleep(SSE_POLL_S)
        quiet += SSE_POLL_S


async def _mjpeg(ctx: StationContext, side: str, request: Request) -> AsyncIterator[bytes]:
    while not await request.is_disconnected():
        jpeg = await run_in_threadpool(ctx.live.panel_jpeg, side)
        yield b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: " + str(len(jpeg)).encode() + b"\r\n\r\n"
        yield jpeg + b"\r\n"
        await asyncio.sleep(0.5)


def _side(request: Request) -> str:
    side = request.path_params["side"]
    return side if side in ("left", "right") else "left"


def _refuse(ctx: StationContext, request: Request) -> Response | None:
    """None if the request carries the configured token; else the refusal to send."""
    if ctx.token is None:
        return JSONResponse(
            {"error": "actions are disabled: set [station] token in the cell config and restart"}, status_code=403
        )
    given = request.headers.get("authorization", "").removeprefix("Bearer ").strip()
    if not given or not hmac.compare_digest(given.encode(), ctx.token.encode()):
        return JSONResponse({"error": "refused: this action needs the station token"}, status_code=401)
    return None


def _journal_rows(state_dir: Path) -> list[CycleRecord]:
    """The newest HISTORY_SCAN cycles (filters apply to these: a page of a day's work, not the whole year)."""
    try:
        journal = Journal.open(state_dir, readonly=True)
    except FileNotFoundError:
        return []
    try:
        return journal.last(HISTORY_SCAN)
    finally:
        journal.close()


def _journal_row(state_dir: Path, row_id: int) -> CycleRecord | None:
    try:
        journal = Journal.open(state_dir, readonly=True)
    except FileNotFoundError:
        return None
    try:
        return journal.get(row_id)
    finally:
        journal.close()


def _png(data: bytes | None) -> Response:
    if data is None:
        return PlainTextResponse("no picture yet", status_code=404)
    return Response(data, media_type="image/png", headers={"Cache-Control": "no-store"})
