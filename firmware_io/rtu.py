"""Modbus RTU: finding request frames in the bytes of a shared RS-485 line.

RTU has no length field; a frame ends with 3.5 character times of silence. USB adapters and ptys
deliver bytes in chunks whose timing says little, so a frame is recognised in two ways:

* a request of one of the served function codes (3, 6, 16, 23) has a length known from its first
  bytes; as soon as that many bytes with a valid CRC are buffered, it is a frame (no waiting);
* anything else (another function code, another slave's answer, line noise) is taken whole once the
  line has been silent for `silence_s`, and is answered only if its CRC is valid and it is addressed
  to this slave.

Requests for another unit id, broadcasts (unit 0) and frames with a bad CRC get no answer at all: the
bus may carry other slaves, and the spec forbids answering a broadcast. The CRC is pymodbus'.

SerialLine reads the port from the event loop (pyserial, non-blocking) and answers each frame as soon as
it is whole; serve_serial_line reopens a port that went away.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

import serial
from pymodbus.framer.rtu import FramerRTU

from firmware_io.endpoints import SerialEndpoint
from firmware_io.pdu import READ_HOLDING, READ_WRITE, WRITE_MULTIPLE, WRITE_SINGLE

log = logging.getLogger(__name__)

#: How often a lost serial port is retried.
SERIAL_REOPEN_PERIOD_S = 1.0

#: Shortest frame: unit id, function code, CRC.
MIN_FRAME = 4
#: Longest RTU frame the spec allows.
MAX_FRAME = 256


def crc(data: bytes) -> bytes:
    """The Modbus CRC of data, as the two bytes that follow it on the line."""
    return FramerRTU.compute_CRC(data).to_bytes(2, "big")


def frame(unit: int, pdu: bytes) -> bytes:
    """An RTU frame: unit id, PDU, CRC."""
    body = bytes([unit]) + pdu
    return body + crc(body)


def silence_s(baudrate: int, bytesize: int = 8, parity: str = "N", stopbits: int = 1) -> float:
    """Inter-frame silence: 3.5 characters (1.75 ms above 19200 baud, as the spec says), plus slack.

    The slack (10 ms) covers USB adapters, which hand bytes over in chunks every few ms.
    """
    bits = 1 + bytesize + (parity != "N") + stopbits
    t35 = 3.5 * bits / baudrate if baudrate <= 19200 else 0.00175
    return t35 + 0.010


def request_length(buffer: bytes | bytearray) -> int | None:
    """Length of the request frame at the start of buffer, if its function code is served and known."""
    if len(buffer) < 2:
        return None
    function = buffer[1]
    if function in (READ_HOLDING, WRITE_SINGLE):
        return 8
    if function == WRITE_MULTIPLE and len(buffer) >= 7:
        return 9 + buffer[6]
    if function == READ_WRITE and len(buffer) >= 11:
        return 13 + buffer[10]
    return None


class RtuDeframer:
    """Collects line bytes and hands out complete, CRC-checked frames as (unit, pdu)."""

    def __init__(self) -> None:
        self._buffer = bytearray()

    def feed(self, data: bytes) -> list[tuple[int, bytes]]:
        """Add received bytes; the frames now complete by their known length."""
        self._buffer += data
        frames = []
        while (length := request_length(self._buffer)) is not None and len(self._buffer) >= length:
            candidate = bytes(self._buffer[:length])
            if candidate[-2:] != crc(candidate[:-2]):
                break  # not a request of known length after all: wait for the silence
            del self._buffer[:length]
            frames.append((candidate[0], candidate[1:-2]))
        if len(self._buffer) > MAX_FRAME:
            self._buffer.clear()  # noise without a pause: nothing in it can be a frame
        return frames

    def silence(self) -> tuple[int, bytes] | None:
        """The line went quiet: whatever is buffered is one frame, if its CRC says so."""
        data, self._buffer = bytes(self._buffer), bytearray()
        if len(data) < MIN_FRAME or data[-2:] != crc(data[:-2]):
            return None
        return data[0], data[1:-2]

    @property
    def pending(self) -> bool:
        return bool(self._buffer)


class SerialLine:
    """One open serial port, read by the event loop; replies are written as soon as a frame is whole."""

    def __init__(self, endpoint: SerialEndpoint, answer: Callable[[int, bytes], bytes | None]) -> None:
        self._answer = answer
        self._port = serial.Serial(
            endpoint.port,
            baudrate=endpoint.baudrate,
            bytesize=endpoint.bytesize,
            parity=endpoint.parity,
            stopbits=endpoint.stopbits,
            timeout=0,
            write_timeout=1.0,
            exclusive=True,
        )
        self._silence_s = silence_s(endpoint.baudrate, endpoint.bytesize, endpoint.parity, endpoint.stopbits)
        self._deframer = RtuDeframer()
        self._loop = asyncio.get_running_loop()
        self._lost = asyncio.Event()
        self._silence: asyncio.TimerHandle | None = None
        self._loop.add_reader(self._port.fileno(), self._on_readable)

    async def lost_or(self, stop: asyncio.Event) -> None:
        """Wait until the line fails or stop is set."""
        waits = {asyncio.create_task(self._lost.wait()), asyncio.create_task(stop.wait())}
        _, pending = await asyncio.wait(waits, return_when=asyncio.FIRST_COMPLETED)
        for task in pending:
            task.cancel()

    def close(self) -> None:
        if self._silence is not None:
            self._silence.cancel()
        try:
            self._loop.remove_reader(self._port.fileno())
        except (OSError, ValueError):
            pass
        self._port.close()

    def _on_readable(self) -> None:
        try:
            data = self._port.read(max(1, self._port.in_waiting))
            for unit, pdu in self._deframer.feed(data):
                self._reply(unit, pdu)
        except (serial.SerialException, OSError) as exc:
            log.debug("serial line failed: %s", exc)
            self._loop.remove_reader(self._port.fileno())
            self._lost.set()
            return
        if self._silence is not None:
            self._silence.cancel()
        if self._deframer.pending:
            self._silence = self._loop.call_later(self._silence_s, self._on_silence)

    def _on_silence(self) -> None:
        received = self._deframer.silence()
        if received is not None:
            try:
                self._reply(*received)
            except (serial.SerialException, OSError):
                self._lost.set()

    def _reply(self, unit: int, pdu: bytes) -> None:
        reply = self._answer(unit, pdu)
        if reply is not None:
            self._port.write(frame(unit, reply))


async def serve_serial_line(
    line: SerialLine,
    endpoint: SerialEndpoint,
    answer: Callable[[int, bytes], bytes | None],
    stop: asyncio.Event,
    on_state: Callable[[bool], None],
) -> None:
    """Serve `line` until stop is set; a lost line (USB adapter unplugged) is reopened every second.

    Reopening the same device name brings the link back when the adapter is replugged (same
    /dev/serial/by-id name), without a service restart.
    """
    while True:
        await line.lost_or(stop)
        line.close()
        on_state(False)
        if stop.is_set():
            return
        log.warning("Modbus RTU line %s lost; reopening every %.0f s", endpoint, SERIAL_REOPEN_PERIOD_S)
        while True:
            try:
                await asyncio.wait_for(stop.wait(), SERIAL_REOPEN_PERIOD_S)
                return
            except TimeoutError:
                pass
            try:
                line = SerialLine(endpoint, answer)
                break
            except (serial.SerialException, OSError):
                continue
        on_state(True)
        log.info("Modbus RTU line %s open again", endpoint)
