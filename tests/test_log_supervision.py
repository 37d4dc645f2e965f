"""The supervised log writer: killed from outside (SIGKILL), it is restarted into a new
file whose first event names the missing cycles exactly, and the session's drop count
equals the cycles missing from the files, counted with the mcap protobuf decoder (not
this project's reader). Policy ``stop`` and the restart limit report the writer lost.
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest

from capstan.controller.log.session import LogSession, WriterHealth

mcap_reader = pytest.importorskip("mcap.reader")
decoder = pytest.importorskip("mcap_protobuf.decoder")

DTYPE = np.dtype([("cycle", "<u8"), ("t_s", "<f8"), ("x", "<f8")])


def _decode_dir(d: Path) -> tuple[list[int], list[dict]]:
    """Cycle numbers and events of every file in ``d``, with the mcap protobuf decoder."""
    cycles, events = [], []
    for f in sorted(d.glob("*.mcap")):
        with open(f, "rb") as fh:
            r = mcap_reader.make_reader(fh, decoder_factories=[decoder.DecoderFactory()])
            for _, ch, msg in r.iter_messages():
                if ch.topic == "/capstan/events":
                    events.append(dict(json.loads(msg.data), file=f.name))
        with open(f, "rb") as fh:
            r = mcap_reader.make_reader(fh, decoder_factories=[decoder.DecoderFactory()])
            cycles += [m.cycle for _, _, _, m in r.iter_decoded_messages(topics=["/capstan/cycle"])]
    return cycles, events


def _run(tmp_path: Path, n: int, kill_at: tuple[int, ...], **kw) -> tuple[LogSession, list[WriterHealth], int]:
    s = LogSession(DTYPE, tmp_path, flush_interval_s=0.2, **kw)
    s.start()
    rec = np.zeros(1, DTYPE)
    health = []
    sent = 0
    todo = list(kill_at)
    t0 = time.monotonic()
    for k in range(n):
        rec["cycle"], rec["t_s"], rec["x"] = k, 100.0 + k * 1e-3, np.sin(k * 1e-2)
        s.push(rec)
        sent += 1
        if todo and k >= todo[0] and s.proc is not None and s.proc.poll() is None and s.cycle.durable[0] > 0:
            os.kill(s.proc.pid, signal.SIGKILL)       # from outside (once it has written): no chance to flush
            s.proc.wait()
            todo.pop(0)
        if k % 100 == 99:
            h = s.supervise()
            health.append(h)
            if h == WriterHealth.LOST:
                break
        time.sleep(max(0.0, t0 + (k + 1) * 1e-3 - time.monotonic()))   # 1 kHz
    return s, health, sent


def test_sigkilled_writer_restarts_into_a_new_file_with_the_exact_gap(tmp_path: Path) -> None:
    s, health, sent = _run(tmp_path, 3000, kill_at=(1150,))
    assert s.close(timeout_s=30) == 0
    assert WriterHealth.RESTARTED in health and WriterHealth.LOST not in health
    cycles, events = _decode_dir(tmp_path)
    assert len(list(tmp_path.glob("*.mcap"))) == 2
    missing = sorted(set(range(sent)) - set(cycles))
    assert len(cycles) == len(set(cycles)) == sent - len(missing)
    assert s.dropped == len(missing) > 0                   # counted exactly, not estimated
    gap = [e for e in events if e["kind_name"] == "WRITER_RESTARTED"]
    assert len(gap) == 1
    g = gap[0]
    assert g["gap_cycles"] == len(missing)
    assert list(range(g["gap_first_cycle"], g["gap_last_cycle"] + 1)) == missing
    assert "SIGKILL" in g["reason"]
    # the event is the first message of the new file: before any of its records
    second = sorted(tmp_path.glob("*.mcap"))[1]
    with open(second, "rb") as fh:
        first_msg = next(iter(mcap_reader.make_reader(fh).iter_messages(log_time_order=False)))
    assert first_msg[1].topic == "/capstan/events"


def test_policy_stop_reports_the_writer_lost(tmp_path: Path) -> None:
    s, health, sent = _run(tmp_path, 3000, kill_at=(550,), on_writer_loss="stop")
    assert health[-1] == WriterHealth.LOST and sent < 3000
    assert "on_writer_loss: stop" in s.lost_reason
    s.close(timeout_s=10)
    cycles, events = _decode_dir(tmp_path)                 # the cut file was recovered at close
    assert not [e for e in events if e["kind_name"] == "WRITER_RESTARTED"]
    assert len(list(tmp_path.glob("*.mcap"))) == 1
    assert len(cycles) + s.dropped == sent and cycles == list(range(len(cycles)))


def test_restart_limit_then_lost(tmp_path: Path) -> None:
    s, health, sent = _run(tmp_path, 4000, kill_at=(750, 1550, 2350), max_writer_restarts=2)
    assert health.count(WriterHealth.RESTARTED) == 2 and health[-1] == WriterHealth.LOST
    assert "3 writer failures, at most 2 restarts" in s.lost_reason
    s.close(timeout_s=10)
    cycles, events = _decode_dir(tmp_path)
    gaps = [e for e in events if e["kind_name"] == "WRITER_RESTARTED"]
    assert len(gaps) == 2
    # every cycle pushed while a writer could take it is either in a file or in a gap
    in_gaps = sum(g["gap_cycles"] for g in gaps)
    assert len(set(cycles)) == len(cycles)
    assert len(cycles) + s.dropped == sent                 # the unwritten tail is counted too
    assert in_gaps < s.dropped                             # the last writer's loss has no successor
    assert len(list(tmp_path.glob("*.mcap"))) == 3         # every file opens indexed (decoded above)


def test_bad_policy_is_refused_by_name(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="on_writer_loss"):
        LogSession(DTYPE, tmp_path, on_writer_loss="ignore")
    with pytest.raises(ValueError, match="max_writer_restarts"):
        LogSession(DTYPE, tmp_path, max_writer_restarts=-1)
