"""The Modbus server of PlcLink in its own thread with its own asyncio loop: TCP (firmware_io.tcp) or RTU
(firmware_io.rtu) framing, requests executed by firmware_io.pdu against the handshake's register image, and
the heartbeat task (firmware_io.heartbeat, which also answers overdue cycles with CYCLE_TIMEOUT).

The controller stays plain blocking code: it only calls start() and stop() here; everything it says to the
PLC goes through the handshake (firmware_io.handshake), under the handshake's lock.
"""

from __future__ import annotations

import asyncio
import logging
import threading

import serial

from firmware_io.endpoints import Endpoint, LinkStartError, SerialEndpoint, TcpEndpoint
from firmware_io.handshake import PlcHandshake
from firmware_io.heartbeat import Heartbeat
from firmware_io.pdu import ExceptionCode, exception_reply, execute
from firmware_io.rtu import SerialLine, serve_serial_line
from firmware_io.tcp import ConnectionLimits, TcpFrontEnd

log = logging.getLogger("firmware_io.server")  # PlcLink's log, as operators know it


class ModbusServerThread:
    """Serves one handshake to the PLC at one endpoint, with its heartbeat running on the same loop."""

    def __init__(
        self,
        endpoint: Endpoint,
        unit_id: int,
        handshake: PlcHandshake,
        limits: ConnectionLimits,
        heartbeat: Heartbeat,
    ) -> None:
        self._endpoint, self._unit_id, self._handshake, self._limits = endpoint, unit_id, handshake, limits
        self._heartbeat = heartbeat
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop_requested: asyncio.Event | None = None
        self._started = threading.Event()
        self._start_error: BaseException | None = None
        self.bound: Endpoint = endpoint  # for TCP port 0, the port actually bound once started
        self._tcp: TcpFrontEnd | None = None
        self._serial_open = False

    def start(self, timeout_s: float = 5.0) -> None:
        """Open the TCP port or serial line and start serving; raises if that fails."""
        if self._thread is not None:
            raise RuntimeError("PlcLink already started; a link starts once")
        self._thread = threading.Thread(target=self._run_loop, name=f"plc-link {self._endpoint}", daemon=True)
        self._thread.start()
        if not self._started.wait(timeout_s):
            self.stop()
            raise RuntimeError(f"Modbus server on {self._endpoint} did not start within {timeout_s} s")
        if self._start_error is not None:
            self._thread.join(timeout_s)
            raise LinkStartError(_start_failure_text(self._endpoint, self._start_error)) from None
        log.info("Modbus %s serving unit id %d", self.bound, self._unit_id)

    def stop(self, timeout_s: float = 5.0) -> None:
        """Close all PLC connections and the port, stop the heartbeat, wake wait_trigger()."""
        self._handshake.close()
        thread, loop, stop = self._thread, self._loop, self._stop_requested
        if thread is None:
            return
        if loop is not None and stop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(stop.set)
            except RuntimeError:  # loop closed between the check and the call: already stopping
                pass
        thread.join(timeout_s)
        if thread.is_alive():
            raise RuntimeError(f"Modbus server thread for {self._endpoint} did not stop within {timeout_s} s")

    @property
    def connected_clients(self) -> int:
        """TCP connections open now (RTU: 1 while the serial line is open)."""
        if isinstance(self._endpoint, SerialEndpoint):
            return int(self._serial_open)
        return 0 if self._tcp is None else self._tcp.connection_count

    # ---- requests ------------------------------------------------------------------------------

    def _answer(self, unit: int, pdu: bytes) -> bytes | None:
        """The reply PDU for a request to `unit`, or None for no answer at all (RTU, other slave)."""
        if isinstance(self._endpoint, SerialEndpoint):
            return execute(pdu, self._handshake) if unit == self._unit_id else None
        if self._unit_id != 0 and unit != self._unit_id:
            return exception_reply(pdu[0], ExceptionCode.GATEWAY_NO_RESPONSE)
        return execute(pdu, self._handshake)

    # ---- server thread -------------------------------------------------------------------------

    def _run_loop(self) -> None:
        try:
            asyncio.run(self._serve())
        except BaseException as exc:  # report, never let the thread die silently
            log.exception("Modbus server thread failed")
            self._start_error = self._start_error or exc
        finally:
            self._started.set()

    async def _serve(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop_requested = asyncio.Event()
        heartbeat = asyncio.create_task(self._heartbeat.run(), name="plc heartbeat")
        try:
            if isinstance(self._endpoint, SerialEndpoint):
                await self._serve_rtu(self._endpoint)
            else:
                await self._serve_tcp(self._endpoint)
        finally:
            heartbeat.cancel()
            await asyncio.gather(heartbeat, return_exceptions=True)

    async def _serve_tcp(self, endpoint: TcpEndpoint) -> None:
        assert self._stop_requested is not None
        self._tcp = TcpFrontEnd(self._limits, self._answer)
        try:
            server = await self._tcp.start(endpoint.host, endpoint.port)
        except OSError as exc:
            self._start_error = exc
            return
        host, port = server.sockets[0].getsockname()[:2]
        self.bound = TcpEndpoint(str(host), int(port))
        self._started.set()
        try:
            await self._stop_requested.wait()
        finally:
            server.close()
            await self._tcp.close_all()
            await server.wait_closed()

    async def _serve_rtu(self, endpoint: SerialEndpoint) -> None:
        assert self._stop_requested is not None
        try:
            line = SerialLine(endpoint, self._answer)
        except (serial.SerialException, OSError, ValueError) as exc:
            self._start_error = exc
            return
        self._started.set()
        self._serial_open = True
        try:
            await serve_serial_line(line, endpoint, self._answer, self._stop_requested, self._on_serial_state)
        finally:
            self._serial_open = False

    def _on_serial_state(self, line_open: bool) -> None:
        self._serial_open = line_open


def _start_failure_text(endpoint: Endpoint, error: BaseException) -> str:
    if isinstance(endpoint, SerialEndpoint):
        hint = "does the serial port exist, is another program using it, is the user in group dialout?"
    else:
        hint = "is the port already in use (another cellctl running?) and is the address one of this PC's?"
    return f"cannot serve Modbus on {endpoint}: {error} ({hint})"
