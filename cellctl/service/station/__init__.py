"""The operator station: web pages, /metrics and the image log, attached to a Daemon in the same process.

    daemon = Daemon(config)
    station = Station.attach(daemon)      # subscribes to daemon.events; serves [station] bind:port
    try:
        daemon.run()
    finally:
        station.stop()

Modules: app (the Starlette app), pages (HTML), api (streams, actions, /metrics), context (what handlers
read), hub (latest state, last picture), live (camera preview), actions (capture, rectification check),
history (table, CSV, trends), calibration_info, server (uvicorn in a thread); templates/ and static/ are
package data.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from cellctl.service.daemon import Daemon
from cellctl.service.imagelog import ImageLog
from cellctl.service.metrics import CellMetrics
from cellctl.service.station.actions import CameraActions
from cellctl.service.station.app import create_app
from cellctl.service.station.context import StationContext
from cellctl.service.station.hub import StationHub
from cellctl.service.station.live import LiveView
from cellctl.service.station.server import WebServer

log = logging.getLogger(__name__)


@dataclass
class Station:
    """The observers of one daemon and, when enabled, the web server showing them."""

    context: StationContext
    server: WebServer | None

    @classmethod
    def attach(cls, daemon: Daemon, *, port: int | None = None) -> Station:
        """Subscribe the hub, metrics and image log to the daemon; start the web server if [station] enabled.
        `port` overrides [station] port (0: any free port, for tests)."""
        config = daemon.config
        state_dir = config.journal.state_dir
        hub = StationHub(daemon.calib)
        metrics = CellMetrics(daemon.link, state_dir)
        image_log = ImageLog(state_dir / "images", daemon.calib, config.image_log)
        for subscriber in (hub.on_event, metrics.on_event, image_log.on_event):
            daemon.events.subscribe(subscriber)
        live = LiveView(
            daemon.source, daemon.camera_lock, lambda: daemon.events.state, daemon.calib, config.measure.depth_range_mm
        )
        context = StationContext(
            hub=hub,
            metrics=metrics,
            image_log=image_log,
            live=live,
            actions=CameraActions(live, daemon.calib, state_dir / "captures", config.station.board),
            state_dir=state_dir,
            calibration_path=config.calibration.path,
            token=config.station.token,
            plc=daemon.link,
            cell_name=config.source.stem,
            active_recipe=lambda: (
                None if daemon.active_recipe is None else (daemon.active_recipe.number, daemon.active_recipe.name)
            ),
            taught_problem=daemon.measurer.taught_problem,
            taught_required=config.measure.require_taught_table,
        )
        server = None
        if config.station.enabled:
            server = WebServer(create_app(context), config.station.bind, config.station.port if port is None else port)
            server.start()
            log.info("operator station at %s", server.url)
        return cls(context, server)

    @property
    def url(self) -> str | None:
        return None if self.server is None else self.server.url

    def stop(self) -> None:
        if self.server is not None:
            self.server.stop()
        if not self.context.image_log.wait_written(10.0):
            log.warning("image log: some pictures were not written before the stop")
