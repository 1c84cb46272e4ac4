"""The operator station's web app: Starlette, server-rendered Jinja2 pages (pages.py), live streams, actions
and /metrics (api.py), static CSS and JS. No front-end build.

Everything that only reads is open; actions (POST /api/capture) need the [station] token as
`Authorization: Bearer TOKEN`.
"""

from __future__ import annotations

from pathlib import Path

from starlette.applications import Starlette
from starlette.routing import BaseRoute, Mount
from starlette.staticfiles import StaticFiles

from cellctl.service.station.api import Api
from cellctl.service.station.context import StationContext
from cellctl.service.station.pages import Pages

STATIC = Path(__file__).parent / "static"


def create_app(ctx: StationContext) -> Starlette:
    routes: list[BaseRoute] = [*Pages(ctx).routes(), *Api(ctx).routes()]
    routes.append(Mount("/static", StaticFiles(directory=str(STATIC)), name="static"))
    return Starlette(routes=routes)
