"""The live log stores measurements as the devices send them; a reader rebuilds the SI
values with the drivers' own conversions, bit for bit.

The drivers' conversions are exercised through their own code paths (TPDO decoding,
``to_tensions_N``, ``joint_from_mtdata2``) and compared bit for bit with
:func:`capstan.controller.log.reader.rebuild_derived` evaluating the derivations the
drivers publish, on random wire values over their whole ranges.
"""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from capstan.controller.law.records import DERIVED_FROM_WIRE, RECORD_DTYPE
from capstan.controller.log.mcap_log import DERIVATIONS_META, McapLog
from capstan.controller.log.reader import read_log, rebuild_derived
from capstan.drivers.canopen.config import MotorConfig
from capstan.drivers.canopen.motor import CanopenMotor
from capstan.drivers.serial.loadcell import LoadCellConfig, SerialLoadCells
from capstan.drivers.serial.xsens import XsensConfig, XsensImu, joint_from_mtdata2
from capstan.drivers.serial.xsens_protocol import MtData2
from capstan.models.common.errors import DataFormatError
from capstan.models.common.wire_units import Derivation

RNG = np.random.default_rng(16)


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, np.float64).view(np.uint64)


def _rebuild(stored: dict[str, np.ndarray], derivations: list[Derivation], fields: list[str]) -> np.ndarray:
    dt = np.dtype([(n, v.dtype) for n, v in stored.items()])
    st = np.zeros(len(next(iter(stored.values()))), dt)
    for n, v in stored.items():
        st[n] = v
    full = np.dtype(list(dt.descr) + [(f, "<f8") for f in fields])
    return rebuild_derived(st, full, json.dumps([d.to_json() for d in derivations]))


def test_load_cell_tensions_rebuild_bit_exactly_from_the_bridge_signals() -> None:
    cfg = LoadCellConfig(port="/dev/null", scale_N_per_mV_V=(251.3, 249.7, 250.1, 248.9),
                         offset_N=(0.7, -1.25, 0.0, 3.1))
    cells = SerialLoadCells(cfg)
    cells.tare_N = (149.83, 151.2, 148.001, 150.5)          # as a start-up tare leaves it
    raw = RNG.normal(0.6, 0.05, (5000, 4)).astype(">f4")     # the amplifier's big-endian float32
    raw[:10] = np.array([0.0, -0.0, 1e-38, -2.5], ">f4")
    want = np.array([cells.to_tensions_N(tuple(float(x) for x in row)) for row in raw])
    names = ["lc_up_in_mV_V", "lc_up_out_mV_V", "lc_lo_out_mV_V", "lc_lo_in_mV_V"]
    got = _rebuild({n: raw[:, k].astype("<f4") for k, n in enumerate(names)}, cells.derivations(),
                   ["T_up_in_N", "T_up_out_N", "T_lo_out_N", "T_lo_in_N"])
    for k, f in enumerate(("T_up_in_N", "T_up_out_N", "T_lo_out_N", "T_lo_in_N")):
        assert np.array_equal(_bits(got[f]), _bits(want[:, k])), f


def test_drive_feedback_rebuilds_bit_exactly_from_counts_units_and_per_mille() -> None:
    cfg = MotorConfig.from_mapping({"node_id": 1, "eds": "capstan_drive.eds", "rated_torque_Nm": 19.7,
                                    "gear_ratio": 7.3, "encoder_counts_per_rev": 131072,
                                    "velocity_units_per_rev_s": 131072})
    motor = CanopenMotor(cfg)
    motor._cobs = (0x181, 0x281, 0x81, 0x701, 0)
    motor._direct = True                                     # poll-time reads of an idle bus

    class _IdleBus:
        def recv(self, timeout: float) -> None:
            return None

    motor._bus = _IdleBus()
    n = 3000
    pos = RNG.integers(-2**31, 2**31, n)
    vel = RNG.integers(-2**31, 2**31, n)
    tq = RNG.integers(-32768, 32768, n)
    want = np.zeros((n, 4))
    t_ns = np.zeros(n, np.int64)
    for i in range(n):
        t = 1000.0 + i * 1e-3 + RNG.random() * 1e-6
        motor._rx.append((0x181, struct.pack("<Hbi", 0x1237, 10, int(pos[i])), t))
        motor._rx.append((0x281, struct.pack("<ih", int(vel[i]), int(tq[i])), t))
        motor._drain()
        rd = motor.reading
        assert (rd.position_counts, rd.velocity_units, rd.torque_permille) == (pos[i], vel[i], tq[i])
        want[i] = rd.position_rad, rd.velocity_rad_s, rd.torque_Nm, rd.t_s
        t_ns[i] = rd.t_ns
    got = _rebuild({"q_m_counts": pos.astype("<i4"), "dq_m_units": vel.astype("<i4"),
                    "tau_m_meas_permille": tq.astype("<i2"), "motor_t_ns": t_ns}, motor.derivations(),
                   ["q_m_rad", "dq_m_rad_s", "tau_m_meas_Nm", "motor_t_s"])
    for k, f in enumerate(("q_m_rad", "dq_m_rad_s", "tau_m_meas_Nm", "motor_t_s")):
        assert np.array_equal(_bits(got[f]), _bits(want[:, k])), f


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_imu_rate_rebuilds_bit_exactly_from_the_sensor_float32(sign: float) -> None:
    cfg = XsensConfig(port="/dev/null", sign=sign)
    imu = XsensImu(cfg)
    rate = RNG.normal(0, 2.0, (2000, 3)).astype(">f4")
    want = np.array([joint_from_mtdata2(MtData2(quaternion=(1.0, 0.0, 0.0, 0.0),
                                                rate_of_turn_rad_s=tuple(float(x) for x in r)), cfg)[1]
                     for r in rate])
    got = _rebuild({"imu_rate_rad_s": rate[:, int(cfg.joint_axis)].astype("<f4"),
                    "imu_t_ns": np.arange(2000, dtype=np.int64)}, imu.derivations(),
                   ["dq_out_rad_s", "imu_t_s"])
    assert np.array_equal(_bits(got["dq_out_rad_s"]), _bits(want))
    assert imu.rate_is_float32


def test_a_wire_log_without_its_derivations_is_refused_by_name(tmp_path) -> None:
    recs = np.zeros(10, RECORD_DTYPE)
    recs["t_ns"] = np.arange(10) * 1_000_000 + 5
    recs["t_s"] = recs["t_ns"] * 1e-9
    log = McapLog(tmp_path, "w", RECORD_DTYPE, drop_fields=tuple(DERIVED_FROM_WIRE))
    log.write_records(recs)
    log.close()
    with pytest.raises(DataFormatError, match="capstan.derivations"):
        read_log(log.current_file)
    log = McapLog(tmp_path / "b", "w", RECORD_DTYPE, drop_fields=tuple(DERIVED_FROM_WIRE))
    log.add_metadata(DERIVATIONS_META, {"derivations": json.dumps([{"field": "t_s", "source": "t_ns",
                                                                    "ops": [["mul", 1e-9]]}])})
    log.write_records(recs)
    log.close()
    with pytest.raises(DataFormatError, match="T_up_in_N"):
        read_log(log.current_file)


@pytest.mark.slow
def test_hil_log_stores_wire_values_and_replays_bit_exactly(tmp_path, capsys) -> None:
    """A HIL run of the daemon (real drivers against the simulated rig): the file, decoded
    with the mcap protobuf decoder, carries integer counts / per mille / ns and the
    amplifier's float32, no SI copies of them; replay of the file is bit-exact."""
    from pathlib import Path

    import yaml
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    from capstan.tools.cli import main
    from hil_helpers import run_hil

    repo = Path(__file__).resolve().parent.parent
    cfg = yaml.safe_load((repo / "config" / "hil.yaml").read_text())
    cfg["logging"]["dir"] = str(tmp_path / "logs")
    cfg["realtime"]["lock_memory"] = False
    path = tmp_path / "hil.yaml"
    path.write_text(yaml.safe_dump(cfg))
    res, out = run_hil(path, 3.0, repo)
    assert res.returncode == 0, res.stderr[-3000:]
    log = out["log_path"]
    with open(log, "rb") as fh:
        msgs = [m for _, _, _, m in make_reader(fh, decoder_factories=[DecoderFactory()])
                .iter_decoded_messages(topics=["/capstan/cycle"])]
    assert len(msgs) == out["cycles"] > 2000
    fields = {f.name for f in msgs[0].DESCRIPTOR.fields}
    assert not fields & set(DERIVED_FROM_WIRE)                       # no SI copies stored
    assert set(DERIVED_FROM_WIRE.values()) <= fields
    last = msgs[-1]
    assert all(isinstance(getattr(last, f), int) for f in
               ("t_ns", "q_m_counts", "dq_m_units", "tau_m_meas_permille", "lc_t_ns", "imu_t_ns", "motor_t_ns"))
    assert last.lc_up_in_mV_V != 0.0 and np.float32(last.lc_up_in_mV_V) == last.lc_up_in_mV_V
    data = read_log(log)                                             # SI values rebuilt
    assert data.records.dtype == RECORD_DTYPE
    k = len(msgs) - 1
    assert data.records["t_s"][k] == msgs[k].t_ns * 1e-9
    assert data.records["q_m_counts"][k] == msgs[k].q_m_counts
    running = data.records[data.records["phase"] == 1]
    assert np.all(running["T_up_in_N"] > 50) and np.all(np.abs(running["tau_m_meas_Nm"]) < 20)
    assert main(["replay", str(log), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["max_abs_dtau_m_Nm"] == 0.0 and rep["cycles_different"] == 0
