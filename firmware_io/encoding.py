"""How values are encoded into the map's registers: float32 in two words of either order, glue points (6
registers) and points with normals (12, map v2). The float conversion itself is pymodbus' (the controller
encodes exactly what a pymodbus client with the same word order decodes)."""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike
from pymodbus.client.mixin import ModbusClientMixin

#: Fixed upper bound of the glue path so the register map has a fixed size (100 + 6 * 2000 = 12100
#: registers). 2000 points at the ~1 mm spacing a robot dispenser needs cover a 2 m contour, several
#: times the perimeter of the largest sole; a longer path must be resampled before publishing.
MAX_GLUE_POINTS = 2000

#: Registers per glue point: x, y, z as float32.
REGISTERS_PER_POINT = 6


class WordOrder(enum.Enum):
    """Order of the two 16-bit words of a float32 (bytes inside a word are always big-endian)."""

    HIGH_FIRST = "high_first"  #: "ABCD", Modbus convention, e.g. Siemens, Codesys default
    LOW_FIRST = "low_first"  #: "CDAB", e.g. many Schneider and Allen-Bradley setups

    @property
    def pymodbus_name(self) -> Literal["big", "little"]:
        """The `word_order` argument pymodbus' converters expect."""
        return "big" if self is WordOrder.HIGH_FIRST else "little"


_FLOAT32 = ModbusClientMixin.DATATYPE.FLOAT32
_FLOAT32_MAX = float(np.finfo(np.float32).max)


@dataclass(frozen=True)
class RegisterMap:
    """Encoding of values into this map's registers for one word order.

    The float conversion itself is pymodbus' (`convert_to_registers`), so the controller encodes
    exactly what a pymodbus client with the same word order decodes.
    """

    word_order: WordOrder = WordOrder.HIGH_FIRST

    def encode_floats(self, values: Sequence[float], what: str = "value") -> list[int]:
        """Registers (2 per value) for float32 values (NaN allowed); refuses finite values too big."""
        checked = [_float32(v, f"{what}[{i}]") for i, v in enumerate(values)]
        if not checked:
            return []
        return ModbusClientMixin.convert_to_registers(checked, _FLOAT32, word_order=self.word_order.pymodbus_name)

    def decode_floats(self, registers: Sequence[int]) -> list[float]:
        """float32 values from registers (2 per value)."""
        if len(registers) % 2:
            raise ValueError(f"float32 needs 2 registers each, got {len(registers)} registers")
        if not registers:
            return []
        decoded = ModbusClientMixin.convert_from_registers(
            list(registers), _FLOAT32, word_order=self.word_order.pymodbus_name
        )
        # pymodbus returns a bare float for a single value; always hand back a list.
        return decoded if isinstance(decoded, list) else [decoded]  # type: ignore[list-item,return-value]

    def encode_points(self, points: ArrayLike) -> list[int]:
        """Registers (6 per point) for an (N, 3) array of x, y, z in mm; N <= MAX_GLUE_POINTS."""
        array = np.asarray(points, dtype=float)
        if array.size == 0:
            return []
        if array.ndim != 2 or array.shape[1] != 3:
            raise ValueError(f"glue points must be an (N, 3) array of x, y, z, got shape {array.shape}")
        if len(array) > MAX_GLUE_POINTS:
            raise ValueError(
                f"glue path has {len(array)} points but the register map holds at most "
                f"{MAX_GLUE_POINTS}: resample the path before publishing"
            )
        return self.encode_floats(array.ravel().tolist(), what="glue point coordinate")

    def decode_points(self, registers: Sequence[int]) -> np.ndarray:
        """An (N, 3) float32 array of x, y, z from registers (6 per point)."""
        if len(registers) % REGISTERS_PER_POINT:
            raise ValueError(f"glue points need 6 registers each, got {len(registers)} registers")
        return np.asarray(self.decode_floats(registers), dtype=np.float32).reshape(-1, 3)

    def encode_path(self, points: ArrayLike, normals: ArrayLike) -> list[int]:
        """Registers (12 per point, map v2) for x, y, z in mm and the unit normal nx, ny, nz of each point."""
        array, directions = np.asarray(points, dtype=float), np.asarray(normals, dtype=float)
        if array.shape != directions.shape:
            raise ValueError(f"glue points {array.shape} and normals {directions.shape} must have the same shape")
        if array.size == 0:
            return []
        if array.ndim != 2 or array.shape[1] != 3 or len(array) > MAX_GLUE_POINTS:
            self.encode_points(array)  # raises with the reason
        lengths = np.linalg.norm(directions, axis=1)
        if not np.all(np.abs(lengths - 1.0) < 1e-3):
            raise ValueError("glue normals must be unit vectors (length 1 within 1e-3)")
        return self.encode_floats(np.hstack([array, directions]).ravel().tolist(), what="glue point or normal")

    def decode_path(self, registers: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) points and (N, 3) normals, float32, from registers (12 per point, map v2)."""
        if len(registers) % (2 * REGISTERS_PER_POINT):
            raise ValueError(f"glue points with normals need 12 registers each, got {len(registers)} registers")
        values = np.asarray(self.decode_floats(registers), dtype=np.float32).reshape(-1, 6)
        return values[:, :3].copy(), values[:, 3:].copy()


def _float32(value: float, what: str) -> float:
    number = float(value)
    if math.isfinite(number) and abs(number) > _FLOAT32_MAX:
        raise ValueError(f"{what} = {number!r} is too large for a float32 (max {_FLOAT32_MAX:.3g})")
    return number
