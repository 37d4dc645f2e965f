"""MCAP logging: schema/codec, file round trip, rotation, the writer process, signals,
kills and drops. Uses its own record dtypes (the logging code is generic)."""

from __future__ import annotations

import signal
import struct
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import NonSeekingReader, make_reader

from capstan.controller.log.reader import read_log, read_logs
from capstan.controller.log.writer import LIVE_ZSTD_LEVEL, LogSession
from capstan.controller.log.mcap_log import DEFAULT_FLUSH_INTERVAL_S, EventKind, McapLog
from capstan.controller.log.schema import LogFormatError, build_layout

DT = np.dtype([("t_s", "<f8"), ("tau_in_Nm", "<f8"), ("q_out_rad", "<f8"), ("x32", "<f4"),
               ("i16", "<i2"), ("i32", "<i4"), ("u8f", "<u1"), ("u64", "<u8"), ("i64", "<i8"),
               ("ok", "?"), ("fault_bits", "<u4")])
STATS = np.dtype([("t_s", "<f8"), ("overruns", "<u4"), ("jitter_p99_s", "<f8")])


def make_records(n: int, t0: float = 100.0, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    r = np.zeros(n, DT)
    k = np.arange(n)
    r["t_s"] = t0 + k * 1e-3
    r["tau_in_Nm"] = np.sin(k * 1e-3) + rng.normal(0, 0.01, n)
    r["q_out_rad"] = rng.normal(0, 1, n)
    r["q_out_rad"][:3] = [np.nan, np.inf, -0.0]          # odd values survive bit for bit
    r["x32"] = rng.normal(0, 1, n).astype(np.float32)
    r["i16"] = rng.integers(-32768, 32767, n)
    r["i32"] = rng.integers(-2**31, 2**31 - 1, n)
    r["u8f"] = k % 256
    r["u64"] = np.uint64(2**64 - 1) - k.astype(np.uint64)
    r["i64"] = -(k.astype(np.int64) << 33)
    r["ok"] = k % 3 == 0
    r["fault_bits"] = k % 7
    return r


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.tobytes() == b.tobytes()


# ---------------------------------------------------------------- schema / codec
def _parse_proto(buf: bytes) -> dict[int, tuple[int, bytes]]:
    """Independent minimal protobuf wire parser: field number -> (wire type, raw value)."""
    out, pos = {}, 0
    while pos < len(buf):
        key, shift = 0, 0
        while True:
            b = buf[pos]; pos += 1
            key |= (b & 0x7F) << shift; shift += 7
            if not b & 0x80:
                break
        num, wt = key >> 3, key & 7
        size = {0: 1, 1: 8, 5: 4}[wt]
        out[num] = (wt, buf[pos:pos + size]); pos += size
    return out


def test_protobuf_wire_format_by_independent_parser() -> None:
    r = make_records(5)
    layout = build_layout(DT)
    msg = layout.encode(r)[4].tobytes()
    f = _parse_proto(msg)
    assert sorted(f) == list(range(1, len(DT.names) + 1))
    assert f[1] == (1, struct.pack("<d", r["t_s"][4]))
    assert f[4] == (5, struct.pack("<f", r["x32"][4]))
    assert f[5] == (5, struct.pack("<i", r["i16"][4]))             # widened to sfixed32
    assert f[8] == (1, struct.pack("<Q", r["u64"][4]))
    assert f[10] == (0, bytes([int(r["ok"][4])]))                   # bool varint
    assert same_bits(layout.decode(layout.encode(r).tobytes()), r)


def test_schema_is_a_valid_file_descriptor_set() -> None:
    descriptor_pb2 = pytest.importorskip("google.protobuf.descriptor_pb2")
    fds = descriptor_pb2.FileDescriptorSet.FromString(build_layout(DT).schema)
    msg = fds.file[0].message_type[0]
    assert fds.file[0].package == "capstan" and msg.name == "Cycle"
    assert [f.name for f in msg.field] == list(DT.names)
    assert [f.type for f in msg.field][:5] == [1, 1, 1, 2, 15]


def test_unloggable_dtypes_rejected_naming_the_field() -> None:
    with pytest.raises(LogFormatError, match="field 'v'"):
        build_layout(np.dtype([("t_s", "<f8"), ("v", "<f8", (3,))]))
    with pytest.raises(LogFormatError, match="field 's'"):
        build_layout(np.dtype([("s", "S4")]))
    layout = build_layout(DT)
    with pytest.raises(LogFormatError, match="multiple"):
        layout.decode(b"\0" * (layout.message_size + 1))


# ---------------------------------------------------------------- file round trip
def test_file_round_trip_bit_exact_with_events_stats_and_config(tmp_path: Path) -> None:
    r = make_records(5000)
    cfg = "controller:\n  kp: 1.5\n"
    log = McapLog(tmp_path, "t", DT, cfg, stats_dtype=STATS, chunk_size_bytes=64 << 10)
    log.write_records(r[:2000])
    log.write_records(r[2000:])
    st = np.zeros(2, STATS); st["t_s"] = [100.5, 101.5]; st["overruns"] = [0, 3]
    log.write_stats(st)
    log.write_event(104.0, EventKind.FAULT, "stale imu", code=5, last_cycles=r[3995:4001])
    log.close()
    data = read_log(log.current_file)
    assert not data.truncated
    assert same_bits(data.records, r)
    assert data.config == {"controller": {"kp": 1.5}} and data.config_yaml == cfg
    assert same_bits(data.stats, st)
    ev = data.events[0]
    assert ev["kind"] == EventKind.FAULT and ev["reason"] == "stale imu" and ev["code"] == 5
    assert same_bits(data.event_cycles(ev), r[3995:4001])
    # a standard reader sees a valid summary, protobuf schema and ns times from t_s
    with open(log.current_file, "rb") as fh:
        reader = make_reader(fh)
        summ = reader.get_summary()
        assert summ is not None and summ.statistics.message_count == 5000 + 2 + 1
        assert summ.schemas[1].encoding == "protobuf" and summ.schemas[1].name == "capstan.Cycle"
        times = [m.log_time for _, ch, m in reader.iter_messages(topics=["/capstan/cycle"])]
    assert times[10] == round(r["t_s"][10] * 1e9) and len(times) == 5000


def test_rotation_by_size_and_time(tmp_path: Path) -> None:
    r = make_records(20000)
    log = McapLog(tmp_path / "s", "s", DT, rotate_size_bytes=150_000, flush_interval_s=0,
                  chunk_size_bytes=32 << 10)
    for i in range(0, len(r), 500):
        log.write_records(r[i:i + 500])
        log.tick()
    log.close()
    assert len(log.files) >= 3
    for f in log.files[:-1]:
        assert f.stat().st_size < 150_000 + 60_000       # one batch/chunk past the threshold
    assert same_bits(read_logs(log.files).records, r)
    tlog = McapLog(tmp_path / "t", "t", DT, rotate_time_s=10.0)
    t0 = time.monotonic()
    tlog.write_records(r[:10]); tlog.tick(t0 + 5.0)
    tlog.write_records(r[10:20]); tlog.tick(t0 + 10.5)
    tlog.write_records(r[20:30]); tlog.close()
    assert len(tlog.files) == 2
    assert same_bits(read_log(tlog.files[1]).records, r[20:30])
    assert read_log(tlog.files[1]).meta["file_index"] == "1"


def test_open_chunk_reaches_the_file_within_the_flush_interval(tmp_path: Path) -> None:
    """What a kill of the writer can lose: the open chunk (at most the flush interval of
    records) plus the time to compress it; the default keeps that under 1 s."""
    r = make_records(400 + int(1000 * DEFAULT_FLUSH_INTERVAL_S))
    log = McapLog(tmp_path, "p", DT, zstd_level=LIVE_ZSTD_LEVEL)
    t0 = time.monotonic()
    assert log.flush_interval_s == DEFAULT_FLUSH_INTERVAL_S
    log.write_records(r[:400])
    log.tick(t0 + 0.5 * DEFAULT_FLUSH_INTERVAL_S)
    assert len(read_log(log.current_file).records) == 0              # chunk still open
    log.tick(t0 + DEFAULT_FLUSH_INTERVAL_S + 0.01)
    assert same_bits(read_log(log.current_file).records, r[:400])   # closed and on disk
    log.write_records(r[400:])
    log.flush()                          # one interval's worth of 1 kHz records
    assert same_bits(read_log(log.current_file).records, r)
    log.close()
    # the interval leaves room for the compression under 1 s (its time on this host is a figure:
    # tests/bench_latency.py, not a bound a loaded machine could break)
    assert DEFAULT_FLUSH_INTERVAL_S + 0.005 < 1.0


def test_file_cut_inside_a_message_index_keeps_complete_chunks(tmp_path: Path) -> None:
    r = make_records(3000)
    log = McapLog(tmp_path, "c", DT, flush_interval_s=0)
    for i in range(0, 3000, 1000):
        log.write_records(r[i:i + 1000])
        log.flush()                                     # three chunks, each with its index
    log.close()
    data = log.current_file.read_bytes()
    with open(log.current_file, "rb") as fh:
        last = make_reader(fh).get_summary().chunk_indexes[-1]
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:last.chunk_start_offset + last.chunk_length + 40])   # inside its index
    got = read_log(cut)
    assert got.truncated and same_bits(got.records, r)


def test_float32_storage_option(tmp_path: Path) -> None:
    r = make_records(1000)
    log = McapLog(tmp_path, "f", DT, float32_fields=("tau_in_Nm",))
    log.write_records(r)
    log.close()
    got = read_log(log.current_file).records
    assert got.dtype == DT
    np.testing.assert_array_equal(got["tau_in_Nm"], r["tau_in_Nm"].astype(np.float32).astype(np.float64))
    assert np.any(got["tau_in_Nm"] != r["tau_in_Nm"])                     # really rounded
    rest = [n for n in DT.names if n != "tau_in_Nm"]
    assert all(got[n].tobytes() == r[n].tobytes() for n in rest)
    with pytest.raises(LogFormatError, match="float32 field 'i32'"):
        build_layout(DT, float32_fields=("i32",))
    with pytest.raises(LogFormatError, match="float32 field 'nope'"):
        LogSession(DT, tmp_path, float32_fields=("nope",))


# ---------------------------------------------------------------- writer process
def _pace(session: LogSession, r: np.ndarray, rate_hz: float) -> None:
    t0 = time.monotonic()
    for i in range(len(r)):
        assert session.push(r[i:i + 1])
        delay = t0 + (i + 1) / rate_hz - time.monotonic()
        if delay > 0:
            time.sleep(delay)


def test_session_fault_and_clean_close(tmp_path: Path) -> None:
    r = make_records(3000)
    s = LogSession(DT, tmp_path, "controller: {kp: 2}\n", capacity=4096, fault_history_n=50,
                   stats_dtype=STATS)
    st = np.zeros(3, STATS)
    st["t_s"], st["overruns"], st["jitter_p99_s"] = [100.5, 101.5, 102.5], [0, 1, 2], [1e-5, 2e-5, 3e-5]
    s.start()
    try:
        for i in range(2000):
            s.push(r[i:i + 1])
            if i % 1000 == 500:
                s.push_stats(st[i // 1000])
        s.fault(float(r["t_s"][1999]), "NaN in tau_in", code=0x4)
        for i in range(2000, 3000):
            s.push(r[i:i + 1])
        s.push_stats(st[2])
    finally:
        assert s.close(timeout_s=20) == 0
    files = sorted(tmp_path.glob("*.mcap"))
    data = read_log(files[0])
    assert not data.truncated and same_bits(data.records, r) and data.config["controller"]["kp"] == 2
    faults = [e for e in data.events if e["kind"] == EventKind.FAULT]
    assert len(faults) == 1 and faults[0]["code"] == 4
    assert same_bits(data.event_cycles(faults[0]), r[1950:2000])   # last 50 up to the fault
    assert same_bits(data.stats, st)
    assert not Path(s.cycle.name).exists()                         # ring file removed


def test_sigterm_closes_valid_file(tmp_path: Path) -> None:
    r = make_records(1500)
    s = LogSession(DT, tmp_path)
    s.start()
    _pace(s, r[:500], 2000.0)
    s.proc.send_signal(signal.SIGINT)      # Ctrl-C reaches the process group: ignored,
    _pace(s, r[500:1000], 2000.0)          # the daemon decides when logging ends
    time.sleep(0.3)
    assert s.proc.poll() is None
    s.proc.send_signal(signal.SIGTERM)
    assert s.proc.wait(timeout=20) == 0
    s.close()
    f = sorted(tmp_path.glob("*.mcap"))[0]
    with open(f, "rb") as fh:
        assert make_reader(fh).get_summary() is not None
    assert same_bits(read_log(f).records, r[:1000])


def test_sigkill_of_writer_loses_at_most_one_second(tmp_path: Path) -> None:
    r = make_records(2500)
    s = LogSession(DT, tmp_path, flush_interval_s=0.5)
    s.start()
    try:
        _pace(s, r, 1000.0)                  # 2.5 s of a 1 kHz loop
        s.proc.kill()
        s.proc.wait(timeout=10)
    finally:
        s.close()
    f = sorted(tmp_path.glob("*.mcap"))[0]
    data = read_log(f)
    # the session restarted the writer at close, which rewrote the cut file (valid, indexed)
    assert not data.truncated
    with open(f, "rb") as fh:
        assert make_reader(fh).get_summary().statistics.channel_message_counts
    n = len(data.records)
    assert same_bits(data.records, r[:n])                      # a clean prefix
    lost_s = r["t_s"][-1] - data.records["t_s"][-1]
    assert lost_s <= 1.0, f"lost {lost_s:.3f} s of log"
    # mcap's own streaming reader also reads the cut file up to the damage
    got = 0
    with open(f, "rb") as fh:
        try:
            for _ in NonSeekingReader(fh).iter_messages(topics=["/capstan/cycle"], log_time_order=False):
                got += 1
        except Exception:
            pass
    assert got >= n


def test_daemon_sigkill_writer_closes_file(tmp_path: Path) -> None:
    """A 'daemon' process logs at 1 kHz and is SIGKILLed; the writer notices, writes
    everything that was in the ring plus a PRODUCER_LOST event and a valid summary."""
    code = textwrap.dedent(f"""
        import os, signal, sys, time
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_log_writer import DT, make_records, _pace
        from capstan.controller.log.writer import LIVE_ZSTD_LEVEL, LogSession
        s = LogSession(DT, {str(tmp_path)!r})
        s.start()
        print(s.proc.pid, flush=True)
        _pace(s, make_records(1200), 1000.0)
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    daemon = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    writer_pid = int(daemon.stdout.readline())
    daemon.wait(timeout=30)
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and Path(f"/proc/{writer_pid}").exists():
        time.sleep(0.05)
    assert not Path(f"/proc/{writer_pid}").exists(), "writer did not exit after the daemon died"
    data = read_log(sorted(tmp_path.glob("*.mcap"))[0])
    assert not data.truncated
    assert same_bits(data.records, make_records(1200))
    assert data.events[-1]["kind"] == EventKind.PRODUCER_LOST


def test_drops_are_counted_and_logged(tmp_path: Path) -> None:
    r = make_records(300)
    s = LogSession(DT, tmp_path, capacity=128)
    ok = [s.push(r[i:i + 1]) for i in range(300)]      # writer not running yet: ring fills
    assert sum(ok) == 128 and s.dropped == 172
    s.start()
    assert s.close(timeout_s=20) == 0
    data = read_log(sorted(tmp_path.glob("*.mcap"))[0])
    assert same_bits(data.records, r[:128])
    drops = [e for e in data.events if e["kind"] == EventKind.DROPPED]
    assert drops and drops[-1]["dropped_total"] == 172


def test_not_a_log_is_refused(tmp_path: Path) -> None:
    from capstan.models.common.errors import DataFormatError
    bad = tmp_path / "x.mcap"
    bad.write_bytes(b"hello world, not mcap at all")
    with pytest.raises(DataFormatError):
        read_log(bad)
    with pytest.raises(DataFormatError, match="cannot open"):
        read_log(tmp_path / "missing.mcap")
