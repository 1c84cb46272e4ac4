"""Modbus TCP: MBAP framing, and who may connect for how long.

One coroutine per connection reads a request, answers it, and only then reads the next, so requests
pipelined in one TCP segment are answered in order. A frame whose MBAP header is malformed (protocol
id not 0, length outside 2..254) leaves no way to find the next frame in the stream: the connection is
closed at once, which a Modbus TCP master handles by reconnecting. A well-framed PDU that is wrong
inside is answered with an exception (firmware_io.pdu) and the connection stays usable.

Limits (docs/modbus.md, "Connections"): an optional allow-list of client addresses (others are closed
on accept), a cap on simultaneous connections (a new one beyond the cap closes the connection that
has been idle longest, so a reconnecting PLC is never locked out by stale or idle ones) and an idle
timeout (a connection that sends nothing for idle_timeout_s is closed).
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass

log = logging.getLogger(__name__)

MBAP = struct.Struct(">HHHB")  # transaction id, protocol id, length (unit id + PDU), unit id
#: MBAP length field: unit id plus a PDU of 1..253 bytes.
MIN_LENGTH, MAX_LENGTH = 2, 254
#: Once a header arrived, the rest of its frame must follow within this time (it is one segment in practice).
FRAME_REST_TIMEOUT_S = 2.0
#: The same complaint about the same client is logged at most once per this period.
LOG_REPEAT_S = 60.0

IpNetwork = ipaddress.IPv4Network | ipaddress.IPv6Network


@dataclass(frozen=True)
class ConnectionLimits:
    """Who may connect to the Modbus TCP server, how many at once, and for how long without a request."""

    max_connections: int = 8
    idle_timeout_s: float = 60.0
    allowed_clients: tuple[str, ...] = ()  #: addresses or networks ("192.168.10.5", "192.168.10.0/24"); () = any

    def __post_init__(self) -> None:
        if not 1 <= self.max_connections <= 256:
            raise ValueError(f"max_connections {self.max_connections} must be 1..256")
        if not self.idle_timeout_s > 0:
            raise ValueError(f"idle_timeout_s {self.idle_timeout_s} must be positive")
        self.networks()  # raises ValueError naming a malformed entry

    def networks(self) -> list[IpNetwork]:
        networks = []
        for entry in self.allowed_clients:
            try:
                networks.append(ipaddress.ip_network(entry, strict=False))
            except ValueError:
                raise ValueError(
                    f"allowed client {entry!r} is not an IP address or network such as 192.168.10.5 or 192.168.10.0/24"
                ) from None
        return networks


class _RateLimitedLog:
    def __init__(self) -> None:
        self._last: dict[str, float] = {}

    def warning(self, key: str, message: str, *args: object) -> None:
        now = time.monotonic()
        if now - self._last.get(key, -LOG_REPEAT_S) >= LOG_REPEAT_S:
            self._last[key] = now
            log.warning(message + " (repeats are not logged for %.0f s)", *args, LOG_REPEAT_S)


@dataclass
class _Connection:
    writer: asyncio.StreamWriter
    task: asyncio.Task[None]
    last_request: float


class TcpFrontEnd:
    """Serves MBAP frames on accepted connections; `answer(unit, pdu)` gives the reply PDU or None."""

    def __init__(self, limits: ConnectionLimits, answer: Callable[[int, bytes], bytes | None]) -> None:
        self._limits = limits
        self._networks = limits.networks()
        self._answer = answer
        self._connections: dict[asyncio.StreamWriter, _Connection] = {}
        self._log = _RateLimitedLog()

    @property
    def connection_count(self) -> int:
        return len(self._connections)

    async def start(self, host: str, port: int) -> asyncio.Server:
        return await asyncio.start_server(self._accept, host, port, reuse_address=True)

    async def close_all(self) -> None:
        tasks = [c.task for c in self._connections.values()]
        for connection in list(self._connections.values()):
            connection.writer.close()
            connection.task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer = writer.get_extra_info("peername")
        host = str(peer[0]) if peer else "?"
        if not self._allowed(host):
            self._log.warning(f"deny {host}", "Modbus TCP: refused a connection from %s (not in allowed_clients)", host)
            writer.close()
            return
        if len(self._connections) >= self._limits.max_connections:
            self._evict_idlest(host)
        task = asyncio.current_task()
        assert task is not None
        self._connections[writer] = _Connection(writer, task, time.monotonic())
        log.debug("Modbus TCP: %s connected (%d open)", host, len(self._connections))
        try:
            await self._serve(reader, writer, host)
        except (asyncio.IncompleteReadError, ConnectionError, TimeoutError):
            pass
        finally:
            self._connections.pop(writer, None)
            writer.close()
            log.debug("Modbus TCP: %s disconnected (%d open)", host, len(self._connections))

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, host: str) -> None:
        while True:
            try:
                header = await asyncio.wait_for(reader.readexactly(MBAP.size), self._limits.idle_timeout_s)
            except TimeoutError:
                log.debug("Modbus TCP: %s idle for %.0f s, closed", host, self._limits.idle_timeout_s)
                return
            transaction, protocol, length, unit = MBAP.unpack(header)
            if protocol != 0 or not MIN_LENGTH <= length <= MAX_LENGTH:
                self._log.warning(
                    f"frame {host}",
                    "Modbus TCP: closed the connection from %s after a malformed frame header %s",
                    host,
                    header.hex(),
                )
                return
            pdu = await asyncio.wait_for(reader.readexactly(length - 1), FRAME_REST_TIMEOUT_S)
            self._connections[writer].last_request = time.monotonic()
            reply = self._answer(unit, pdu)
            if reply is None:
                continue
            writer.write(MBAP.pack(transaction, 0, len(reply) + 1, unit) + reply)
            await writer.drain()

    def _allowed(self, host: str) -> bool:
        if not self._networks:
            return True
        try:
            address = ipaddress.ip_address(host)
        except ValueError:
            return False
        if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
            address = address.ipv4_mapped
        return any(address in network for network in self._networks)

    def _evict_idlest(self, newcomer: str) -> None:
        idlest = min(self._connections.values(), key=lambda c: c.last_request)
        self._connections.pop(idlest.writer, None)
        idlest.writer.close()
        idlest.task.cancel()
        self._log.warning(
            "cap",
            "Modbus TCP: %d connections open (max_connections); closed the one idle longest for %s",
            self._limits.max_connections,
            newcomer,
        )
