"""``capstan replay``: logged config reproduces the commands bit for bit; an override
gives a what-if log and plot; tampering or a wrong config is detected."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader

from capstan.controller.law.config import ControllerConfig
from capstan.controller.law.core import Controller
from capstan.controller.law.fingerprint import law_fingerprint
from capstan.controller.runtime.session_log import newest_log, open_session
from capstan.controller.log.reader import read_log
from capstan.controller.log.mcap_log import McapLog
from capstan.controller.law.records import LOG_FLOAT32_FIELDS, LOG_FLOAT32_QUANTA, MEASUREMENT_FIELDS, RECORD_DTYPE, STEP_OUTPUT_FIELDS
from capstan.tools.cli import main
from capstan.tools.offline.replay import merge_config, replay_records

CONFIG = {"controller": {"torque_loop": "ldo", "feedback": {"kp": 4.0, "kd_s": 0.04},
                         "feedforward": {"gain": 0.8}},
          "rig": {"note": "other sections are kept verbatim"}}


def simulate_run(n: int, cfg: dict = CONFIG, seed: int = 3) -> np.ndarray:
    """Records of a live-like loop: noisy load cells at 1 kHz, IMU at 400 Hz (sample and
    hold), jittered periods, the real controller stepping, timing fields after."""
    rng = np.random.default_rng(seed)
    ctl = Controller(ControllerConfig.from_mapping(cfg["controller"]))
    ctl.warmup()
    out = np.zeros(n, RECORD_DTYPE)
    rec = ctl.record[0]
    t = 50.0
    q = dq = 0.0
    for k in range(n):
        t += 1e-3 + rng.normal(0, 2e-6)
        phase = 2 * np.pi * 0.5 * k * 1e-3
        tau = 3.0 * np.sin(phase)
        rec["cycle"], rec["t_s"] = k, t
        rec["T_up_in_N"] = 150 + tau / 0.08 + rng.normal(0, 0.2)
        rec["T_lo_in_N"] = 150 - tau / 0.08 + rng.normal(0, 0.2)
        rec["T_up_out_N"] = 148 + 0.9 * tau / 0.08 + rng.normal(0, 0.2)
        rec["T_lo_out_N"] = 148 - 0.9 * tau / 0.08 + rng.normal(0, 0.2)
        rec["lc_t_s"] = t - 2e-4
        if k % 5 in (0, 2):                           # ~400 Hz IMU
            q, dq = 0.4 * np.sin(phase - 0.3), 0.4 * np.pi * np.cos(phase - 0.3)
            rec["imu_new"], rec["imu_t_s"] = 1, t - 3e-4
        else:
            rec["imu_new"] = 0
        rec["q_out_rad"], rec["dq_out_rad_s"] = np.float32(q), np.float32(dq)
        rec["q_m_rad"] = 0.41 * np.sin(phase - 0.25)
        rec["dq_m_rad_s"] = 0.41 * np.pi * np.cos(phase - 0.25)
        rec["tau_m_meas_Nm"] = tau + rng.normal(0, 0.05)
        rec["motor_t_s"] = t - 1e-4
        ctl.step()
        rec["period_s"], rec["compute_s"], rec["late"] = 1e-3, 2e-5, 0
        rec["phase"], rec["cmd_scale"] = 1, 1.0          # running: stepped, unscaled
        out[k] = rec
    return out


def write_log(path: Path, records: np.ndarray, cfg: dict = CONFIG,
              float32_fields: tuple[str, ...] = ()) -> Path:
    log = McapLog(path.parent, "x", records.dtype, yaml.safe_dump(cfg), first_path=path,
                  flush_interval_s=0, float32_fields=float32_fields)
    log.write_records(records)
    log.close()
    return path


@pytest.fixture(scope="module")
def run_log(tmp_path_factory) -> tuple[Path, np.ndarray]:
    recs = simulate_run(4000)
    return write_log(tmp_path_factory.mktemp("replay") / "run.mcap", recs), recs


def test_replay_with_logged_config_is_bit_exact(run_log, capsys) -> None:
    path, recs = run_log
    assert np.any(recs["d_hat_Nm"] != 0) and np.any(recs["tau_fc_Nm"] != 0)   # a non-trivial run
    assert main(["replay", str(path), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["cycles"] == 4000 and rep["config"] == "logged"
    assert rep["max_abs_dtau_m_Nm"] == 0.0 and rep["cycles_different"] == 0
    # CPU seconds of the two parts the speed figure counts (never more than the process
    # could use in that wall time on two cores, never nothing)
    assert 0 < rep["read_cpu_s"] <= 2 * rep["read_wall_s"] + 0.01
    assert 0 < rep["step_cpu_s"] <= 2 * rep["step_wall_s"] + 0.01
    assert rep["speed_x_realtime_cpu"] == pytest.approx(rep["duration_s"] / (rep["read_cpu_s"] + rep["step_cpu_s"]))


def test_replay_of_log_with_float32_intermediates_is_exact(tmp_path: Path, run_log, capsys) -> None:
    _, recs = run_log
    f32 = tuple(f for f in STEP_OUTPUT_FIELDS if f not in ("tau_m_cmd_Nm", "fault_bits"))
    path = write_log(tmp_path / "f32.mcap", recs, float32_fields=f32)
    assert main(["replay", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["max_abs_dtau_m_Nm"] == 0.0


def test_daemon_log_layout_has_every_field_and_replays_bit_exactly(tmp_path: Path, run_log, capsys) -> None:
    """The daemon's own log session (writer process, float32 copies of what the replay
    recomputes): every record field is in the protobuf schema with its storage type, the
    inputs and the command come back bit for bit, and the replay matches exactly."""
    descriptor_pb2 = pytest.importorskip("google.protobuf.descriptor_pb2")
    _, recs = run_log
    session = open_session(tmp_path, RECORD_DTYPE, CONFIG, ring_records=8192, fault_history_cycles=100)
    for i in range(len(recs)):
        assert session.push(recs[i:i + 1])
    assert session.close(timeout_s=30) == 0
    path = newest_log(tmp_path)
    assert path is not None
    data = read_log(path)
    assert data.records.dtype == RECORD_DTYPE and len(data.records) == len(recs)
    for f in RECORD_DTYPE.names:
        if f in LOG_FLOAT32_QUANTA:             # display copies rounded to their quantum
            q = LOG_FLOAT32_QUANTA[f]
            assert np.all(np.abs(data.records[f] - recs[f]) <= q / 2), f
            np.testing.assert_array_equal(data.records[f] / q, np.round(data.records[f] / q))
        elif f in LOG_FLOAT32_FIELDS:
            np.testing.assert_array_equal(data.records[f], recs[f].astype(np.float32).astype(np.float64))
        else:
            assert data.records[f].tobytes() == recs[f].tobytes(), f
    assert set(LOG_FLOAT32_FIELDS) <= set(STEP_OUTPUT_FIELDS) | {"period_s", "compute_s"}
    assert "tau_m_cmd_Nm" not in LOG_FLOAT32_FIELDS and not set(LOG_FLOAT32_FIELDS) & set(MEASUREMENT_FIELDS)
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        schema = reader.get_summary().schemas[1]
        k = 1234
        _, _, msg_k = next(m for i, m in enumerate(reader.iter_messages(topics=["/capstan/cycle"])) if i == k)
    fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
    msg = fds.file[0].message_type[0]
    assert [fd.name for fd in msg.field] == list(RECORD_DTYPE.names)
    double, float_, fixed64, fixed32 = 1, 2, 6, 7
    sfixed32, sfixed64 = 15, 16
    want = {f: float_ if f in LOG_FLOAT32_FIELDS or RECORD_DTYPE[f] == np.float32 else
            {"f": double, "u": fixed32, "i": sfixed32}[RECORD_DTYPE[f].kind]
            for f in RECORD_DTYPE.names}
    want["cycle"] = fixed64
    want.update({f: sfixed64 for f in RECORD_DTYPE.names if RECORD_DTYPE[f] == np.int64})
    assert {fd.name: fd.type for fd in msg.field} == want
    # a standard protobuf decoder (as Foxglove's) reads a logged message from that schema
    from google.protobuf import descriptor_pool, message_factory
    pool = descriptor_pool.DescriptorPool()
    pool.Add(fds.file[0])
    decoded = message_factory.GetMessageClass(pool.FindMessageTypeByName("capstan.Cycle")).FromString(msg_k.data)
    for f in RECORD_DTYPE.names:
        assert getattr(decoded, f) == data.records[f][k], f
    assert decoded.cycle == k and decoded.d_hat_Nm != 0.0
    assert main(["replay", str(path), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["max_abs_dtau_m_Nm"] == 0.0 and rep["cycles_different"] == 0 and rep["cycles"] == len(recs)
    # the log names the law that wrote it: this build's
    assert data.meta["law_sha256"] == law_fingerprint() and rep["law_changed"] is False


def test_replay_recomputes_every_step_output(run_log) -> None:
    path, recs = run_log
    ctl = Controller(ControllerConfig.from_mapping(CONFIG["controller"]))
    ctl.warmup()
    blanked = recs.copy()
    for f in STEP_OUTPUT_FIELDS:                      # outputs are not taken from the log
        blanked[f] = 0
    inputs = ("cycle", *MEASUREMENT_FIELDS)
    res = replay_records(blanked, ctl, inputs, STEP_OUTPUT_FIELDS)
    assert res.replayed.tobytes() == recs.tobytes()


def test_tampered_log_is_detected(tmp_path: Path, run_log, capsys) -> None:
    _, recs = run_log
    bad = recs.copy()
    bad["tau_m_cmd_Nm"][1234] = np.nextafter(bad["tau_m_cmd_Nm"][1234], np.inf)   # one ulp
    path = write_log(tmp_path / "bad.mcap", bad)
    assert main(["replay", str(path), "--json"]) == 1
    rep = json.loads(capsys.readouterr().out)
    assert rep["cycles_different"] == 1 and rep["first_different_cycle"] == 1234
    assert 0 < rep["max_abs_dtau_m_Nm"] < 1e-12


@pytest.mark.parametrize("logged_law, changed, says", [
    (None, None, "does not record which control law"),
    ("0" * 64, True, "written by a different control law"),
    ("this build", False, "the control law is the same"),
])
def test_a_replay_that_differs_says_whether_the_law_changed(tmp_path: Path, run_log, capsys, caplog,
                                                            logged_law, changed, says) -> None:
    _, recs = run_log
    bad = recs.copy()
    bad["tau_m_cmd_Nm"][100] += 0.5
    meta = {} if logged_law is None else {"law_sha256": law_fingerprint() if logged_law == "this build" else logged_law}
    log = McapLog(tmp_path, "x", bad.dtype, yaml.safe_dump(CONFIG), first_path=tmp_path / "law.mcap",
                  flush_interval_s=0, extra_meta=meta)
    log.write_records(bad)
    log.close()
    assert main(["replay", str(tmp_path / "law.mcap"), "--json"]) == 1
    rep = json.loads(capsys.readouterr().out)
    assert rep["cycles_different"] == 1 and rep["law_changed"] is changed
    assert rep["law_sha256_replay"] == law_fingerprint()
    assert says in caplog.text


def test_override_writes_whatif_log_and_plot(tmp_path: Path, run_log, capsys) -> None:
    path, recs = run_log
    ovr = tmp_path / "ovr.yaml"
    ovr.write_text("controller:\n  feedforward:\n    gain: 0.0\n")
    out = tmp_path / "whatif.mcap"
    assert main(["replay", str(path), "--config", str(ovr), "--out", str(out), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["config"] == "override" and rep["max_abs_dtau_m_Nm"] > 0.01
    assert Path(rep["plot"]).stat().st_size > 10_000
    wi = read_log(out)
    assert wi.config["controller"]["feedforward"] == {"gain": 0.0}        # merged override
    assert wi.config["controller"]["feedback"]["kp"] == 4.0              # rest kept
    assert wi.config["rig"] == CONFIG["rig"]
    assert np.all(wi.records["tau_fc_Nm"] == 0.0)                        # no feedforward
    for f in MEASUREMENT_FIELDS + ("period_s", "compute_s"):
        np.testing.assert_array_equal(wi.records[f], recs[f])            # same inputs, timing
    # the what-if log replays bit-exactly with its own stored config
    assert main(["replay", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["max_abs_dtau_m_Nm"] == 0.0


def test_invalid_override_names_the_key(tmp_path: Path, run_log, capsys) -> None:
    path, _ = run_log
    ovr = tmp_path / "bad.yaml"
    ovr.write_text("controller:\n  feedback:\n    kp: -1\n")
    assert main(["replay", str(path), "--config", str(ovr)]) == 2
    assert "controller.feedback.kp" in capsys.readouterr().err


def test_merge_config_is_deep_and_does_not_mutate() -> None:
    base = {"a": {"b": 1, "c": {"d": 2}}, "e": [1, 2]}
    out = merge_config(base, {"a": {"c": {"d": 3}}, "e": [9]})
    assert out == {"a": {"b": 1, "c": {"d": 3}}, "e": [9]}
    assert base["a"]["c"]["d"] == 2


def test_progress_bar_draws_on_its_stream() -> None:
    import io
    from capstan.tools.offline.progress import Progress
    buf = io.StringIO()
    bar = Progress("replay", stream=buf)
    bar.update(0, 200)
    bar.update(200, 200)
    bar.done()
    assert "replay" in buf.getvalue() and "100%" in buf.getvalue() and buf.getvalue().endswith("\n")
    quiet = io.StringIO()
    Progress("x", enabled=False, stream=quiet).update(5, 10)
    assert quiet.getvalue() == ""


class _BoundController:
    """Stand-in controller that steps on the record buffer it was built with (ignores a
    swapped ``record`` attribute): y = 2 x + integral of x, with state."""

    DT = np.dtype([("t_s", "<f8"), ("x", "<f8"), ("y", "<f8"), ("tau_m_cmd_Nm", "<f8")])

    def __init__(self) -> None:
        self.record = np.zeros(1, self.DT)
        self._own = self.record
        self.acc = 0.0

    def step(self) -> float:
        r = self._own[0]
        self.acc += float(r["x"])
        r["y"] = 2.0 * r["x"]
        r["tau_m_cmd_Nm"] = r["y"] + self.acc
        return float(r["tau_m_cmd_Nm"])

    def reset(self) -> None:
        self.acc = 0.0


def test_replay_machinery_with_a_controller_bound_to_its_own_record() -> None:
    log = np.zeros(50, _BoundController.DT)
    log["t_s"] = np.arange(50) * 1e-3
    log["x"] = np.sin(np.arange(50))
    log["y"] = 2.0 * log["x"]
    log["tau_m_cmd_Nm"] = log["y"] + np.cumsum(log["x"])
    res = replay_records(log, _BoundController(), ("t_s", "x"), ("y", "tau_m_cmd_Nm"))
    assert res.n_different == 0 and res.max_abs_dtau_m_Nm == 0.0
    assert res.replayed.tobytes() == log.tobytes()


def test_the_daemon_logs_the_resolved_controller_config(tmp_path: Path) -> None:
    """A config that leaves keys to their defaults is logged with every value explicit, so a
    later change of a default cannot change what a replay of the log rebuilds."""
    from capstan.controller.runtime.session_log import logged_config
    raw = {"controller": {"dt_s": 0.001}, "loop": {"period_s": 0.001}}
    ctl = Controller(ControllerConfig.from_mapping(raw["controller"]))
    logged = logged_config(raw, ctl)
    assert logged["loop"] == raw["loop"] and raw["controller"] == {"dt_s": 0.001}   # not mutated
    fb = logged["controller"]["feedback"]
    assert {"kp", "deflection_damping_Nms_rad", "inertia_comp_kg_m2"} <= set(fb)
    again = yaml.safe_load(yaml.safe_dump(logged, sort_keys=False))       # as the log stores it
    assert ControllerConfig.from_mapping(again["controller"]) == ctl.cfg
    assert logged_config(raw, object()) is raw                              # a controller without a config
