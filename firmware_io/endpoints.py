"""Where the Modbus link runs: a TCP address or a serial port. Shared by the server and the PLC simulator."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Parity = Literal["N", "E", "O"]
StopBits = Literal[1, 2]
ByteSize = Literal[7, 8]

#: Default TCP port: 5020 rather than the registered 502, which needs root on Linux.
DEFAULT_TCP_PORT = 5020


@dataclass(frozen=True)
class TcpEndpoint:
    """Modbus TCP. The server listens on host:port (port 0 picks a free port); the simulator connects."""

    host: str = "127.0.0.1"
    port: int = DEFAULT_TCP_PORT

    def __post_init__(self) -> None:
        if not self.host:
            raise ValueError("Modbus TCP host is empty: give an address such as 127.0.0.1 or 0.0.0.0")
        if not 0 <= self.port <= 65535:
            raise ValueError(f"Modbus TCP port {self.port} is out of range 0..65535")

    def __str__(self) -> str:
        return f"tcp://{self.host}:{self.port}"


@dataclass(frozen=True)
class SerialEndpoint:
    """Modbus RTU over a serial line (RS-485 adapter). Defaults are the Modbus spec's 19200 8E1."""

    port: str
    baudrate: int = 19200
    parity: Parity = "E"
    stopbits: StopBits = 1
    bytesize: ByteSize = 8

    def __post_init__(self) -> None:
        if not self.port:
            raise ValueError("serial port is empty: give a device such as /dev/ttyUSB0")
        if self.baudrate <= 0:
            raise ValueError(f"serial baud rate {self.baudrate} must be positive, e.g. 19200")
        if self.parity not in ("N", "E", "O"):
            raise ValueError(f"serial parity {self.parity!r} must be 'N', 'E' or 'O'")
        if self.stopbits not in (1, 2):
            raise ValueError(f"serial stop bits {self.stopbits} must be 1 or 2")
        if self.bytesize not in (7, 8):
            raise ValueError(f"serial byte size {self.bytesize} must be 7 or 8")

    def __str__(self) -> str:
        return f"rtu:{self.port} {self.baudrate} {self.bytesize}{self.parity}{self.stopbits}"


Endpoint = TcpEndpoint | SerialEndpoint


class LinkStartError(RuntimeError):
    """The TCP port or serial line cannot be opened; the message names it and what to check.

    Here rather than in firmware_io.server so the command line can catch it without loading the server.
    """


def check_unit_id(unit_id: int, endpoint: Endpoint) -> int:
    """Validate a Modbus unit (slave) id for the endpoint; 0 means "any" on TCP only."""
    if isinstance(endpoint, SerialEndpoint):
        if not 1 <= unit_id <= 247:
            raise ValueError(f"Modbus RTU unit id {unit_id} must be 1..247 (0 is broadcast)")
    elif not 0 <= unit_id <= 255:
        raise ValueError(f"Modbus TCP unit id {unit_id} must be 0..255 (0 = answer any unit id)")
    return unit_id
