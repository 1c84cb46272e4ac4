"""The station's live streams (SSE state, MJPEG cameras), actions (token-checked) and /metrics."""

from __future__ import annotations

import asyncio
import hmac
import json
from collections.abc import AsyncIterator

from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import JSONResponse, PlainTextResponse, Response, StreamingResponse
from starlette.routing import Route

from cellctl.cameras.base import CameraError
from cellctl.service.station.context import StationContext

SSE_POLL_S = 0.25  # how often a live page's stream looks for news; events are rare, the check is cheap
SSE_KEEPALIVE_S = 15.0
MJPEG_PERIOD_S = 0.5  # matches live.PREVIEW_PERIOD_S: no frame is sent twice on purpose
NO_STORE = {"Cache-Control": "no-store"}


class Api:
    """Everything that is not a page."""

    def __init__(self, ctx: StationContext) -> None:
        self.ctx = ctx

    def routes(self) -> list[Route]:
        return [
            Route("/api/state", self.state),
            Route("/events", self.events),
            Route("/cameras/{side}.jpg", self.camera_snapshot),
            Route("/cameras/{side}.mjpg", self.camera_stream),
            Route("/api/capture", self.capture, methods=["POST"]),
            Route("/captures/last.jpg", self.capture_preview),
            Route("/api/rectification-check", self.rectification_check, methods=["POST"]),
            Route("/calibration/rectified.jpg", self.rectified_picture),
            Route("/metrics", self.metrics),
        ]

    async def state(self, request: Request) -> Response:
        return JSONResponse(self.ctx.cell_view())

    async def events(self, request: Request) -> Response:
        return StreamingResponse(self._sse(request), media_type="text/event-stream", headers=NO_STORE)

    async def _sse(self, request: Request) -> AsyncIterator[str]:
        """The cell view whenever the state or the last cycle changes, and a keep-alive comment now and then."""
        seen: tuple[int, int] | None = None
        quiet = 0.0
        while not await request.is_disconnected():
            now = (self.ctx.hub.state_version, self.ctx.hub.cycle_version)
            if now != seen:
                seen, quiet = now, 0.0
                yield f"data: {json.dumps(self.ctx.cell_view())}\n\n"
            elif quiet >= SSE_KEEPALIVE_S:
                quiet = 0.0
                yield ": keep-alive\n\n"
            await asyncio.sleep(SSE_POLL_S)
            quiet += SSE_POLL_S

    async def camera_snapshot(self, request: Request) -> Response:
        jpeg = await run_in_threadpool(self.ctx.live.panel_jpeg, _side(request))
        return Response(jpeg, media_type="image/jpeg", headers=NO_STORE)

    async def camera_stream(self, request: Request) -> Response:
        media = "multipart/x-mixed-replace; boundary=frame"
        return StreamingResponse(self._mjpeg(_side(request), request), media_type=media, headers=NO_STORE)

    async def _mjpeg(self, side: str, request: Request) -> AsyncIterator[bytes]:
        while not await request.is_disconnected():
            jpeg = await run_in_threadpool(self.ctx.live.panel_jpeg, side)
            yield b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: " + str(len(jpeg)).encode() + b"\r\n\r\n"
            yield jpeg + b"\r\n"
            await asyncio.sleep(MJPEG_PERIOD_S)

    async def capture(self, request: Request) -> Response:
        if (refusal := self._refuse(request)) is not None:
            return refusal
        try:
            saved = await run_in_threadpool(self.ctx.actions.capture)
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

    async def capture_preview(self, request: Request) -> Response:
        return _last_jpeg(self.ctx.actions.last_capture, "no pair captured yet")

    async def rectification_check(self, request: Request) -> Response:
        """Open to all: it only reads (a grab between cycles and a picture), like the live view."""
        try:
            summary = await run_in_threadpool(self.ctx.actions.rectification_check)
        except (CameraError, ValueError) as exc:
            return JSONResponse({"error": str(exc)}, status_code=409)
        return JSONResponse({"summary": summary})

    async def rectified_picture(self, request: Request) -> Response:
        return _last_jpeg(self.ctx.actions.last_rectification, "no rectification check run yet")

    async def metrics(self, request: Request) -> Response:
        body = await run_in_threadpool(self.ctx.metrics.exposition)
        return Response(body, media_type="text/plain; version=0.0.4; charset=utf-8")

    def _refuse(self, request: Request) -> Response | None:
        """None if the request carries the configured token; else the refusal to send."""
        token = self.ctx.token
        if token is None:
            message = "actions are disabled: set [station] token in the cell config and restart"
            return JSONResponse({"error": message}, status_code=403)
        given = request.headers.get("authorization", "").removeprefix("Bearer ").strip()
        if not given or not hmac.compare_digest(given.encode(), token.encode()):
            return JSONResponse({"error": "refused: this action needs the station token"}, status_code=401)
        return None


def _side(request: Request) -> str:
    side = request.path_params["side"]
    return side if side in ("left", "right") else "left"


def _last_jpeg(last: tuple[object, bytes] | None, missing: str) -> Response:
    """The JPEG of the last capture or check (its second item), or 404 with `missing` before there is one."""
    if last is None:
        return PlainTextResponse(missing, status_code=404)
    return Response(last[1], media_type="image/jpeg", headers=NO_STORE)
