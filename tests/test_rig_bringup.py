"""The bring-up's own logic without a rig: START validation, the bring-up move's limits and
zero torque, the check's channel-order inference, the refusal of a drive that does not move,
the atomic write of the tuned config, the served rig's configuration.

Against the served simulated rig: tests/test_rig_bringup_sim.py (slow).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from capstan.controller.law.records import FaultBits
from capstan.models.common.errors import ConfigError
from capstan.tools.hil.serve import load_plant, served_config
from capstan.tools.rig.check import infer_order
from capstan.tools.rig.profiles import CheckMove, Rest
from capstan.tools.rig.start_config import BringupStop, RigStart, StepLimits
from capstan.tools.rig.step_run import ProfileController
from capstan.tools.rig.tuned import write_atomic
from capstan.tools.offline.shipped import config_path

PLANTS = Path(__file__).parent / "plants"


def start_mapping() -> dict:
    return yaml.safe_load(config_path("rig_start.yaml").read_text())


def test_shipped_start_config_loads() -> None:
    s = RigStart.from_mapping(start_mapping())
    assert s.drawing.r_in_m == 0.04 and s.limits.tau_max_Nm == 4.0
    assert s.calibration.reference == "drive_torque"


@pytest.mark.parametrize("path, value, key", [
    (("drawing", "r_in_m"), -0.04, "drawing.r_in_m"),
    (("limits", "tau_max_Nm"), 40.0, "limits.tau_max_Nm"),           # beyond the drive's max_torque_Nm
    (("limits", "speed"), 1.0, "limits"),                               # unknown key
    (("calibration", "reference"), "guess", "calibration.reference"),
])
def test_start_config_errors_name_the_key(path: tuple[str, str], value: object, key: str) -> None:
    raw = start_mapping()
    raw[path[0]][path[1]] = value
    with pytest.raises(ConfigError) as exc:
        RigStart.from_mapping(raw)
    assert key in str(exc.value)


def test_start_without_a_device_section_is_refused() -> None:
    raw = start_mapping()
    del raw["devices"]["imu"]
    with pytest.raises(ConfigError, match="devices.imu"):
        RigStart.from_mapping(raw)


def _controller(profile, limits: StepLimits = StepLimits()) -> ProfileController:
    ctl = ProfileController(profile, limits, 0.04, 100)
    r = ctl.record[0]
    r["T_up_in_N"] = r["T_up_out_N"] = r["T_lo_out_N"] = r["T_lo_in_N"] = 150.0
    return ctl


def _cycle(ctl: ProfileController, t_s: float, **fields: float) -> float:
    r = ctl.record[0]
    r["t_s"] = t_s
    for key in ("lc_t_s", "imu_t_s", "motor_t_s"):
        r[key] = t_s
    for k, v in fields.items():
        r[k] = v
    return ctl.step()


class _Constant:
    def __init__(self, tau: float) -> None:
        self.tau = tau

    def torque_Nm(self, t_s: float, r: object) -> float:
        return self.tau

    def done(self, t_s: float) -> bool:
        return False


def test_profile_torque_is_clamped_to_the_start_limit() -> None:
    ctl = _controller(_Constant(10.0), StepLimits(tau_max_Nm=2.5))
    assert _cycle(ctl, 0.0) == 2.5
    assert ctl.record[0]["fault_bits"] == 0


@pytest.mark.parametrize("fields, words", [
    ({"q_m_rad": 1.2}, "motor travel"),
    ({"dq_m_rad_s": -4.0}, "motor speed"),
    ({"q_out_rad": 1.0}, "joint angle"),
    ({"T_lo_in_N": 2.0}, "tension T_lo_in_N"),
])
def test_a_limit_latches_a_fault_with_zero_torque_and_a_reason(fields: dict, words: str) -> None:
    ctl = _controller(_Constant(1.0))
    assert _cycle(ctl, 0.0) == 1.0                 # the first cycle latches q_m's start
    assert _cycle(ctl, 0.001, **fields) == 0.0
    assert ctl.record[0]["fault_bits"] & FaultBits.EXTERNAL_STOP
    assert words in ctl.reason and "\n" not in ctl.reason
    assert _cycle(ctl, 0.002) == 0.0               # latched: no torque afterwards either


def test_a_silent_load_cell_stops_the_move() -> None:
    ctl = _controller(_Constant(1.0))
    for k in range(60):                             # the loop runs every 1 ms, the cells stop at 0
        r = ctl.record[0]
        r["t_s"] = r["imu_t_s"] = r["motor_t_s"] = k * 1e-3
        tau = ctl.step()
    assert tau == 0.0
    assert "load cells silent for 51 ms" in ctl.reason


def test_a_host_stall_is_not_a_silent_device() -> None:
    ctl = _controller(_Constant(1.0))
    _cycle(ctl, 0.0)
    r = ctl.record[0]                               # the loop itself did not run for 80 ms:
    r["t_s"], r["imu_t_s"], r["motor_t_s"], r["lc_t_s"] = 0.081, 0.081, 0.081, 0.0
    assert ctl.step() == 1.0 and ctl.reason == ""   # the cells' last frame is old, but not their fault
    assert ctl.longest_gap_s == pytest.approx(0.080)
    r["t_s"], r["imu_t_s"], r["motor_t_s"] = 0.082, 0.082, 0.082
    assert ctl.step() == 0.0 and "load cells silent for 82 ms" in ctl.reason


def test_check_move_refuses_a_drive_that_does_not_move() -> None:
    move = CheckMove(tau_limit_Nm=2.0, rest_s=0.1)
    rec = np.zeros(1, dtype=[("q_m_rad", "f8")])[0]
    with pytest.raises(BringupStop, match="the drive does not move"):
        for k in range(5000):
            move.torque_Nm(k * 1e-3, rec)


def test_check_move_goes_both_ways_and_ends() -> None:
    move = CheckMove(tau_limit_Nm=2.0, rest_s=0.1, hold_s=0.2, settle_s=0.1)
    rec = np.zeros(1, dtype=[("q_m_rad", "f8")])[0]
    taus = []
    t = 0.0
    while not move.done(t) and t < move.max_duration_s:
        tau = move.torque_Nm(t, rec)
        rec["q_m_rad"] += 0.002 * tau             # a motor that follows its torque
        taus.append(tau)
        t += 1e-3
    assert move.done(t)
    assert max(taus) > 0.5 and min(taus) < -0.5 and taus[-1] == 0.0
    assert [w[0] for w in move.windows] == ["rest", "hold_pos", "hold_neg"]


@pytest.mark.parametrize("order", [(0, 1, 2, 3), (0, 1, 3, 2), (1, 0, 2, 3), (3, 2, 1, 0)])
def test_channel_order_is_inferred_from_sign_and_size(order: tuple[int, ...]) -> None:
    true_change = np.array([60.0, 25.0, -27.0, -58.0])     # up_in, up_out, lo_out, lo_in
    reported = true_change[list(order)]
    assert infer_order(reported) == list(order)


def test_rest_profile() -> None:
    p = Rest(0.5)
    assert p.torque_Nm(0.1, None) == 0.0 and not p.done(0.4) and p.done(0.5)


def test_atomic_write_leaves_the_old_file_when_writing_fails(tmp_path: Path) -> None:
    out = tmp_path / "tuned.yaml"
    out.write_text("old: 1\n")
    with pytest.raises(TypeError):
        write_atomic(out, {"bad": object()}, "# header\n")
    assert out.read_text() == "old: 1\n"
    assert list(tmp_path.iterdir()) == [out]                # no temporary left behind
    write_atomic(out, {"controller": {"dt_s": 0.001}}, "# provenance\n")
    assert out.read_text().startswith("# provenance\n")
    assert yaml.safe_load(out.read_text()) == {"controller": {"dt_s": 0.001}}


def test_served_config_keeps_the_plant_and_its_faults_apart() -> None:
    plant = load_plant(PLANTS / "fault_lc_lost.yaml")
    cfg = served_config(plant)
    assert "faults" not in cfg["hil"]["plant"]
    assert cfg["hil"]["faults"] == {"load_cells_silent_after_s": 4.0}
    assert cfg["motor"]["channel"] == "auto" and cfg["imu"]["port"] == "auto"
    # the served devices never take a client's beliefs: no sign, no scale
    assert "sign" not in cfg["imu"] and "scale_N_per_mV_V" not in cfg["load_cells"]


@pytest.mark.parametrize("name", sorted(p.name for p in PLANTS.glob("*.yaml")))
def test_every_plant_fixture_is_a_valid_plant(name: str) -> None:
    from capstan.tools.hil.plant import HilSettings
    from capstan.models.plant.rig import SimulatedRig
    cfg = served_config(load_plant(PLANTS / name))
    HilSettings.from_mapping(cfg["hil"])
    rig = SimulatedRig.from_mapping(cfg["hil"]["plant"], "hil.plant")
    assert rig.spec.transmission.stiffness_Nm_rad > 0 and math.isfinite(rig.t_s)


def test_tuned_mapping_is_a_daemon_config_with_provenance_as_comments(tmp_path: Path) -> None:
    from capstan.controller.runtime.config import DaemonConfig
    from capstan.tools.rig.tuned import provenance_comment, tuned_mapping
    start = RigStart.from_mapping(start_mapping()).with_ports({"channel": "auto", "imu_port": "auto",
                                                               "load_cells_port": "auto"})
    controller = yaml.safe_load(config_path("rig.yaml").read_text())["controller"]
    cal = {"scale_N_per_mV_V": [251.0, 250.0, 250.0, 249.0], "offset_N": [0.5, -0.5, 0.0, 0.0]}
    mapping = tuned_mapping(start, controller, {"imu": {"sign": -1.0}, "load_cells": cal})
    out = write_atomic(tmp_path / "config" / "tuned.yaml", mapping,
                       provenance_comment({"date": "2026-11-28", "logs": ["a.mcap"], "fit": {"K_c": 1.0}}))
    cfg = DaemonConfig.load(out)
    assert cfg.imu["sign"] == -1.0 and cfg.imu["port"] == "auto"
    assert cfg.load_cells["scale_N_per_mV_V"] == cal["scale_N_per_mV_V"]
    assert cfg.motor["interface"] == "capstan_unix" and cfg.motor["channel"] == "auto"
    assert cfg.logging.dir == tmp_path / "runs" / "logs"
    text = out.read_text()
    assert "# logs:" in text and "# - a.mcap" in text
