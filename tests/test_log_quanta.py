"""The live log's display copies of the step intermediates are stored rounded to a
power-of-two quantum (``LOG_FLOAT32_QUANTA``): the rounding is what it says (a multiple
of the quantum, at most half a quantum off, low mantissa bits zero), an invalid quantum
is refused by name, a standard protobuf decoder reads the rounded values, and the
archive still recomputes those fields and reads back bit for bit."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from capstan.controller.law.records import LOG_FLOAT32_FIELDS, LOG_FLOAT32_QUANTA, MEASUREMENT_FIELDS, STEP_OUTPUT_FIELDS
from capstan.controller.law.safety import COMMAND_QUANTUM_NM
from capstan.controller.log.mcap_log import McapLog
from capstan.controller.log.reader import read_log
from capstan.controller.log.schema import LogFormatError, build_layout, quantize_float32
from capstan.tools.offline.archive import read_any, write_archive
from test_replay import CONFIG, simulate_run

mcap_reader = pytest.importorskip("mcap.reader")
decoder = pytest.importorskip("mcap_protobuf.decoder")


def test_quantize_rounds_to_the_nearest_multiple_and_clears_low_mantissa_bits() -> None:
    rng = np.random.default_rng(1)
    x = np.concatenate([rng.normal(0, 5, 20000), rng.normal(0, 1e-3, 2000), [0.0, -0.0, 1e-9, 4095.9]])
    q = 2.0 ** -12
    y = quantize_float32(x, q)
    assert y.dtype == np.float32
    yd = y.astype(np.float64)
    assert np.all(np.abs(yd - x) <= q / 2)                          # nearest multiple
    assert np.all(yd / q == np.round(yd / q))                       # exactly a multiple
    # a float32 in [2**e, 2**(e+1)) has ulp 2**(e-23): a multiple of 2**-12 is 2**(11-e)
    # ulps, its low 11 - e mantissa bits are zero (9 of 23 at 4..8 Nm, 13 at 0.25..0.5)
    mant = y.view(np.uint32) & np.uint32(0x7FFFFF)
    for e in (2, -2):
        band = (np.abs(x) >= 2.0 ** e) & (np.abs(x) < 2.0 ** (e + 1))
        assert band.sum() > 500 and np.all((mant[band] & np.uint32((1 << (11 - e)) - 1)) == 0)
    # ties to even, and nothing but rounding: half a quantum up/down
    assert quantize_float32(np.array([0.5 * q, 1.5 * q, -2.5 * q]), q).tolist() == [0.0, 2 * q, -2 * q]
    special = quantize_float32(np.array([np.nan, np.inf, -np.inf]), q)
    assert np.isnan(special[0]) and special[1] == np.inf and special[2] == -np.inf


def test_quanta_are_powers_of_two_of_float32_fields_and_refused_by_name() -> None:
    dt = np.dtype([("a_Nm", "<f8"), ("b_N", "<f8")])
    with pytest.raises(LogFormatError, match="a_Nm.*not a power of two"):
        build_layout(dt, "x.Y", ("a_Nm",), {"a_Nm": 1e-5})
    with pytest.raises(LogFormatError, match="b_N.*not one of the float32 fields"):
        build_layout(dt, "x.Y", ("a_Nm",), {"b_N": 2.0 ** -10})
    with pytest.raises(LogFormatError, match="a_Nm.*not a power of two"):
        build_layout(dt, "x.Y", ("a_Nm",), {"a_Nm": -0.25})
    assert build_layout(dt, "x.Y", ("a_Nm",), {"a_Nm": 0.25}).quanta == (("a_Nm", 0.25),)
    # the daemon's quanta: powers of two, only float32 fields, never a replay input or the command;
    # the loop's timing below a microsecond
    for f, q in LOG_FLOAT32_QUANTA.items():
        assert f in LOG_FLOAT32_FIELDS and math.frexp(q)[0] == 0.5
        assert f not in MEASUREMENT_FIELDS and f != "tau_m_cmd_Nm"
    assert LOG_FLOAT32_QUANTA["period_s"] < 1e-6 and LOG_FLOAT32_QUANTA["compute_s"] < 1e-6


@pytest.fixture(scope="module")
def quantized_log(tmp_path_factory) -> tuple[Path, np.ndarray]:
    recs = simulate_run(3000)
    path = tmp_path_factory.mktemp("quanta") / "run.mcap"
    f32 = tuple(f for f in LOG_FLOAT32_FIELDS if f in recs.dtype.names)
    log = McapLog(path.parent, "x", recs.dtype, yaml.safe_dump(CONFIG), first_path=path, flush_interval_s=0,
                  float32_fields=f32, float32_quanta=LOG_FLOAT32_QUANTA)
    log.write_records(recs)
    log.close()
    return path, recs


def test_protobuf_decoder_reads_the_rounded_values(quantized_log) -> None:
    path, recs = quantized_log
    with open(path, "rb") as fh:
        r = mcap_reader.make_reader(fh, decoder_factories=[decoder.DecoderFactory()])
        ch = next(c for c in r.get_summary().channels.values() if c.topic == "/capstan/cycle")
        msgs = [m for _, _, _, m in r.iter_decoded_messages(topics=["/capstan/cycle"])]
    assert json.loads(ch.metadata["float32_quanta"]) == LOG_FLOAT32_QUANTA
    assert len(msgs) == len(recs)
    for f, q in LOG_FLOAT32_QUANTA.items():
        got = np.array([getattr(m, f) for m in msgs])
        assert np.any(recs[f] != 0), f
        np.testing.assert_array_equal(got, quantize_float32(recs[f], q).astype(np.float64))
        assert np.all(np.abs(got - recs[f]) <= q / 2), f
    # the command and the measurements are not rounded by the log; the command is on the law's grid
    assert np.array([m.tau_m_cmd_Nm for m in msgs]).tobytes() == recs["tau_m_cmd_Nm"].tobytes()
    cmd_q = recs["tau_m_cmd_Nm"] / COMMAND_QUANTUM_NM
    assert np.any(recs["tau_m_cmd_Nm"] != 0) and np.array_equal(cmd_q, np.round(cmd_q))
    assert np.array([m.T_up_in_N for m in msgs]).tobytes() == recs["T_up_in_N"].tobytes()


def test_replay_and_archive_of_a_quantized_log_are_exact(quantized_log, tmp_path: Path, capsys) -> None:
    from capstan.tools.cli import main
    path, _ = quantized_log
    assert main(["replay", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["max_abs_dtau_m_Nm"] == 0.0
    res = write_archive(path, tmp_path / "a.mcap")
    # the replay rounded the same way reproduces the stored copies: they are left out; the
    # loop's timing is no step output: the archive keeps it as stored
    assert {f for f in LOG_FLOAT32_QUANTA if f in STEP_OUTPUT_FIELDS} <= set(res.recomputed)
    assert not {"period_s", "compute_s"} & set(res.recomputed)
    live, arch = read_log(path).records, read_any(tmp_path / "a.mcap").records
    for f in live.dtype.names:
        assert live[f].tobytes() == arch[f].tobytes(), f
