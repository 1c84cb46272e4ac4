"""The cell for the plant's MES: an OPC UA server (asyncua) with the cell's state, last result and history.

    server = OpcUaServer(config.opcua, status=lambda: link.status, recipes=book, active_recipe=...)
    server.start()                  # own thread and event loop; the controller stays plain blocking code
    daemon.listeners.append(server.publish)      # every finished cycle: variables, history, one event
    server.stop()

The address space follows the structure of the OPC UA Machine Vision companion specification (OPC 40100)
as far as it fits a measuring cell without its full type system: a system object per cell with a
VisionStateMachine (CurrentState: Preoperational, Ready, SingleExecution, Error, Halted), RecipeManagement
(active recipe), ResultManagement with the last result (ResultId, CreationTime, RecipeId, measurements,
IsPass) and its history, and a ResultReadyEventType event per cycle (emitted by the Server object, SourceNode
the cell's object).
docs/opcua.md lists every node; cellctl.service.opcua_nodes builds them and writes to them. Off unless [opcua] enabled = true; anonymous access only if
allow_anonymous = true, otherwise username and the password from password_file.
"""

from __future__ import annotations

import asyncio
import hmac
import logging
import threading
from collections import deque
from collections.abc import Callable
from typing import Any

from asyncua import Server, ua
from asyncua.crypto.permission_rules import User, UserRole

from cellctl.errors import UserError
from cellctl.service.config import OpcUaConfig
from cellctl.service.opcua_nodes import NAMESPACE, CellNodes
from cellctl.service.outcome import CycleOutcome
from cellctl.service.recipes import Recipe, RecipeBook
from firmware_io.registers import StatusBit
from firmware_io.server import PlcLink

__all__ = ["NAMESPACE", "OpcUaServer", "serve_cell", "system_state"]

log = logging.getLogger(__name__)
# asyncua reports every connection and endpoint at INFO; the service log keeps its warnings and errors.
logging.getLogger("asyncua").setLevel(logging.WARNING)

#: How often CurrentState follows the PLC link's status register.
STATE_PERIOD_S = 0.2


def system_state(status: StatusBit, stopping: bool) -> str:
    """CurrentState of the VisionStateMachine for the PLC link's status register."""
    if stopping:
        return "Halted"
    if status & StatusBit.BUSY:
        return "SingleExecution"
    if status & StatusBit.READY:
        return "Ready"
    healthy = StatusBit.CAMERAS_OK | StatusBit.CALIBRATION_OK
    return "Error" if status & healthy != healthy else "Preoperational"


class _PasswordUsers:
    """asyncua user manager: one configured user, password compared in constant time; anonymous if allowed."""

    def __init__(self, username: str | None, password: str | None, allow_anonymous: bool) -> None:
        self._username, self._password, self._anonymous = username, password, allow_anonymous

    def get_user(self, iserver: object, username: str | None = None, password: str | None = None, certificate: object = None) -> User | None:  # fmt: skip
        if username is None:  # anonymous token (the secure channel's certificate may still be there)
            return User(role=UserRole.User) if self._anonymous else None
        if self._username is None or self._password is None or username != self._username:
            return None
        if not hmac.compare_digest((password or "").encode(), self._password.encode()):
            return None
        return User(role=UserRole.User, name=username)


class OpcUaServer:
    """The OPC UA server of one cell, in its own thread."""

    def __init__(
        self,
        config: OpcUaConfig,
        *,
        status: Callable[[], StatusBit],
        recipes: list[tuple[int, str]],
        active_recipe: Callable[[], tuple[int, str]],
    ) -> None:
        self.config = config
        self._status = status
        self._recipes = recipes
        self._active_recipe = active_recipe
        self._history: deque[CycleOutcome] = deque(maxlen=config.history)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._thread: threading.Thread | None = None
        self._started = threading.Event()
        self._start_error: BaseException | None = None
        self._stopping = False
        self._nodes: CellNodes | None = None  # once the address space is built (server thread)
        self.endpoint = config.endpoint  #: with the port actually bound once started (port 0 picks one)

    # ---- lifetime (controller thread) ------------------------------------------------------------

    def start(self, timeout_s: float = 30.0) -> None:
        self._thread = threading.Thread(target=self._run, name="opcua", daemon=True)
        self._thread.start()
        if not self._started.wait(timeout_s):
            self.stop()
            raise UserError(f"OPC UA server on {self.config.endpoint} did not start within {timeout_s} s")
        if self._start_error is not None:
            raise UserError(
                f"cannot serve OPC UA on {self.config.endpoint}: {self._start_error} (is the port in use by another "
                "cellctl, and is the address local to this PC? set [opcua] endpoint)"
            )
        log.info("OPC UA serving %s", self.endpoint)

    def stop(self, timeout_s: float = 10.0) -> None:
        self._stopping = True
        loop, stop, thread = self._loop, self._stop, self._thread
        if loop is not None and stop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(stop.set)
            except RuntimeError:  # loop closed meanwhile: already stopped
                pass
        if thread is not None:
            thread.join(timeout_s)

    def publish(self, outcome: CycleOutcome) -> None:
        """Daemon listener: queue the outcome for the server's loop; never blocks the cycle."""
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        future = asyncio.run_coroutine_threadsafe(self._publish(outcome), loop)
        future.add_done_callback(_log_failure)

    # ---- server thread ---------------------------------------------------------------------------

    def _run(self) -> None:
        try:
            asyncio.run(self._serve())
        except BaseException as exc:  # report, never die silently
            log.exception("OPC UA server failed")
            self._start_error = self._start_error or exc
        finally:
            self._started.set()

    async def _serve(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        server = await _new_server(self.config)
        nodes = self._nodes = await CellNodes.build(server, self.config, self._recipes)
        try:
            await server.start()
        except Exception as exc:
            self._start_error = exc
            return
        self.endpoint = _bound_endpoint(self.config.endpoint, server.bserver.port if server.bserver else None)
        self._started.set()
        try:
            while not self._stop.is_set():
                try:
                    await self._follow_state()
                except Exception:  # a failed update must not end the server; the next tick tries again
                    log.exception("OPC UA: updating the state failed")
                try:
                    await asyncio.wait_for(self._stop.wait(), STATE_PERIOD_S)
                except TimeoutError:
                    pass
            await nodes.state.write_value("Halted")
        finally:
            await server.stop()

    async def _follow_state(self) -> None:
        if self._nodes is not None:
            await self._nodes.show_state(system_state(self._status(), self._stopping), self._active_recipe())

    async def _publish(self, outcome: CycleOutcome) -> None:
        self._history.appendleft(outcome)
        if self._nodes is not None:
            await self._nodes.show_result(outcome, self._history)


async def _new_server(cfg: OpcUaConfig) -> Server:
    """An asyncua server at the configured endpoint, with its users (nodes not yet added)."""
    password = None if cfg.password_file is None else cfg.password_file.read_text(encoding="utf-8").strip()
    server = Server(user_manager=_PasswordUsers(cfg.username, password, cfg.allow_anonymous))  # type: ignore[arg-type]
    await server.init()
    server.set_endpoint(cfg.endpoint)
    server.set_server_name(f"cellctl {cfg.cell_name}")
    tokens: list[type] = [ua.UserNameIdentityToken]
    if cfg.allow_anonymous:
        tokens.append(ua.AnonymousIdentityToken)
    server.set_identity_tokens(tokens)
    return server


def _bound_endpoint(url: str, port: int | None) -> str:
    if port is None:
        return url
    scheme_host, _, rest = url.removeprefix("opc.tcp://").partition("/")
    host = scheme_host.rsplit(":", 1)[0]
    return f"opc.tcp://{host}:{port}/{rest}"


def _log_failure(future: Any) -> None:
    if not future.cancelled() and future.exception() is not None:
        log.error("OPC UA: publishing a result failed: %s", future.exception())


def serve_cell(
    config: OpcUaConfig, link: PlcLink, recipes: RecipeBook, active: Callable[[], Recipe | None]
) -> OpcUaServer:
    """The cell's OPC UA server, started: its state from the PLC link, the recipes loaded, the active one."""

    def active_recipe() -> tuple[int, str]:
        recipe = active()
        return (0, "") if recipe is None else (recipe.number, recipe.name)

    server = OpcUaServer(
        config, status=lambda: link.status, recipes=[(r.number, r.name) for r in recipes], active_recipe=active_recipe
    )
    server.start()
    return server
