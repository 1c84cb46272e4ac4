"""Field side of the cell: Modbus register map, TCP/RTU servers, PLC handshake and simulator."""
