"""An in-memory serial cable for lockstep runs: two ends with pyserial's non-blocking API.

pyserial's ``loop://`` echoes one end to itself and a pty hands bytes over through the
kernel asynchronously; a lockstep bench needs two ends whose bytes arrive exactly when
written, so runs repeat bit for bit. Each :class:`MemorySerial` end offers what the drivers
use of ``serial.Serial``: ``read(size)`` (returns what is there, never blocks), ``write``,
``in_waiting``, ``reset_input_buffer``, ``close`` and ``is_open``; a closed end raises
``serial.SerialException`` like a vanished device.
"""

from __future__ import annotations

import serial


class MemorySerial:
    """One end of a :func:`memory_serial_pair`."""

    def __init__(self, rx: bytearray, tx: bytearray, name: str) -> None:
        self._rx, self._tx, self.name = rx, tx, name
        self.is_open = True
        self.timeout = 0

    def _check(self) -> None:
        if not self.is_open:
            raise serial.SerialException(f"{self.name}: port is closed")

    def read(self, size: int = 1) -> bytes:
        self._check()
        out = bytes(self._rx[:size])
        del self._rx[:size]
        return out

    def write(self, data: bytes) -> int:
        self._check()
        self._tx += data
        return len(data)

    @property
    def in_waiting(self) -> int:
        self._check()
        return len(self._rx)

    def reset_input_buffer(self) -> None:
        self._rx.clear()

    def flush(self) -> None:
        pass

    def close(self) -> None:
        self.is_open = False


def memory_serial_pair(name: str = "bench-serial") -> tuple[MemorySerial, MemorySerial]:
    """``(flight_end, device_end)``: what one writes, the other reads."""
    a_to_b, b_to_a = bytearray(), bytearray()
    return MemorySerial(b_to_a, a_to_b, f"{name}:flight"), MemorySerial(a_to_b, b_to_a, f"{name}:device")
