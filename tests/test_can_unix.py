"""Cross-process python-can bus over Unix sockets (``capstan_unix``)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import textwrap
import time

import can
import pytest

from capstan.drivers.can_unix import UnixSocketBus


@pytest.fixture
def channel(tmp_path):
    return str(tmp_path / "can0")


def _msg(can_id: int, data: bytes = b"", **kw) -> can.Message:
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=kw.pop("ext", False), **kw)


def test_loaded_through_python_can_entry_point(channel):
    with can.Bus(interface="capstan_unix", channel=channel) as bus:
        assert isinstance(bus, UnixSocketBus)


def test_every_other_instance_receives_each_frame_once(channel):
    a, b, c = (UnixSocketBus(channel) for _ in range(3))
    try:
        a.send(_msg(0x181, b"\x01\x02\x03"))
        for bus in (b, c):
            got = bus.recv(1.0)
            assert got.arbitration_id == 0x181 and bytes(got.data) == b"\x01\x02\x03"
            assert not got.is_extended_id and got.is_rx
            assert bus.recv(0.05) is None  # exactly once
        assert a.recv(0.05) is None  # not to itself by default
    finally:
        for bus in (a, b, c):
            bus.shutdown()


def test_flags_extended_remote_fd_survive(channel):
    a, b = UnixSocketBus(channel), UnixSocketBus(channel)
    try:
        a.send(_msg(0x1ABCDEF0, b"\xff", ext=True))
        a.send(can.Message(arbitration_id=0x701, is_remote_frame=True, dlc=1, is_extended_id=False))
        a.send(can.Message(arbitration_id=0x10, data=bytes(range(64)), is_fd=True, bitrate_switch=True,
                           is_extended_id=False))
        m1, m2, m3 = b.recv(1), b.recv(1), b.recv(1)
        assert m1.is_extended_id and m1.arbitration_id == 0x1ABCDEF0 and bytes(m1.data) == b"\xff"
        assert m2.is_remote_frame and m2.dlc == 1 and m2.arbitration_id == 0x701
        assert m3.is_fd and m3.bitrate_switch and bytes(m3.data) == bytes(range(64))
    finally:
        a.shutdown()
        b.shutdown()


def test_order_kept_and_nothing_lost_in_a_burst(channel):
    a, b = UnixSocketBus(channel), UnixSocketBus(channel)
    try:
        n = 2000
        for i in range(n):
            a.send(_msg(0x200, i.to_bytes(4, "little")))
        got = [int.from_bytes(b.recv(1.0).data, "little") for _ in range(n)]
        assert got == list(range(n))
        assert a.tx_dropped == 0
    finally:
        a.shutdown()
        b.shutdown()


def test_receive_own_messages(channel):
    with UnixSocketBus(channel, receive_own_messages=True) as a:
        a.send(_msg(0x80, b"\x00"))
        m = a.recv(0.5)
        assert m is not None and m.arbitration_id == 0x80 and not m.is_rx


def test_a_reader_that_stopped_does_not_block_the_sender(channel):
    a, b = UnixSocketBus(channel), UnixSocketBus(channel)
    try:
        t0 = time.perf_counter()
        for _ in range(50_000):
            a.send(_msg(0x200, b"12345678"))
        assert time.perf_counter() - t0 < 20.0
        assert a.tx_dropped > 0  # b never read: its buffer filled, frames were dropped, no hang
    finally:
        a.shutdown()
        b.shutdown()


def test_stale_socket_file_is_removed_and_dead_peer_forgotten(channel):
    os.makedirs(channel)
    stale = os.path.join(channel, "99999-0.sock")
    s = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    s.bind(stale)
    s.close()  # file remains, nobody listens
    a, b = UnixSocketBus(channel), UnixSocketBus(channel)
    try:
        assert not os.path.exists(stale)
        assert a.peer_count == 1
        b.shutdown()
        a.send(_msg(0x1))
        assert a.peer_count == 0
    finally:
        a.shutdown()
        b.shutdown()
    assert [n for n in os.listdir(channel) if n.endswith(".sock")] == []


def test_two_processes_exchange_frames(channel):
    code = textwrap.dedent(f"""
        import can
        bus = can.Bus(interface="capstan_unix", channel={channel!r})
        print("ready", flush=True)
        for _ in range(100):
            m = bus.recv(5.0)
            bus.send(can.Message(arbitration_id=m.arbitration_id + 1, data=m.data, is_extended_id=False))
        bus.shutdown()
    """)
    env = dict(os.environ)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout.readline().strip() == "ready"
        with UnixSocketBus(channel) as bus:
            for i in range(100):
                bus.send(_msg(0x600, bytes([i])))
                reply = bus.recv(2.0)
                assert reply is not None and reply.arbitration_id == 0x601 and reply.data[0] == i
        assert proc.wait(10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()


@pytest.mark.slow
def test_processes_joining_at_once_get_exactly_one_link_per_pair(channel):
    code = textwrap.dedent(f"""
        import sys, time, can
        me = int(sys.argv[1])
        bus = can.Bus(interface="capstan_unix", channel={channel!r})
        print("ready", flush=True)
        sys.stdin.readline()
        bus.send(can.Message(arbitration_id=0x100 + me, is_extended_id=False))
        got = []
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            m = bus.recv(0.05)
            if m is not None:
                got.append(m.arbitration_id)
        print(sorted(got), flush=True)
        bus.shutdown()
    """)
    procs = [subprocess.Popen([sys.executable, "-c", code, str(k)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True) for k in range(4)]
    try:
        for p in procs:
            assert p.stdout.readline().strip() == "ready"
        for p in procs:
            p.stdin.write("go\n")
            p.stdin.flush()
        for k, p in enumerate(procs):
            got = eval(p.stdout.readline())
            assert got == sorted(0x100 + j for j in range(4) if j != k)  # each other frame, once
            assert p.wait(10) == 0
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()


def test_timestamp_is_the_arrival_time_not_the_read_time(channel):
    a, b = UnixSocketBus(channel), UnixSocketBus(channel)
    try:
        t_send = time.time()
        a.send(_msg(0x181, b"\x01"))
        time.sleep(0.1)
        m = b.recv(0)
        t_read = time.time()
        assert t_send <= m.timestamp < t_read - 0.05   # stamped on arrival (kernel), read 100 ms later
    finally:
        a.shutdown()
        b.shutdown()
