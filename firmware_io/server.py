"""PlcLink: the controller's Modbus slave towards the robot PLC (TCP server or RTU over a serial port).

Threading: pymodbus' server is asyncio-only, while the controller (cameras, C matching core, SQLite
journal) is plain blocking code. PlcLink therefore runs pymodbus in one background thread with its
own event loop, and the controller talks to it through thread-safe calls. The Modbus side keeps
answering the PLC and the heartbeat keeps running while the controller thread is busy measuring,
and no asyncio leaks into the rest of the code base.

Register storage: pymodbus 3.16's SimDevice keeps the registers; its documented `action` hook runs
on every request, and we use it to (a) refuse function codes other than holding-register access,
(b) route trigger writes into the handshake and (c) copy the requested range from the handshake's
register image just before pymodbus answers a read. The image (firmware_io.handshake) is the single
source of truth and is updated under one lock, which is what makes results atomic for the PLC.
Writes to read-only registers are refused by pymodbus itself (SimData readonly=True), with
exception 0x02 ILLEGAL DATA ADDRESS. SimDevice rather than ModbusServerContext/ModbusDeviceContext:
3.16 deprecates the latter (a warning at construction, removal announced for v4) and points to
SimDevice, although pymodbus still labels it experimental; tests/test_modbus.py pins the behaviour
we rely on.
"""

from __future__ import annotations

import asyncio
import logging
import threading
from collections.abc import Sequence

from numpy.typing import ArrayLike
from pymodbus.constants import ExcCodes
from pymodbus.exceptions import NoSuchIdException
from pymodbus.framer import FramerType
from pymodbus.server import ModbusBaseServer, ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from firmware_io.endpoints import Endpoint, SerialEndpoint, TcpEndpoint, check_unit_id
from firmware_io.handshake import Inspection, PathInfo, PlcHandshake, Trigger
from firmware_io.registers import ErrorCode, MapLayout, RegisterMap, StatusBit, WordOrder

log = logging.getLogger(__name__)

#: Holding-register function codes: read (3), write single (6), write multiple (16), read/write (23).
#: Everything else (coils, input registers, mask write) is answered with ILLEGAL FUNCTION, because
#: the map is holding registers only and a second view of the same memory would be a second way in.
HOLDING_REGISTER_FUNCTIONS = frozenset({3, 6, 16, 23})

#: How often a lost serial port is retried.
SERIAL_REOPEN_PERIOD_S = 1.0


class PlcLink:
    """The controller's side of the PLC handshake, served over Modbus TCP or RTU.

    Typical controller loop::

        with PlcLink(TcpEndpoint("0.0.0.0", 5020), unit_id=1) as link:
            link.set_status(cameras_ok=True, calibration_ok=True)
            while running:
                trigger = link.wait_trigger(timeout_s=0.5)
                if trigger is None:
                    continue
                ...measure...
                link.publish_result(trigger.cycle, heel_height_mm=..., toe_height_mm=...,
                                    length_mm=..., cycle_time_ms=..., glue_points=points)
                # or: link.publish_error(trigger.cycle, ErrorCode.NO_SOLE, cycle_time_ms=...)
    """

    def __init__(
        self,
        endpoint: Endpoint = TcpEndpoint(),
        *,
        unit_id: int = 1,
        word_order: WordOrder = WordOrder.HIGH_FIRST,
        heartbeat_period_s: float = 0.25,
        liveness_timeout_s: float | None = 5.0,
        map_version: int = 1,
    ) -> None:
        """Configure the link; nothing is opened until start().

        unit_id: Modbus unit (slave) id answered; on TCP 0 answers any id. Requests for another id
            get exception 0x0B on TCP and no answer at all on RTU (the bus may have other slaves).
        heartbeat_period_s: heartbeat increment period; must stay below 0.5 s (the documented limit).
        liveness_timeout_s: the heartbeat stops when the controller has made no PlcLink call (a
            waiting wait_trigger() counts) for this long, so the PLC sees a hung controller.
            None keeps it beating whenever the link runs.
        map_version: register map layout served (docs/modbus.md): 1, or 2 with recipes and normals.
        """
        if not 0 < heartbeat_period_s < 0.5:
            raise ValueError(f"heartbeat period {heartbeat_period_s} s must be above 0 and below 0.5 s")
        if liveness_timeout_s is not None and liveness_timeout_s <= heartbeat_period_s:
            raise ValueError(f"liveness timeout {liveness_timeout_s} s must be longer than the heartbeat period")
        self._endpoint = endpoint
        self._unit_id = check_unit_id(unit_id, endpoint)
        self._map = RegisterMap(word_order)
        self._heartbeat_period_s = heartbeat_period_s
        self._liveness_timeout_s = liveness_timeout_s
        self._layout = MapLayout.of(map_version)
        self._handshake = PlcHandshake(self._map, self._layout)
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop_requested: asyncio.Event | None = None
        self._line_lost: asyncio.Event | None = None
        self._started = threading.Event()
        self._start_error: BaseException | None = None
        self._bound: Endpoint = endpoint
        # For the operator station and /metrics (read from other threads; ints are replaced atomically).
        self.connected_clients = 0  # TCP connections open now (RTU: 1 while the serial line is open)
        self.heartbeat_stalls = 0  # times the heartbeat stopped because the controller went silent
        self.heartbeat_stalled = False

    # ---- lifetime ------------------------------------------------------------------------------

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
            raise RuntimeError(_start_failure_text(self._endpoint, self._start_error)) from self._start_error
        log.info("Modbus %s serving unit id %d", self._bound, self._unit_id)

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

    def __enter__(self) -> PlcLink:
        self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    @property
    def endpoint(self) -> Endpoint:
        """Where the link serves; for TCP port 0, the port actually bound once started."""
        return self._bound

    # ---- controller API ------------------------------------------------------------------------

    @property
    def status(self) -> StatusBit:
        """The status register as the PLC reads it now."""
        return self._handshake.status

    @property
    def layout(self) -> MapLayout:
        """The register map version served."""
        return self._layout

    def wait_trigger(self, timeout_s: float | None = None) -> Trigger | None:
        """Block until the PLC starts a new cycle; None on timeout or when the link stops."""
        slice_s = self._heartbeat_period_s if self._liveness_timeout_s is None else self._liveness_timeout_s / 2
        return self._handshake.wait_trigger(timeout_s, liveness_slice_s=slice_s)

    def set_status(self, *, cameras_ok: bool, calibration_ok: bool) -> None:
        """Report camera and calibration health (status bits 4 and 5; READY needs both)."""
        self._handshake.set_health(cameras_ok=cameras_ok, calibration_ok=calibration_ok)

    def publish_result(
        self,
        cycle: int,
        *,
        heel_height_mm: float,
        toe_height_mm: float,
        length_mm: float,
        cycle_time_ms: float,
        glue_points: ArrayLike,
        path: PathInfo | None = None,
        inspection: Inspection | None = None,
    ) -> None:
        """Publish the measurement of `cycle` atomically; glue_points is (N, 3) mm, N <= 2000.

        Map version 2 also publishes `path` (normals, frame, offsets; required) and `inspection`.
        """
        self._handshake.publish_result(
            cycle,
            heel_height_mm=heel_height_mm,
            toe_height_mm=toe_height_mm,
            length_mm=length_mm,
            cycle_time_ms=cycle_time_ms,
            glue_points=glue_points,
            path=path,
            inspection=inspection,
        )

    def publish_error(self, cycle: int, code: ErrorCode, *, cycle_time_ms: float) -> None:
        """Publish that `cycle` failed with `code` (ERROR bit set, RESULT_VALID clear)."""
        self._handshake.publish_error(cycle, code, cycle_time_ms=cycle_time_ms)

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
        self._line_lost = asyncio.Event()
        try:
            server = await self._open_server()
        except Exception as exc:
            self._start_error = exc
            return
        self._bound = _bound_endpoint(server, self._endpoint)
        heartbeat = asyncio.create_task(self._heartbeat(), name="plc heartbeat")
        self._started.set()
        try:
            while server is not None and await self._line_lost_or_stop():
                await server.shutdown()
                server = await self._reopen_serial_line()
        finally:
            heartbeat.cancel()
            if server is not None:
                await server.shutdown()
            # Let the transports' close callbacks run so sockets and the tty are released before
            # the loop is torn down.
            await asyncio.sleep(0)
            await asyncio.sleep(0)

    async def _open_server(self) -> ModbusBaseServer:
        server = self._make_server()
        await server.serve_forever(background=True)  # RuntimeError if the port cannot be opened
        return server

    async def _line_lost_or_stop(self) -> bool:
        """Wait; True when the serial line was lost, False when stop() was called."""
        stop = asyncio.create_task(self._stop_requested.wait())
        lost = asyncio.create_task(self._line_lost.wait())
        await asyncio.wait({stop, lost}, return_when=asyncio.FIRST_COMPLETED)
        stop.cancel()
        lost.cancel()
        return not self._stop_requested.is_set()

    async def _reopen_serial_line(self) -> ModbusBaseServer | None:
        """Reopen a serial port that went away (USB adapter unplugged) until it is back or stop()."""
        # pymodbus' serial server does not reopen its port after an I/O error; we do, so replugging
        # the adapter (same /dev/serial/by-id name) brings the link back without a service restart.
        log.warning("Modbus RTU line %s lost; reopening every %.0f s", self._endpoint, SERIAL_REOPEN_PERIOD_S)
        while not self._stop_requested.is_set():
            try:
                await asyncio.wait_for(self._stop_requested.wait(), SERIAL_REOPEN_PERIOD_S)
                return None
            except TimeoutError:
                pass
            self._line_lost.clear()
            try:
                server = await self._open_server()
            except RuntimeError:
                continue
            log.info("Modbus RTU line %s open again", self._endpoint)
            return server
        return None

    def _on_connection(self, connected: bool) -> None:
        """pymodbus trace_connect hook: a TCP client came or went, or the serial line opened or failed."""
        log.debug("Modbus %s: connection %s", self._endpoint, "opened" if connected else "closed")
        self.connected_clients = max(0, self.connected_clients + (1 if connected else -1))
        stopping = self._stop_requested is not None and self._stop_requested.is_set()
        if not connected and isinstance(self._endpoint, SerialEndpoint) and not stopping:
            self._line_lost.set()

    async def _heartbeat(self) -> None:
        while True:
            beating = self._handshake.beat(self._liveness_timeout_s)
            if not beating and not self.heartbeat_stalled:
                self.heartbeat_stalls += 1
            self.heartbeat_stalled = not beating
            await asyncio.sleep(self._heartbeat_period_s)

    def _make_server(self) -> ModbusBaseServer:
        device = SimDevice(id=self._unit_id, simdata=_map_blocks(self._layout), action=self._on_request)
        if isinstance(self._endpoint, SerialEndpoint):
            ep = self._endpoint
            server: ModbusBaseServer = ModbusSerialServer(
                device,
                framer=FramerType.RTU,
                port=ep.port,
                baudrate=ep.baudrate,
                parity=ep.parity,
                stopbits=ep.stopbits,
                bytesize=ep.bytesize,
                ignore_missing_devices=True,
                trace_connect=self._on_connection,
            )
        else:
            server = ModbusTcpServer(
                device, address=(self._endpoint.host, self._endpoint.port), trace_connect=self._on_connection
            )
        if self._unit_id != 0:
            server.context = _SingleUnit(server.context, self._unit_id)
        return server

    async def _on_request(
        self,
        function_code: int,
        start_address: int,
        address: int,
        count: int,
        current_registers: list[int],
        set_values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        """pymodbus SimDevice action: runs after pymodbus' address/read-only checks, before it answers."""
        if function_code not in HOLDING_REGISTER_FUNCTIONS:
            return ExcCodes.ILLEGAL_FUNCTION
        if set_values is not None:
            return self._handshake.plc_write(address, [int(v) for v in set_values])
        offset = address - start_address
        current_registers[offset : offset + count] = self._handshake.plc_read(address, count)
        return None


class _SingleUnit:
    """Answers only one unit id.

    pymodbus 3.16's SimCore falls back to unit 0 for unknown ids and fails with KeyError when there
    is none, which the server turns into exception 0x04 with a traceback in the log, and answers even
    on an RTU bus. Raising NoSuchIdException instead gives pymodbus' documented behaviour:
    exception 0x0B on TCP, silence on RTU (ignore_missing_devices=True).
    """

    def __init__(self, inner: object, unit_id: int) -> None:
        self._inner = inner
        self._unit_id = unit_id

    def _check(self, device_id: int) -> None:
        if device_id != self._unit_id:
            raise NoSuchIdException(f"this controller answers unit id {self._unit_id}, not {device_id}")

    async def async_getValues(self, device_id: int, func_code: int, address: int, count: int = 1):  # noqa: N802
        self._check(device_id)
        return await self._inner.async_getValues(device_id, func_code, address, count)  # type: ignore[attr-defined]

    async def async_setValues(self, device_id: int, func_code: int, address: int, values: Sequence[int]):  # noqa: N802
        self._check(device_id)
        return await self._inner.async_setValues(device_id, func_code, address, values)  # type: ignore[attr-defined]

    def device_ids(self) -> list[int]:
        return [self._unit_id]


def _map_blocks(layout: MapLayout) -> list[SimData]:
    """The whole map as register blocks: PLC-writable ones read-write, every other one read-only."""
    blocks: list[SimData] = []
    start = 0
    size, plc_writable = layout.size, layout.plc_writable
    while start < size:
        writable = start in plc_writable
        end = start + 1
        while end < size and (end in plc_writable) == writable:
            end += 1
        blocks.append(
            SimData(address=start, count=end - start, values=0, datatype=DataType.REGISTERS, readonly=not writable)
        )
        start = end
    return blocks


def _bound_endpoint(server: ModbusBaseServer, endpoint: Endpoint) -> Endpoint:
    if isinstance(endpoint, TcpEndpoint) and endpoint.port == 0:
        host, port = server.transport.sockets[0].getsockname()[:2]  # type: ignore[union-attr]
        return TcpEndpoint(host, port)
    return endpoint


def _start_failure_text(endpoint: Endpoint, error: BaseException) -> str:
    if isinstance(endpoint, SerialEndpoint):
        hint = "does the serial port exist, is another program using it, is the user in group dialout?"
    else:
        hint = "is the port already in use (another cellctl running?) and is the address local to this PC?"
    return f"cannot serve Modbus on {endpoint}: {error} ({hint})"
