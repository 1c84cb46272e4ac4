"""A log that does not repeat itself: one line when a problem starts or changes, then one a while."""

from __future__ import annotations

import logging
import time


class RepeatQuietLog:
    """Logs a warning when it changes, and the same warning again only every `repeat_s` (at debug between).

    A camera unplugged over a weekend is probed every second; one line a minute says it is still missing.
    """

    def __init__(self, logger: logging.Logger, repeat_s: float) -> None:
        self._log, self._repeat_s = logger, repeat_s
        self._last: tuple[str, float] | None = None

    def warning(self, key: str, message: str, *args: object) -> None:
        now = time.monotonic()
        if self._last is None or self._last[0] != key or now - self._last[1] >= self._repeat_s:
            self._last = (key, now)
            self._log.warning(message, *args)
        else:
            self._log.debug(message, *args)

    def reset(self) -> None:
        self._last = None
