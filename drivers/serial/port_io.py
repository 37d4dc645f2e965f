"""Non-blocking reads from a pyserial port for the per-cycle ``poll()`` of serial drivers.

On POSIX, pyserial opens the device with ``O_NONBLOCK`` and VMIN = VTIME = 0; reading
the file descriptor directly costs one ``read`` system call (returning ``b""`` when
nothing is there) instead of pyserial's ``ioctl(TIOCINQ)`` + ``select`` + ``read`` +
``select``. Ports without a usable descriptor (``serial_for_url`` test ports, fakes)
use ``in_waiting``/``read``.

A device that disappears (USB unplugged, pty master closed) then reads as "no data"
rather than an error; the daemon's sensor-freshness check (``safety.*_timeout_s``)
turns that into a fault within one timeout.
"""

from __future__ import annotations

import os
from typing import Any

#: bytes read per call at most (a 1 ms cycle sees ~20-60 bytes; a stall a few kB)
READ_SIZE = 65536


def port_fd(port: Any) -> int:
    """File descriptor to read without blocking, or -1 to use the pyserial API."""
    fileno = getattr(port, "fileno", None)
    if fileno is None or getattr(port, "fd", None) is None:
        return -1
    try:
        fd = int(fileno())
    except (OSError, ValueError, TypeError, AttributeError):
        return -1
    try:
        import fcntl

        if not fcntl.fcntl(fd, fcntl.F_GETFL) & os.O_NONBLOCK:
            return -1
    except OSError:
        return -1
    return fd


def read_available(port: Any, fd: int) -> bytes:
    """All bytes available now (possibly ``b""``); never blocks.

    :raises OSError: if the device fails (e.g. unplugged: EIO, or pyserial's
        ``SerialException``, which derives from OSError).
    """
    if fd >= 0:
        try:
            return os.read(fd, READ_SIZE)
        except (BlockingIOError, InterruptedError):
            return b""
    n = port.in_waiting
    return port.read(n) if n else b""
