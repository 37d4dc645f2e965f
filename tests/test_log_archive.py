"""``capstan archive``: the columnar archive of a live log is lossless (archive -> export
equals live -> export, every record field bit for bit), several times smaller, and
readable by replay/export; the blocks decode with the mcap protobuf decoder."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from capstan.controller.log.mcap_log import McapLog
from capstan.controller.log.reader import read_log
from capstan.tools.cli import main
from capstan.tools.offline.archive import ARCHIVE_TOPIC, read_any, write_archive

mcap_reader = pytest.importorskip("mcap.reader")
decoder = pytest.importorskip("mcap_protobuf.decoder")
REPO = Path(__file__).resolve().parent.parent


def _bits_equal(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and all(np.ascontiguousarray(a[n]).tobytes() == np.ascontiguousarray(b[n]).tobytes()
                                      for n in a.dtype.names)


def _chunk_bytes(path: Path) -> int:
    """Bytes of the file's chunks with their message indexes (from its summary)."""
    with open(path, "rb") as fh:
        return sum(ix.chunk_length + ix.message_index_length
                   for ix in mcap_reader.make_reader(fh).get_summary().chunk_indexes)


def test_archive_without_a_controller_stores_every_column_and_reads_back_exactly(tmp_path: Path) -> None:
    dt = np.dtype([("cycle", "<u8"), ("t_s", "<f8"), ("t_ns", "<i8"), ("lc_t_ns", "<i8"), ("x", "<f8"),
                   ("y", "<f4"), ("k", "<i2"), ("flag", "u1")])
    rng = np.random.default_rng(4)
    r = np.zeros(3500, dt)
    r["cycle"] = np.arange(3500) + 17
    r["t_ns"] = 5_000_000_000 + np.cumsum(rng.integers(990_000, 1_010_000, 3500))
    r["t_s"] = r["t_ns"] * 1e-9
    r["lc_t_ns"] = r["t_ns"] - rng.integers(0, 80_000, 3500)
    r["x"], r["y"] = rng.normal(size=3500), rng.normal(size=3500).astype(np.float32)
    r["k"], r["flag"] = rng.integers(-300, 300, 3500), rng.integers(0, 2, 3500)
    log = McapLog(tmp_path, "capstan", dt)
    log.write_records(r)
    log.close()
    res = write_archive(log.current_file, tmp_path / "a.mcap")
    assert res.recomputed == ()                             # no config: nothing to recompute
    assert _bits_equal(read_any(tmp_path / "a.mcap").records, read_log(log.current_file).records)


@pytest.mark.slow
def test_hil_log_archive_export_equals_live_export(tmp_path: Path, capsys) -> None:
    from hil_helpers import run_hil
    cfg = yaml.safe_load((REPO / "config" / "hil.yaml").read_text())
    cfg["logging"]["dir"] = str(tmp_path / "logs")
    cfg["realtime"]["lock_memory"] = False
    path = tmp_path / "hil.yaml"
    path.write_text(yaml.safe_dump(cfg))
    res, out = run_hil(path, 4.0, REPO)
    assert res.returncode == 0, res.stderr[-3000:]
    live = Path(out["log_path"])
    arch = tmp_path / "run.archive.mcap"
    assert main(["archive", str(live), "--out", str(arch), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    # the target, ≤ 120 MB/hour at 1 kHz = 33.3 B per cycle, on what grows with the
    # run: the archive's chunks (cycle blocks, events, stats); a 4 s file's fixed parts
    # (metadata, schemas, summary: about 12 kB) would count 3 B/cycle here and 0.1 in an hour
    assert _chunk_bytes(arch) / out["cycles"] <= 120e6 / 3.6e6
    assert _chunk_bytes(arch) < 120 / 250 * _chunk_bytes(live)      # the two targets' ratio
    assert "tau_m_cmd_Nm" in rep["recomputed_fields"] and "d_hat_Nm" in rep["recomputed_fields"]
    assert _bits_equal(read_any(arch).records, read_log(live).records)
    for src, csv in ((live, tmp_path / "live.csv"), (arch, tmp_path / "arch.csv")):
        assert main(["export", str(src), "--out", str(csv)]) == 0
    capsys.readouterr()
    assert (tmp_path / "live.csv").read_bytes() == (tmp_path / "arch.csv").read_bytes()
    side = [yaml.safe_load(p.read_text()) for p in (tmp_path / "live.yaml", tmp_path / "arch.yaml")]
    for s in side:
        s.pop("source_log", None)
    assert side[0] == side[1]
    # one message per second of cycles; a generic protobuf decoder reads the blocks
    with open(arch, "rb") as fh:
        r = mcap_reader.make_reader(fh, decoder_factories=[decoder.DecoderFactory()])
        blocks = [m for _, _, _, m in r.iter_decoded_messages(topics=[ARCHIVE_TOPIC])]
        fh.seek(0)
        events = list(mcap_reader.make_reader(fh).iter_messages(topics=["/capstan/events", "/capstan/stats"]))
    assert sum(b.n for b in blocks) == out["cycles"] and all(b.n <= 1001 for b in blocks)
    assert len(blocks) >= int(out["cycles"] / 1000)
    with open(live, "rb") as fh:
        assert len(events) == len(list(mcap_reader.make_reader(fh).iter_messages(
            topics=["/capstan/events", "/capstan/stats"])))
    assert main(["replay", str(arch), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["max_abs_dtau_m_Nm"] == 0.0
