"""The serial side of simulated devices: a raw pty pair, a non-blocking endpoint, fault injection.

A simulated device writes the real device's bytes into the master side of a pty pair
(``os.openpty``); the driver opens the slave path with pyserial exactly as it would
open ``/dev/ttyUSB0``. The pair shares one termios, so the device side can read the
line rate the driver set (:meth:`DeviceEndpoint.line_baudrate`).
"""

from __future__ import annotations

import fcntl
import os
import random
import termios
import tty
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

from capstan.drivers.serial.xsens_config import BAUD_CODES

#: bytes a simulated device queues while the reader lags; beyond that frames are dropped
MAX_PENDING_BYTES = 65536


@dataclass
class PtyPair:
    """A pseudo-terminal pair: the device writes ``master_fd``, the driver opens ``slave_path``.

    ``slave_fd`` is kept open so that the master never sees EIO between driver sessions.
    """

    master_fd: int
    slave_fd: int
    slave_path: str

    def close(self) -> None:
        """Close both ends (idempotent)."""
        for fd in (self.master_fd, self.slave_fd):
            try:
                os.close(fd)
            except OSError:
                pass
        self.master_fd = self.slave_fd = -1


def open_pty_pair() -> PtyPair:
    """Open a raw (no echo, no line editing, 8-bit clean), non-blocking pty pair.

    :raises OSError: if the system has no free pseudo-terminal.
    """
    master, slave = os.openpty()
    tty.setraw(slave)
    fl = fcntl.fcntl(master, fcntl.F_GETFL)
    fcntl.fcntl(master, fcntl.F_SETFL, fl | os.O_NONBLOCK)
    return PtyPair(master, slave, os.ttyname(slave))


class SerialFault(IntEnum):
    """Faults a simulated device can inject into its next frames."""

    CORRUPT_CHECKSUM = 1
    TRUNCATE = 2
    GARBAGE = 3
    DROP_COUNTER = 4


#: termios speed constant -> line rate [Bd]
_SPEEDS = {getattr(termios, f"B{bd}"): bd for bd in BAUD_CODES if hasattr(termios, f"B{bd}")}


class DeviceEndpoint:
    """Non-blocking byte pipe over a pty master fd, a device path or a pyserial port."""

    def __init__(self, fd_or_port: int | str | Any) -> None:
        self._fd = -1
        self._port: Any = None
        if isinstance(fd_or_port, int):
            self._fd = fd_or_port
            fl = fcntl.fcntl(self._fd, fcntl.F_GETFL)
            fcntl.fcntl(self._fd, fcntl.F_SETFL, fl | os.O_NONBLOCK)
        elif isinstance(fd_or_port, str):
            import serial

            self._port = serial.Serial(fd_or_port, timeout=0)
        else:
            self._port = fd_or_port
        self._pending = bytearray()
        self.dropped_bytes = 0

    def line_baudrate(self) -> int | None:
        """Line rate the host set on the pty [Bd]; None if unknown (not a pty, odd speed)."""
        if self._fd < 0:
            return None
        try:
            speed = termios.tcgetattr(self._fd)[5]
        except termios.error:
            return None
        return _SPEEDS.get(speed)

    def read_available(self) -> bytes:
        if self._port is not None:
            n = self._port.in_waiting
            return self._port.read(n) if n else b""
        try:
            return os.read(self._fd, 65536)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:  # EIO: no reader/writer on the other side
            return b""

    def write(self, data: bytes) -> None:
        if len(self._pending) + len(data) > MAX_PENDING_BYTES:
            self.dropped_bytes += len(data)
        else:
            self._pending += data
        self.flush()

    def flush(self) -> None:
        if not self._pending:
            return
        if self._port is not None:
            self._port.write(bytes(self._pending))
            self._pending.clear()
            return
        try:
            n = os.write(self._fd, self._pending)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            n = len(self._pending)
            self.dropped_bytes += n
        del self._pending[:n]


class FaultInjector:
    def __init__(self, seed: int) -> None:
        self._faults: list[SerialFault] = []
        self.rng = random.Random(seed)

    def inject_fault(self, fault: SerialFault, count: int = 1) -> None:
        """Apply ``fault`` to each of the next ``count`` emitted frames."""
        self._faults += [SerialFault(fault)] * count

    def _next_fault(self) -> SerialFault | None:
        return self._faults.pop(0) if self._faults else None

    def _damage(self, frame: bytes, fault: SerialFault | None) -> bytes:
        if fault == SerialFault.CORRUPT_CHECKSUM:
            return frame[:-1] + bytes((frame[-1] ^ 0x5A,))
        if fault == SerialFault.TRUNCATE:
            return frame[:max(2, len(frame) // 2)]
        if fault == SerialFault.GARBAGE:
            return self.rng.randbytes(self.rng.randint(1, 40)) + frame
        return frame
