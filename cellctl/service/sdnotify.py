"""systemd's notify protocol (sd_notify(3)): READY=1, WATCHDOG=1, STATUS=... over $NOTIFY_SOCKET.

A handful of lines over an AF_UNIX datagram socket rather than a dependency (python-systemd needs
libsystemd headers to build); the protocol is one datagram of newline-separated KEY=VALUE lines.
Without $NOTIFY_SOCKET (not run by systemd, or Type= is not notify) every call does nothing.
"""

from __future__ import annotations

import logging
import os
import socket

log = logging.getLogger(__name__)


class SystemdNotifier:
    def __init__(self, address: str | None = None) -> None:
        address = os.environ.get("NOTIFY_SOCKET") if address is None else address
        # A leading '@' names a socket in the abstract namespace, which Python spells with a NUL byte.
        self._address = None if not address else "\0" + address[1:] if address.startswith("@") else address
        self._socket: socket.socket | None = None
        if self._address is not None:
            self._socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)

    @property
    def enabled(self) -> bool:
        return self._socket is not None

    def notify(self, **fields: str | int) -> None:
        """Send e.g. notify(READY=1, STATUS="waiting for trigger"); failures are logged, never raised."""
        if self._socket is None or self._address is None:
            return
        message = "\n".join(f"{key}={value}" for key, value in fields.items()).encode()
        try:
            self._socket.sendto(message, self._address)
        except OSError as exc:  # systemd gone or socket full: the service must keep running regardless
            log.warning("cannot notify systemd at %s: %s", self._address, exc)

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None


def watchdog_period_s() -> float | None:
    """systemd's watchdog period (WatchdogSec=, passed as $WATCHDOG_USEC), or None without a watchdog."""
    usec = os.environ.get("WATCHDOG_USEC", "")
    return int(usec) / 1e6 if usec.isdigit() else None


def check_watchdog(needed_s: float, what: str) -> None:
    """ValueError if `what` (needed_s seconds without a watchdog ping) would outlast systemd's watchdog."""
    watchdog_s = watchdog_period_s()
    if watchdog_s is not None and needed_s >= watchdog_s:
        raise ValueError(
            f"{what} = {needed_s:g} s must be below the systemd watchdog ({watchdog_s:g} s, WatchdogSec= in the "
            "unit): lower them or raise WatchdogSec"
        )
