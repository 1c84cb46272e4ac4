"""A Modbus master over pymodbus' synchronous client (TCP or RTU): the raw register access of the simulated
PLC (firmware_io.plc_sim), also used by tests for malformed requests. The controller's own server is thus
tested against a master this package did not write."""

from __future__ import annotations

from typing import Any

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ModbusException
from pymodbus.framer import FramerType

from firmware_io.endpoints import Endpoint, SerialEndpoint, check_unit_id
from firmware_io.plc_readings import ModbusRequestError, PlcSimError


class ModbusMaster:
    """Function codes 3, 6 and 16 towards one unit; PlcSimError when the controller does not answer."""

    def __init__(self, endpoint: Endpoint, unit_id: int, response_timeout_s: float) -> None:
        self._endpoint = endpoint
        self._unit_id = check_unit_id(unit_id, endpoint)
        self._client = _make_client(endpoint, response_timeout_s)

    def close(self) -> None:
        """Drop the connection (the controller must carry on as if the PLC went away)."""
        self._client.close()

    def _connect_client(self) -> None:
        if not self._client.connect():
            raise PlcSimError(f"cannot connect to the controller at {self._endpoint} (is `cellctl run` running?)")

    def read_registers(self, address: int, count: int) -> list[int]:
        """Function code 3; ModbusRequestError on an exception response."""
        response = self._execute(self._client.read_holding_registers, address, count=count)
        if response.isError():
            raise ModbusRequestError(f"reading {count} registers at {address}", response.exception_code)
        return list(response.registers)

    def write_register(self, address: int, value: int) -> None:
        """Function code 6; ModbusRequestError on an exception response."""
        response = self._execute(self._client.write_register, address, value)
        if response.isError():
            raise ModbusRequestError(f"writing {value} to register {address}", response.exception_code)

    def write_registers(self, address: int, values: list[int]) -> None:
        """Function code 16; ModbusRequestError on an exception response."""
        response = self._execute(self._client.write_registers, address, values)
        if response.isError():
            raise ModbusRequestError(f"writing {len(values)} registers at {address}", response.exception_code)

    def _execute(self, request: Any, *args: Any, **kwargs: Any) -> Any:
        try:
            return request(*args, device_id=self._unit_id, **kwargs)
        except ModbusException as exc:  # connection refused or lost, no answer within the timeout
            raise PlcSimError(f"no answer from the controller at {self._endpoint}: {exc}") from exc


def _make_client(endpoint: Endpoint, timeout_s: float) -> ModbusTcpClient | ModbusSerialClient:
    # retries=0: a PLC that gets no answer reports it; silent retries would hide a slow controller.
    if isinstance(endpoint, SerialEndpoint):
        return ModbusSerialClient(
            endpoint.port,
            framer=FramerType.RTU,
            baudrate=endpoint.baudrate,
            parity=endpoint.parity,
            stopbits=endpoint.stopbits,
            bytesize=endpoint.bytesize,
            timeout=timeout_s,
            retries=0,
        )
    return ModbusTcpClient(endpoint.host, port=endpoint.port, timeout=timeout_s, retries=0)
