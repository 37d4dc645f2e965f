"""A cross-process python-can bus over Unix domain sockets (``capstan_unix``).

For machines without SocketCAN (no ``vcan`` in the kernel): every bus instance that
opens the same *channel* (a directory, e.g. ``/tmp/capstan-can0``) sees every frame
any other instance sends, like nodes on one CAN bus. Registered with python-can
through the ``can.interface`` entry point, so::

    bus = can.Bus(interface="capstan_unix", channel="/tmp/capstan-can0")

Topology: a full mesh without a broker. Each bus listens on its own
``SOCK_SEQPACKET`` socket ``<channel>/<pid>-<n>.sock`` (message boundaries kept,
reliable, in order) and, while holding an ``flock`` on ``<channel>/.join.lock``,
connects to every bus that joined before it; later buses connect to it. Hence one
connection per pair, and a process that dies simply drops its connections (its
stale socket file is removed by the next joiner). There is no single point of
failure and no thread of its own: frames are read in :meth:`recv`.

Sending never blocks: a frame whose peer buffer is full (the peer stopped reading)
is dropped for that peer and counted in :attr:`UnixSocketBus.tx_dropped` — a dead
reader must not stall the control loop. ``send(msg, timeout=t)`` with ``t > 0`` waits
up to ``t`` seconds for buffer space instead.

Wire format of one frame (one seqpacket): ``<u32 id|flags><u8 length><data>`` with
flags bit 31 extended id, 30 remote, 29 error frame, 28 FD, 27 BRS, 26 ESI.
The receive timestamp (``time.time()`` base) is the kernel's ``SO_TIMESTAMP`` of the
frame's arrival at the receiving socket, as SocketCAN stamps frames on reception.
"""

from __future__ import annotations

import errno
import fcntl
import itertools
import logging
import os
import select
import socket
import struct
import sys
import threading
import time
from collections import deque
from typing import Any

import can
from can import BusABC, CanInitializationError, CanOperationError, Message

logger = logging.getLogger(__name__)

_HDR = struct.Struct("<IB")
_F_EXT = 1 << 31
_F_RTR = 1 << 30
_F_ERR = 1 << 29
_F_FD = 1 << 28
_F_BRS = 1 << 27
_F_ESI = 1 << 26
_ID_MASK = 0x1FFFFFFF
_MAX_PACKET = _HDR.size + 64
_TIMEVAL = struct.Struct("@ll")
#: SO_TIMESTAMP (= SCM_TIMESTAMP); Python does not export it; 29 on Linux x86/arm/riscv
_SO_TIMESTAMP = getattr(socket, "SO_TIMESTAMP", 29 if sys.platform.startswith("linux") else -1)
_CMSG_SPACE = socket.CMSG_SPACE(_TIMEVAL.size)
_counter = itertools.count()


class UnixSocketBus(BusABC):
    """python-can bus shared between processes through a directory of Unix sockets.

    :param channel: directory that names the bus (created if missing).
    :param receive_own_messages: also deliver frames this instance sends to itself.
    :param can_filters: python-can filters (applied in software).
    :raises can.CanInitializationError: if the channel cannot be created or joined.
    """

    #: Socket buffer size requested for each connection [bytes] (capped by the kernel).
    SOCKET_BUFFER_BYTES = 4 << 20

    def __init__(self, channel: Any = "/tmp/capstan-can0", can_filters: Any = None,
                 receive_own_messages: bool = False, fd: bool = True, **kwargs: object) -> None:
        if not channel:
            raise CanInitializationError("capstan_unix: channel (a directory path) is required")
        self.channel = str(channel)
        self.channel_info = f"capstan_unix {self.channel}"
        self._receive_own = bool(receive_own_messages)
        self._pending: deque[Message] = deque()
        self._lock = threading.Lock()
        self._peers: tuple[socket.socket, ...] = ()
        self._by_fd: dict[int, socket.socket] = {}
        #: frames not delivered to some peer because its buffer was full
        self.tx_dropped = 0
        self._closed = False
        try:
            os.makedirs(self.channel, exist_ok=True)
        except OSError as exc:
            raise CanInitializationError(f"capstan_unix: cannot create channel directory "
                                         f"{self.channel!r}: {exc}") from exc
        if not os.path.isdir(self.channel):
            raise CanInitializationError(f"capstan_unix: channel {self.channel!r} is not a directory")
        self._path = os.path.join(self.channel, f"{os.getpid()}-{next(_counter)}.sock")
        self._epoll = select.epoll()
        self._listener = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            self._join()
        except OSError as exc:
            self._listener.close()
            self._epoll.close()
            raise CanInitializationError(f"capstan_unix: cannot join {self.channel!r}: {exc}") from exc
        self._can_protocol = can.CanProtocol.CAN_FD if fd else can.CanProtocol.CAN_20
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)

    # ------------------------------------------------------------------ joining
    def _join(self) -> None:
        lock_path = os.path.join(self.channel, ".join.lock")
        lock_fd = os.open(lock_path, os.O_CREAT | os.O_RDWR, 0o666)
        try:
            fcntl.flock(lock_fd, fcntl.LOCK_EX)
            if os.path.exists(self._path):
                os.unlink(self._path)
            self._listener.bind(self._path)
            self._listener.listen(64)
            self._listener.setblocking(False)
            self._epoll.register(self._listener.fileno(), select.EPOLLIN)
            for name in sorted(os.listdir(self.channel)):
                path = os.path.join(self.channel, name)
                if not name.endswith(".sock") or path == self._path:
                    continue
                sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
                try:
                    sock.connect(path)
                except OSError as exc:
                    sock.close()
                    if exc.errno in (errno.ECONNREFUSED, errno.ENOENT):
                        logger.debug("removing stale socket %s", path)
                        try:
                            os.unlink(path)
                        except OSError:
                            pass
                        continue
                    raise
                self._add_peer(sock)
        finally:
            fcntl.flock(lock_fd, fcntl.LOCK_UN)
            os.close(lock_fd)

    def _add_peer(self, sock: socket.socket) -> None:
        for opt in (socket.SO_SNDBUF, socket.SO_RCVBUF):
            try:
                sock.setsockopt(socket.SOL_SOCKET, opt, self.SOCKET_BUFFER_BYTES)
            except OSError:
                pass
        try:  # kernel receive timestamps, as SocketCAN gives them
            if _SO_TIMESTAMP > 0:
                sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMP, 1)
        except OSError:
            pass
        sock.setblocking(False)
        with self._lock:
            self._by_fd[sock.fileno()] = sock
            self._peers = self._peers + (sock,)
            self._epoll.register(sock.fileno(), select.EPOLLIN | select.EPOLLRDHUP)

    def _drop_peer(self, sock: socket.socket) -> None:
        with self._lock:
            if sock not in self._peers:
                return
            self._peers = tuple(s for s in self._peers if s is not sock)
            fd = sock.fileno()
            self._by_fd.pop(fd, None)
            try:
                self._epoll.unregister(fd)
            except (OSError, ValueError):
                pass
        sock.close()

    def _accept_all(self) -> None:
        while True:
            try:
                sock, _ = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            self._add_peer(sock)

    @property
    def peer_count(self) -> int:
        """Number of other bus instances currently connected (after pending accepts)."""
        if not self._closed:
            self._accept_all()
        return len(self._peers)

    # ------------------------------------------------------------------ sending
    @staticmethod
    def _encode(msg: Message) -> bytes:
        word = msg.arbitration_id & _ID_MASK
        if msg.is_extended_id:
            word |= _F_EXT
        if msg.is_remote_frame:
            word |= _F_RTR
        if msg.is_error_frame:
            word |= _F_ERR
        if msg.is_fd:
            word |= _F_FD
            if msg.bitrate_switch:
                word |= _F_BRS
            if msg.error_state_indicator:
                word |= _F_ESI
        data = bytes(msg.data) if msg.data is not None else b""
        length = msg.dlc if msg.is_remote_frame else len(data)
        return _HDR.pack(word, length) + data

    def send(self, msg: Message, timeout: float | None = None) -> None:
        """Deliver ``msg`` to every other bus instance on the channel.

        :param timeout: ``None`` or 0: never wait (a full peer drops the frame, counted
            in :attr:`tx_dropped`); ``> 0``: wait up to this long for buffer space.
        :raises can.CanOperationError: if the bus is shut down or the frame is invalid.
        """
        if self._closed:
            raise CanOperationError("capstan_unix: bus is shut down")
        if msg.data is not None and len(msg.data) > (64 if msg.is_fd else 8):
            raise CanOperationError(f"capstan_unix: {len(msg.data)} data bytes do not fit a frame")
        packet = self._encode(msg)
        self._accept_all()
        for sock in self._peers:
            try:
                sock.send(packet)
            except (BlockingIOError, InterruptedError):
                if timeout and self._wait_writable(sock, timeout):
                    try:
                        sock.send(packet)
                        continue
                    except OSError:
                        pass
                self.tx_dropped += 1
            except OSError:
                self._drop_peer(sock)
        if self._receive_own:
            own = Message(timestamp=time.time(), arbitration_id=msg.arbitration_id,
                          is_extended_id=msg.is_extended_id, is_remote_frame=msg.is_remote_frame,
                          is_error_frame=msg.is_error_frame, is_fd=msg.is_fd,
                          bitrate_switch=msg.bitrate_switch, dlc=msg.dlc,
                          data=bytes(msg.data or b""), channel=self.channel, is_rx=False)
            self._pending.append(own)

    @staticmethod
    def _wait_writable(sock: socket.socket, timeout_s: float) -> bool:
        try:
            _, w, _ = select.select([], [sock], [], timeout_s)
        except (OSError, ValueError):
            return False
        return bool(w)

    # ---------------------------------------------------------------- receiving
    def _read_sock(self, sock: socket.socket, now: float) -> None:
        while True:
            try:
                packet, ancdata, _, _ = sock.recvmsg(_MAX_PACKET, _CMSG_SPACE)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                self._drop_peer(sock)
                return
            if not packet:
                self._drop_peer(sock)
                return
            if len(packet) < _HDR.size:
                continue
            stamp = now
            for level, kind, cdata in ancdata:
                if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMP and len(cdata) >= _TIMEVAL.size:
                    sec, usec = _TIMEVAL.unpack_from(cdata)
                    stamp = sec + usec * 1e-6
            word, length = _HDR.unpack_from(packet)
            is_fd = bool(word & _F_FD)
            is_rtr = bool(word & _F_RTR)
            data = packet[_HDR.size:]
            self._pending.append(Message(
                timestamp=stamp, arbitration_id=word & _ID_MASK,
                is_extended_id=bool(word & _F_EXT), is_remote_frame=is_rtr,
                is_error_frame=bool(word & _F_ERR), is_fd=is_fd,
                bitrate_switch=bool(word & _F_BRS), error_state_indicator=bool(word & _F_ESI),
                dlc=length if is_rtr else len(data), data=None if is_rtr else data,
                channel=self.channel, is_rx=True, check=False))

    def _recv_internal(self, timeout: float | None) -> tuple[Message | None, bool]:
        if self._pending:
            return self._pending.popleft(), False
        if self._closed:
            raise CanOperationError("capstan_unix: bus is shut down")
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            if deadline is None:
                wait = -1.0
            else:
                wait = max(0.0, deadline - time.monotonic())
            try:
                events = self._epoll.poll(wait)
            except InterruptedError:
                events = []
            except (OSError, ValueError) as exc:
                if self._closed:
                    return None, False
                raise CanOperationError(f"capstan_unix: poll failed: {exc}") from exc
            now = time.time()
            lfd = self._listener.fileno() if not self._closed else -1
            for fd, ev in events:
                if fd == lfd:
                    self._accept_all()
                    continue
                sock = self._by_fd.get(fd)
                if sock is None:
                    continue
                self._read_sock(sock, now)
                if ev & (select.EPOLLHUP | select.EPOLLRDHUP | select.EPOLLERR):
                    self._read_sock(sock, now)
                    self._drop_peer(sock)
            if self._pending:
                return self._pending.popleft(), False
            if deadline is not None and time.monotonic() >= deadline:
                return None, False

    def fileno(self) -> int:
        """The epoll descriptor (readable when a frame or a new peer is waiting)."""
        return self._epoll.fileno()

    def shutdown(self) -> None:
        """Leave the channel: close all connections and remove this bus's socket file."""
        if self._closed:
            return
        self._closed = True
        super().shutdown()
        for sock in self._peers:
            try:
                sock.close()
            except OSError:
                pass
        self._peers = ()
        self._by_fd.clear()
        try:
            self._listener.close()
        finally:
            try:
                os.unlink(self._path)
            except OSError:
                pass
            self._epoll.close()

    @staticmethod
    def _detect_available_configs() -> list[dict[str, Any]]:
        out: list[dict[str, Any]] = []
        try:
            names = os.listdir("/tmp")
        except OSError:
            return out
        for name in sorted(names):
            if name.startswith("capstan-can") and os.path.isdir(os.path.join("/tmp", name)):
                out.append({"interface": "capstan_unix", "channel": os.path.join("/tmp", name)})
        return out
