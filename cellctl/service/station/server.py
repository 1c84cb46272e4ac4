"""uvicorn in a thread of the service process, so the pages share the daemon's state without any IPC."""

from __future__ import annotations

import asyncio
import logging
import threading

import uvicorn
from starlette.applications import Starlette

log = logging.getLogger(__name__)

START_TIMEOUT_S = 10.0


class WebServer:
    """Serves an ASGI app on bind:port from a background thread; start() returns once it listens."""

    def __init__(self, app: Starlette, bind: str, port: int) -> None:
        config = uvicorn.Config(
            app,
            host=bind,
            port=port,
            log_level="warning",
            access_log=False,
            lifespan="off",
            # Live streams (SSE, MJPEG) end by themselves on stop; do not wait long for them.
            timeout_graceful_shutdown=2,
        )
        self._server = uvicorn.Server(config)
        self._thread = threading.Thread(target=self._run, name="station-web", daemon=True)
        self._error: BaseException | None = None
        self.bind = bind

    def _run(self) -> None:
        try:
            asyncio.run(self._server.serve())
        except BaseException as exc:  # reported by start()
            self._error = exc

    def start(self) -> None:
        self._thread.start()
        deadline = threading.Event()
        waited = 0.0
        while not self._server.started and self._thread.is_alive() and waited < START_TIMEOUT_S:
            deadline.wait(0.05)
            waited += 0.05
        if not self._server.started:
            self._server.should_exit = True
            raise ValueError(
                f"the operator station cannot listen on {self.bind}: "
                f"{self._error or 'port in use or address not on this machine'} (see [station] in the config)"
            )

    @property
    def port(self) -> int:
        """The port bound (the configured one, or the one chosen for port 0)."""
        for server in self._server.servers:
            for sock in server.sockets:
                return int(sock.getsockname()[1])
        return 0

    @property
    def url(self) -> str:
        host = "127.0.0.1" if self.bind in ("0.0.0.0", "") else self.bind
        return f"http://{host}:{self.port}/"

    def stop(self) -> None:
        self._server.should_exit = True
        self._thread.join(timeout=5.0)
