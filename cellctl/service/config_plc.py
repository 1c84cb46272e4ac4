"""The [plc] section of the cell configuration: Modbus TCP or RTU, the map version, the link's timing and who
may connect (docs/modbus.md, docs/service.md)."""

from __future__ import annotations

from dataclasses import dataclass

from cellctl.service.config_table import Table
from firmware_io.endpoints import (
    DEFAULT_TCP_PORT,
    ByteSize,
    Endpoint,
    Parity,
    SerialEndpoint,
    StopBits,
    TcpEndpoint,
    check_unit_id,
)
from firmware_io.registers import WordOrder
from firmware_io.tcp import ConnectionLimits

# The serial settings SerialEndpoint accepts; read through these tables so the types follow the checks.
_PARITIES: dict[str, Parity] = {"N": "N", "E": "E", "O": "O"}
_STOP_BITS: dict[int, StopBits] = {1: 1, 2: 2}
_BYTE_SIZES: dict[int, ByteSize] = {7: 7, 8: 8}


@dataclass(frozen=True)
class PlcConfig:
    transport: str = "tcp"
    host: str = "127.0.0.1"
    port: int = DEFAULT_TCP_PORT
    serial_port: str | None = None
    baudrate: int = 19200
    parity: Parity = "E"
    stopbits: StopBits = 1
    bytesize: ByteSize = 8
    unit_id: int = 1
    word_order: WordOrder = WordOrder.HIGH_FIRST
    heartbeat_period_s: float = 0.25
    liveness_timeout_s: float = 5.0
    map_version: int = 1  # docs/modbus.md; 2 adds recipes, normals, frame; 1 for PLCs programmed for it
    # A cycle not published within this is answered CYCLE_TIMEOUT (below the PLC's documented 5 s timeout).
    cycle_timeout_s: float = 4.0
    max_connections: int = 8
    idle_timeout_s: float = 60.0
    allowed_clients: tuple[str, ...] = ()

    def limits(self) -> ConnectionLimits:
        """Who may connect to the Modbus TCP server, how many at once, how long idle."""
        return ConnectionLimits(self.max_connections, self.idle_timeout_s, self.allowed_clients)

    def endpoint(self) -> Endpoint:
        """Where PlcLink serves."""
        if self.transport == "rtu":
            assert self.serial_port is not None
            return SerialEndpoint(self.serial_port, self.baudrate, self.parity, self.stopbits, self.bytesize)
        return TcpEndpoint(self.host, self.port)


def read_plc(t: Table) -> PlcConfig:
    transport = t.choice("transport", ("tcp", "rtu"), "tcp")
    allowed = t.get("allowed_clients", list, [])
    if not all(isinstance(entry, str) for entry in allowed):
        raise t.fail("allowed_clients", f'expected a list of addresses such as ["192.168.10.5"], got {allowed!r}')
    config = PlcConfig(
        transport=transport,
        host=t.get("host", str, "127.0.0.1"),
        port=t.integer("port", DEFAULT_TCP_PORT, low=0, high=65535),
        serial_port=t.get("serial_port", str, None),
        baudrate=t.integer("baudrate", 19200, low=300, high=4_000_000),
        parity=_PARITIES[t.choice("parity", tuple(_PARITIES), "E")],
        stopbits=_STOP_BITS[t.integer("stopbits", 1, low=1, high=2)],
        bytesize=_BYTE_SIZES[t.integer("bytesize", 8, low=7, high=8)],
        unit_id=t.integer("unit_id", 1, low=0, high=255),
        word_order=WordOrder(t.choice("word_order", tuple(w.value for w in WordOrder), "high_first")),
        heartbeat_period_s=t.number("heartbeat_period_s", 0.25, above=0, high=0.49),
        liveness_timeout_s=t.number("liveness_timeout_s", 5.0, above=0.5, high=600),
        map_version=int(t.number("map_version", 1, low=1, high=2)),
        cycle_timeout_s=t.number("cycle_timeout_s", 4.0, above=0.5, high=600),
        max_connections=t.integer("max_connections", 8, low=1, high=256),
        idle_timeout_s=t.number("idle_timeout_s", 60.0, above=0, high=86400),
        allowed_clients=tuple(allowed),
    )
    t.finish()
    if transport == "rtu" and not config.serial_port:
        raise t.fail("serial_port", "required for transport 'rtu', e.g. /dev/serial/by-id/usb-FTDI_...-if00-port0")
    try:
        check_unit_id(config.unit_id, config.endpoint())
    except ValueError as exc:
        raise t.fail("unit_id", str(exc)) from None
    try:
        config.limits()
    except ValueError as exc:
        raise t.fail("allowed_clients", str(exc)) from None
    return config
