"""What each PLC error code means and what the operator should do, in words for the station's pages.

The same table as docs/modbus.md "Error codes" (tests/service/test_station_parts.py checks they agree),
read from the register map's texts so there is one copy in the code.
"""

from __future__ import annotations

from firmware_io.registers import ErrorCode

# One table, in the register map (firmware_io.registers): the words the PLC programmer and the operator read.
OPERATOR_TEXT: dict[ErrorCode, tuple[str, str]] = {code: (code.meaning, code.operator_action) for code in ErrorCode}


def describe_code(code: int) -> tuple[str, str, str]:
    """(name, meaning, operator action) of an error code; an unknown code still gets a line."""
    try:
        known = ErrorCode(code)
    except ValueError:
        return str(code), f"Unknown error code {code}.", "Save the service log and call support."
    meaning, action = OPERATOR_TEXT.get(known, ("", ""))
    return known.name, meaning, action
