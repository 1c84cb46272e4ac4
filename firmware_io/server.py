"""PlcLink: the controller's Modbus slave towards the robot PLC (TCP server or RTU over a serial port).

Threading: the server is asyncio, while the controller (cameras, C matching core, SQLite journal) is
plain blocking code. PlcLink therefore runs the server in one background thread with its own event
loop, and the controller talks to it through thread-safe calls. The Modbus side keeps answering the
PLC and the heartbeat keeps running while the controller thread is busy measuring, and no asyncio
leaks into the rest of the code base.

Protocol: requests are parsed and executed by firmware_io.pdu against the handshake's register image
(firmware_io.handshake), the single source of truth, updated under one lock: results are atomic for
the PLC. Framing is firmware_io.tcp (MBAP, connection limits) and firmware_io.rtu (CRC, silence).
Until version 3.16, pymodbus' server did all this; it was replaced because it executed a request
piecewise (a refused fc 23 had already started a cycle), answered function codes this map does not
serve (8, 17, 43 naming the stack; on RTU for any unit id), fell silent for ~22 requests after one bad
frame and had no connection cap or idle timeout (docs/modbus.md lists what is answered now).
pymodbus remains the client of the PLC simulator, a master this server did not write.

Typical controller loop::

    with PlcLink(TcpEndpoint("192.168.10.2", 5020), unit_id=1, cycle_timeout_s=4.0) as link:
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

from __future__ import annotations

from numpy.typing import ArrayLike

from firmware_io.endpoints import Endpoint, TcpEndpoint, check_unit_id
from firmware_io.handshake import Inspection, PathInfo, PlcHandshake, Trigger
from firmware_io.heartbeat import Heartbeat
from firmware_io.registers import ErrorCode, MapLayout, RegisterMap, StatusBit, WordOrder
from firmware_io.server_thread import ModbusServerThread
from firmware_io.tcp import ConnectionLimits


class PlcLink:
    """The controller's side of the PLC handshake, served over Modbus TCP or RTU.

    The field side's one facade (lifetime and the controller API); the work is in handshake, the server
    thread (firmware_io.server_thread), its heartbeat (firmware_io.heartbeat), pdu, tcp and rtu. The module
    docstring shows a typical controller loop.
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
        cycle_timeout_s: float | None = None,
        limits: ConnectionLimits = ConnectionLimits(),
    ) -> None:
        """Configure the link; nothing is opened until start().

        unit_id: Modbus unit (slave) id answered; on TCP 0 answers any id. Requests for another id
            get exception 0x0B on TCP and no answer at all on RTU (the bus may have other slaves).
        heartbeat_period_s: heartbeat increment period; must stay below 0.5 s (the documented limit).
        liveness_timeout_s: between cycles, the heartbeat stops when the controller has made no
            PlcLink call (a waiting wait_trigger() counts) for this long. None: never stops.
        map_version: register map layout served (docs/modbus.md): 1, or 2 with recipes and normals.
        cycle_timeout_s: while a cycle runs the heartbeat keeps beating; a cycle not published within
            this time is answered with ErrorCode.CYCLE_TIMEOUT by the link itself, and the liveness
            rule applies again from then on. None: no limit.
        limits: TCP connection cap, idle timeout and allowed client addresses.
        """
        self._layout = MapLayout.of(map_version)
        self._handshake = PlcHandshake(RegisterMap(word_order), self._layout)
        self._heartbeat = Heartbeat(self._handshake, heartbeat_period_s, liveness_timeout_s, cycle_timeout_s)
        self._server = ModbusServerThread(
            endpoint, check_unit_id(unit_id, endpoint), self._handshake, limits, self._heartbeat
        )

    # ---- lifetime ------------------------------------------------------------------------------

    def start(self, timeout_s: float = 5.0) -> None:
        """Open the TCP port or serial line and start serving; raises if that fails."""
        self._server.start(timeout_s)

    def stop(self, timeout_s: float = 5.0) -> None:
        """Close all PLC connections and the port, stop the heartbeat, wake wait_trigger()."""
        self._server.stop(timeout_s)

    def __enter__(self) -> PlcLink:
        self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    @property
    def connected_clients(self) -> int:
        """TCP connections open now (RTU: 1 while the serial line is open)."""
        return self._server.connected_clients

    @property
    def endpoint(self) -> Endpoint:
        """Where the link serves; for TCP port 0, the port actually bound once started."""
        return self._server.bound

    @property
    def heartbeat_stalls(self) -> int:
        """Times the heartbeat stopped because the controller went silent (station, /metrics)."""
        return self._heartbeat.stalls

    @property
    def heartbeat_stalled(self) -> bool:
        return self._heartbeat.stalled

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
        return self._handshake.wait_trigger(timeout_s, liveness_slice_s=self._heartbeat.liveness_slice_s)

    def timed_out(self, cycle: int) -> bool:
        """True if the link already answered `cycle` with CYCLE_TIMEOUT (see cycle_timeout_s)."""
        return self._handshake.timed_out(cycle)

    def restore_last_cycle(self, cycle: int) -> None:
        """After a restart, the cycle answered last (from the journal): writing it again starts nothing."""
        self._handshake.restore_last_cycle(cycle)

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
    ) -> bool:
        """Publish the measurement of `cycle` atomically; glue_points is (N, 3) mm, N <= 2000.

        Map version 2 also publishes `path` (normals, frame, offsets; required) and `inspection`. False if
        the link had already answered the cycle with CYCLE_TIMEOUT (nothing published).
        """
        return self._handshake.publish_result(
            cycle,
            heel_height_mm=heel_height_mm,
            toe_height_mm=toe_height_mm,
            length_mm=length_mm,
            cycle_time_ms=cycle_time_ms,
            glue_points=glue_points,
            path=path,
            inspection=inspection,
        )

    def publish_error(self, cycle: int, code: ErrorCode, *, cycle_time_ms: float) -> bool:
        """Publish that `cycle` failed with `code`; False if it had already timed out (see publish_result)."""
        return self._handshake.publish_error(cycle, code, cycle_time_ms=cycle_time_ms)
