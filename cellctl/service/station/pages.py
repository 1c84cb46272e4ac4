"""The station's HTML pages and the pictures they show."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import FileResponse, PlainTextResponse, Response
from starlette.routing import Route
from starlette.templating import Jinja2Templates

from cellctl.service.operator_text import describe_code
from cellctl.service.station.calibration_info import calibration_facts
from cellctl.service.station.context import StationContext
from cellctl.service.station.history import HistoryFilter, to_csv, trends
from cellctl.service.timefmt import local_time

TEMPLATES = Path(__file__).parent / "templates"


class Pages:
    """Server-rendered pages: cell, history (and CSV), one cycle, cameras, calibration."""

    def __init__(self, ctx: StationContext) -> None:
        self.ctx = ctx
        self.templates = Jinja2Templates(directory=str(TEMPLATES))
        self.templates.env.globals.update(local_time=local_time, describe_code=describe_code)

    def routes(self) -> list[Route]:
        return [
            Route("/", self.cell),
            Route("/fragments/last", self.last_fragment),
            Route("/last/overlay.png", self.last_overlay),
            Route("/history", self.history),
            Route("/history.csv", self.history_csv),
            Route("/cycle/{row_id:int}", self.cycle),
            Route("/cycle/{row_id:int}/{kind}.png", self.cycle_picture),
            Route("/cameras", self.cameras),
            Route("/calibration", self.calibration),
            Route("/calibration/errors.png", self.calibration_chart),
        ]

    def page(self, request: Request, name: str, **values: Any) -> Response:
        context = {"ctx": self.ctx, "cell": self.ctx.cell_view(), **values}
        return self.templates.TemplateResponse(request, name, context)

    async def cell(self, request: Request) -> Response:
        return self.page(request, "cell.html", active="cell")

    async def last_fragment(self, request: Request) -> Response:
        return self.page(request, "_last.html")

    async def last_overlay(self, request: Request) -> Response:
        png = await run_in_threadpool(self.ctx.hub.last_overlay_png)
        if png is None:
            return PlainTextResponse("no picture yet", status_code=404)
        return Response(png, media_type="image/png", headers={"Cache-Control": "no-store"})

    async def history(self, request: Request) -> Response:
        wanted = HistoryFilter.from_query(dict(request.query_params))
        records = wanted.apply(await run_in_threadpool(self.ctx.journal_rows))
        logged = {e.row_id for e in self.ctx.image_log.entries()}
        newest_first = list(reversed(records))
        return self.page(
            request,
            "history.html",
            active="history",
            records=newest_first,
            wanted=wanted,
            trends=trends(records),
            logged=logged,
        )

    async def history_csv(self, request: Request) -> Response:
        wanted = HistoryFilter.from_query(dict(request.query_params))
        records = wanted.apply(await run_in_threadpool(self.ctx.journal_rows))
        headers = {"Content-Disposition": 'attachment; filename="cellctl-history.csv"'}
        return PlainTextResponse(to_csv(records), media_type="text/csv", headers=headers)

    async def cycle(self, request: Request) -> Response:
        row_id = int(request.path_params["row_id"])
        record = await run_in_threadpool(self.ctx.journal_row, row_id)
        if record is None:
            return PlainTextResponse(f"no journaled cycle with id {row_id}", status_code=404)
        entry = self.ctx.image_log.find(row_id)
        meta = entry.meta() if entry else {}
        return self.page(request, "cycle.html", active="history", r=record, entry=entry, meta=meta)

    async def cycle_picture(self, request: Request) -> Response:
        """A logged picture (left, right, overlay) or the kept overlay PNG (artifact); only paths we made."""
        row_id, kind = int(request.path_params["row_id"]), request.path_params["kind"]
        path: Path | None = None
        if kind == "artifact":
            record = await run_in_threadpool(self.ctx.journal_row, row_id)
            path = None if record is None or record.overlay_path is None else Path(record.overlay_path)
        elif kind in ("left", "right", "overlay") and (entry := self.ctx.image_log.find(row_id)) is not None:
            path = entry.path(kind)
        if path is None or not path.is_file():
            return PlainTextResponse("no such picture (not logged, or removed by retention)", status_code=404)
        return FileResponse(path, media_type="image/png")

    async def cameras(self, request: Request) -> Response:
        return self.page(request, "cameras.html", active="cameras", board=self.ctx.actions.board)

    async def calibration(self, request: Request) -> Response:
        facts = calibration_facts(self.ctx.hub.calib, self.ctx.calibration_path)
        check = self.ctx.actions.last_rectification
        taught = (self.ctx.taught_problem, self.ctx.taught_required)
        return self.page(request, "calibration.html", active="calibration", facts=facts, check=check, taught=taught)

    async def calibration_chart(self, request: Request) -> Response:
        chart = calibration_facts(self.ctx.hub.calib, self.ctx.calibration_path).chart
        if chart is None:
            return PlainTextResponse("no per-pair error chart next to the calibration file", status_code=404)
        return FileResponse(chart, media_type="image/png")
