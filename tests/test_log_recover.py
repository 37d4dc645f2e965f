"""``recover_log`` on files cut at every kind of place: the result opens with ``mcap``'s
indexed reader, holds exactly the complete chunks (as many cycles as a streaming read of
the cut file finds), and the records are a prefix of what was written."""

from __future__ import annotations

import numpy as np
import pytest
from mcap.reader import NonSeekingReader, make_reader

from capstan.controller.log.mcap_log import McapLog
from capstan.controller.log.reader import read_log
from capstan.controller.log.recover import recover_log
from capstan.models.common.errors import DataFormatError

DT = np.dtype([("cycle", "<u8"), ("t_s", "<f8"), ("x", "<f8")])


def _full_log(tmp_path) -> tuple[bytes, np.ndarray]:
    r = np.zeros(5000, DT)
    r["cycle"] = np.arange(5000)
    r["t_s"] = 1.0 + r["cycle"] * 1e-3
    r["x"] = np.sin(r["cycle"] * 0.01)
    log = McapLog(tmp_path, "full", DT, flush_interval_s=0)
    for i in range(0, 5000, 500):
        log.write_records(r[i:i + 500])
        log.flush()
    log.close()
    return log.current_file.read_bytes(), r


def _streamed(path) -> int:
    n = 0
    with open(path, "rb") as fh:
        try:
            for _ in NonSeekingReader(fh, record_size_limit=None).iter_messages(log_time_order=False):
                n += 1
        except Exception:  # noqa: BLE001 - the cut
            pass
    return n


@pytest.mark.parametrize("frac", [0.05, 0.33, 0.5, 0.77, 0.97])
def test_cut_files_recover_to_their_complete_chunks(tmp_path, frac: float) -> None:
    blob, r = _full_log(tmp_path)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(blob[:int(len(blob) * frac)])
    want = _streamed(cut)
    res = recover_log(cut)
    assert not res.was_complete and res.messages == want
    with open(cut, "rb") as fh:
        stats = make_reader(fh).get_summary().statistics
    assert stats.message_count == want
    got = read_log(cut)
    assert not got.truncated and len(got.records) == want
    assert got.records.tobytes() == r[:want].tobytes()


def test_complete_file_is_left_alone_and_garbage_is_refused(tmp_path) -> None:
    blob, _ = _full_log(tmp_path)
    ok = tmp_path / "ok.mcap"
    ok.write_bytes(blob)
    assert recover_log(ok).was_complete and ok.read_bytes() == blob
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file at all")
    with pytest.raises(DataFormatError, match="bad.mcap"):
        recover_log(bad)
    assert not (tmp_path / "bad.mcap.recovering").exists()


def test_start_up_recovers_cut_logs_that_no_process_holds(tmp_path) -> None:
    from capstan.controller.log.session import LogSession
    blob, r = _full_log(tmp_path)
    logs = tmp_path / "logs"
    logs.mkdir()
    cut = logs / "capstan_20260101-000000_000.mcap"
    cut.write_bytes(blob[:len(blob) // 2])
    held = logs / "capstan_20260101-000001_000.mcap"
    held.write_bytes(blob[:len(blob) // 3])
    want = _streamed(cut)
    with open(held, "rb"):                                  # e.g. another writer still at work
        s = LogSession(DT, logs)
        s.close()
    assert not read_log(cut).truncated and len(read_log(cut).records) == want
    with open(cut, "rb") as fh:
        assert make_reader(fh).get_summary().statistics.message_count == want
    assert held.read_bytes() == blob[:len(blob) // 3]       # a file in use is left alone
