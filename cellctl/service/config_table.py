"""Reading one TOML table of the cell configuration: keys handed out with their type and bounds checked, and
a complaint about every key nobody asked for (a typo must not silently fall back to a default).

Every problem is a ConfigError naming the file, the section and key, what is wrong and what to write instead.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from types import EllipsisType
from typing import Any


class ConfigError(ValueError):
    """The configuration file is missing, malformed or asks for something impossible."""


def read_toml(path: Path) -> dict[str, Any]:
    """The file's TOML as a dict; ConfigError naming the file if it is not valid TOML or not UTF-8 text."""
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path} is not valid TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path} is not UTF-8 text: {exc}") from None


class Table:
    """One TOML table being read: hands out keys and complains about the ones nobody asked for."""

    def __init__(self, data: dict[str, Any], name: str, source: Path) -> None:
        self.data, self.name, self.source = data, name, source
        self._taken: set[str] = set()

    def fail(self, key: str, problem: str) -> ConfigError:
        return ConfigError(f"{self.source}: [{self.name}] {key}: {problem}")

    def get(self, key: str, kind: type | tuple[type, ...], default: Any = ...) -> Any:
        self._taken.add(key)
        if key not in self.data:
            if default is ...:
                raise ConfigError(f"{self.source}: [{self.name}] is missing the required key {key!r}")
            return default
        value = self.data[key]
        kinds = kind if isinstance(kind, tuple) else (kind,)
        # bool is an int in Python; a number key given `true` is a mistake, not 1.
        if isinstance(value, bool) and bool not in kinds or not isinstance(value, kinds):
            names = " or ".join(k.__name__ for k in kinds)
            raise self.fail(key, f"expected {names}, got {type(value).__name__} {value!r}")
        return float(value) if float in kinds and isinstance(value, int) and not isinstance(value, bool) else value

    def number(
        self,
        key: str,
        default: float | EllipsisType = ...,  # ...: a required key (as in `get`)
        *,
        low: float | None = None,
        high: float | None = None,
        above: float | None = None,
    ) -> float:
        return self._bounded(key, float(self.get(key, (int, float), default)), low, high, above)

    def optional_number(
        self,
        key: str,
        default: float | None = None,
        *,
        low: float | None = None,
        high: float | None = None,
        above: float | None = None,
    ) -> float | None:
        """A number that may be absent (None unless `default`)."""
        value = self.get(key, (int, float), default)
        return None if value is None else self._bounded(key, float(value), low, high, above)

    def _bounded(self, key: str, value: float, low: float | None, high: float | None, above: float | None) -> float:
        if (
            (low is not None and value < low)
            or (high is not None and value > high)
            or (above is not None and value <= above)
        ):
            bounds = (
                f"above {above:g}"
                if above is not None
                else f"in {low:g}..{high:g}"
                if high is not None
                else f">= {low:g}"
            )
            raise self.fail(key, f"{value:g} is impossible: must be {bounds}")
        return value

    def integer(self, key: str, default: Any = ..., *, low: int | None = None, high: int | None = None) -> int:
        """A whole number: 5020.7 is refused, not truncated to 5020."""
        value = self.get(key, int, default)
        if (low is not None and value < low) or (high is not None and value > high):
            bounds = f"in {low}..{high}" if low is not None and high is not None else f">= {low}"
            raise self.fail(key, f"{value} is impossible: must be {bounds}")
        return int(value)

    def choice(self, key: str, choices: tuple[str, ...], default: Any = ...) -> str:
        value = self.get(key, str, default)
        if value not in choices:
            raise self.fail(key, f"{value!r} is not one of {', '.join(repr(c) for c in choices)}")
        return value

    def path(self, key: str, default: Any = ...) -> Path | None:
        value = self.get(key, str, default)
        if value is None:
            return None
        if not value:
            raise self.fail(key, "empty path")
        path = Path(value).expanduser()
        return path if path.is_absolute() else (self.source.parent / path).resolve()

    def table(self, key: str) -> Table:
        value = self.get(key, dict, {})
        return Table(value, f"{self.name}.{key}", self.source)

    def finish(self) -> None:
        unknown = sorted(set(self.data) - self._taken)
        if unknown:
            known = ", ".join(sorted(self._taken))
            raise ConfigError(
                f"{self.source}: [{self.name}] has unknown key(s) {', '.join(unknown)} (known keys: {known})"
            )
