"""The torque loop with the real I/O delay: the analysis against the code it models,
against a time-domain run of the real Numba step, against physics, and the start-up check."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from capstan.controller.law.config import ControllerConfig
from capstan.controller.law.core import Controller
from capstan.controller.law.loop_model import (PlantPoint, closed_loop_poles, controller_tf, plant_continuous)
from capstan.controller.law.stability import analyse, check_margins
from capstan.controller.runtime.config import DaemonConfig
from capstan.controller.runtime.daemon import build_controller
from capstan.models.common.config_tools import load_yaml
from capstan.models.common.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
#: the gains tuned in lock-step (no delay): kp 5, kd 0.05, Q 10 Hz
LOCKSTEP_LDO = {"torque_loop": "ldo", "feedback": {"kp": 5.0, "kd_s": 0.05, "derivative_cutoff_hz": 40.0},
                "ldo": {"q_cutoff_hz": 10.0}}
#: J_c and the damping as shipped before the output torque gain's peak: J_c 0.2 from the link's acceleration
#: (b 60, link rate 30 Hz, lag compensated), no peak
PREV_JC = {"inertia_comp_kg_m2": 0.2, "acceleration_source": "link", "acceleration_cutoff_hz": 5.0,
           "deflection_damping_Nms_rad": 60.0, "deflection_link_cutoff_hz": 30.0, "deflection_link_lag_compensation": True,
           "output_torque_peak_gain": 0.0, "link_inertia_comp_kg_m2": 0.0}
#: the shipped feedback before the deflection-rate damping: feedforward + integral trim + J_c, kp 0
OLD_LOOP = {**PREV_JC, "kp": 0.0, "deflection_damping_Nms_rad": 0.0, "rest_gate_cutoff_hz": 0.0, "band_gain": 0.0,
            "output_torque_gain": 0.0}
NO_LIMITS = {"tau_max_Nm": 1e6, "tau_fault_Nm": 1e7, "dtau_max_Nm_s": 1e9, "dtau_fault_Nm_s": 1e10,
             "command_quantum_Nm": 0.0}   # the safety stage linear: no clamps, no rounding


def _quiet(m: dict) -> dict:
    """No gravity, feedforward or limits; the feedback keys a test does not set are those of the
    loop before the deflection-rate damping (kp 0, no damping, no rest gate on kp)."""
    m = copy.deepcopy(m)
    m.update({"gravity": {"enabled": False}, "feedforward": {"enabled": False}, "safety": NO_LIMITS})
    m["feedback"] = {**OLD_LOOP, **m.get("feedback", {})}
    return m


def _run_step(cfg: ControllerConfig, p: PlantPoint | None, delay: int, n: int, kick_Nm: float = 1e-3,
              tau_in_in: np.ndarray | None = None) -> np.ndarray:
    """The real Numba step in closed loop with a ZOH-discretised plant and a command FIFO of
    ``delay`` cycles (or, with ``p`` None, open loop on the given tau_in sequence)."""
    ctl = Controller(cfg)
    r = ctl.record[0]
    if p is not None:
        a, b, c, d = signal.tf2ss(*plant_continuous(p))
        a, b, c, d, _ = signal.cont2discrete((a, b, c, d), cfg.dt_s, method="zoh")
        x = np.zeros(a.shape[0])
    fifo = [0.0] * delay
    out = np.zeros(n)
    for k in range(n):
        if p is not None:
            tau = float((c @ x).ravel()[0]) + (kick_Nm if k == 10 else 0.0)
        else:
            tau = float(tau_in_in[k])
        r["t_s"] = r["lc_t_s"] = r["imu_t_s"] = r["motor_t_s"] = k * cfg.dt_s
        r["T_up_in_N"], r["T_lo_in_N"] = 150.0 + tau / 0.08, 150.0 - tau / 0.08
        r["T_up_out_N"] = r["T_lo_out_N"] = 150.0
        r["imu_new"] = 1
        u = ctl.step()
        out[k] = u if p is None else tau
        if p is not None:
            fifo.append(u)
            x = a @ x + (b * fifo.pop(0)).ravel()
    return out


@pytest.mark.parametrize("m", [LOCKSTEP_LDO, {"torque_loop": "pid", "feedback": {"kp": 0.5, "kd_s": 0.01,
                                                                                 "ki_1_s": 3.0}}])
def test_controller_transfer_function_is_the_step(m):
    """C(z) built from the step's coefficient functions reproduces the compiled step's
    response to a tau_in pulse to rounding (the analysis models the code that runs)."""
    cfg = ControllerConfig.from_mapping(_quiet(m))
    x = np.zeros(400)
    x[5] = 1e-3
    u = _run_step(cfg, None, 0, len(x), tau_in_in=x)
    c = controller_tf(cfg)
    assert np.max(np.abs(u + signal.lfilter(c[0], c[1], x))) < 1e-9 * np.max(np.abs(u))


@pytest.mark.parametrize("m,p,delay,grows", [
    (LOCKSTEP_LDO, PlantPoint(2640.0, 0.73, 0.5), 2, True),     # sheath stick, real delay: rings
    (LOCKSTEP_LDO, PlantPoint(2640.0, 0.73, 0.5), 0, False),    # the same in lock-step: fine
    (LOCKSTEP_LDO, PlantPoint(240.0, 0.73, 0.5), 2, False),
    ({}, PlantPoint(2640.0, 0.95, 0.5), 2, False),              # the loop before (kp 0)
    ({}, PlantPoint(250.0, 0.73, 0.5, slip=True), 2, False),
])
def test_predicted_poles_agree_with_a_time_domain_run_of_the_step(m, p, delay, grows):
    cfg = ControllerConfig.from_mapping(_quiet(m))
    rho = float(np.max(np.abs(closed_loop_poles(cfg, p, delay))))
    assert (rho > 1.0) == grows
    if grows:
        # growth from one 100-cycle window to the next as the dominant pole predicts
        tau = _run_step(cfg, p, delay, 320)
        a, b = np.max(np.abs(tau[100:200])), np.max(np.abs(tau[200:300]))
        assert 1.0 / 3.0 < (b / a) / rho ** 100 < 3.0 and b > 10.0 * a
    else:
        tau = _run_step(cfg, p, delay, 6000)
        assert np.max(np.abs(tau[-1000:])) < np.max(np.abs(tau[:1000]))


def test_open_loop_limit_is_the_motor_on_the_cable():
    """With no feedback and no delay the loop's slowest poles are the plant's own:
    f_n = sqrt(K_c / J_m) / 2 pi (design.md: 2.9-3.1 Hz) with damping B / (2 sqrt(K J))."""
    cfg = ControllerConfig.from_mapping(_quiet({"torque_loop": "pid", "feedback": {"kp": 0.0, "kd_s": 0.0,
                                                                                 "ki_1_s": 0.0}}))
    p = PlantPoint(240.0, 0.73, 0.5)
    poles = closed_loop_poles(cfg, p, 0)
    s = np.log(poles[np.abs(poles) > 0.9]) / cfg.dt_s
    wn, zeta = math.sqrt(240.0 / 0.73), 0.5 / (2.0 * math.sqrt(240.0 * 0.73))
    osc = s[np.abs(s.imag) > 1.0]
    assert np.allclose(np.abs(osc), wn, rtol=1e-6)
    assert np.allclose(-osc.real / np.abs(osc), zeta, rtol=1e-4)
    assert 2.8 < wn / (2 * math.pi) < 3.0


@pytest.mark.slow
def test_lockstep_gains_ring_where_the_hil_log_rang():
    """The lock-step gains with the 2-cycle delay on the sheath-stick plant (N + 1 = 11
    times K_c for the 10-node HIL model) grow at 40-55 Hz: the HIL log's command peaked at
    46-49 Hz (README "Torque loop")."""
    cfg = ControllerConfig.from_mapping(LOCKSTEP_LDO)
    rep = analyse(cfg)
    sheath_nominal = rep.points[22]           # sheath stick, middle stiffness and inertia
    assert not sheath_nominal.stable
    assert 40.0 < sheath_nominal.dominant_pole_hz < 55.0
    assert not rep.ok


@pytest.mark.parametrize("name", ["hil.yaml", "rig.yaml", "controller.yaml"])
def test_shipped_configs_meet_the_margins(name):
    raw = load_yaml(ROOT / "config" / name)["controller"]
    rep = analyse(ControllerConfig.from_mapping(raw))
    assert rep.all_stable
    assert rep.worst_phase_margin_deg >= 45.0 and rep.worst_gain_margin_dB >= 6.0
    assert len(rep.points) == 36


def _daemon_cfg(**controller) -> dict:
    raw = load_yaml(ROOT / "config" / "hil.yaml")
    raw["controller"].update(controller)
    return raw


@pytest.mark.slow
def test_start_up_refuses_gains_outside_the_margins_with_the_margin_they_would_have():
    cfg = DaemonConfig.from_mapping(_daemon_cfg(**LOCKSTEP_LDO))
    with pytest.raises(ConfigError) as err:
        build_controller(cfg)
    assert err.value.key == "controller.feedback"
    assert "phase margin" in err.value.reason and "UNSTABLE" in err.value.reason


@pytest.mark.slow
def test_lab_override_starts_them_and_says_why():
    raw = _daemon_cfg(**LOCKSTEP_LDO)
    raw["lab_override"] = {"margins": True, "reason": "reproduce the 48 Hz ring"}
    cfg = DaemonConfig.from_mapping(raw)
    assert cfg.lab_override.margins and cfg.lab_override.reason == "reproduce the 48 Hz ring"
    assert build_controller(cfg) is not None
    assert not check_margins(ControllerConfig.from_mapping(raw["controller"]), override=True).ok


@pytest.mark.slow
def test_margin_check_fails_for_a_gain_set_outside_and_passes_just_inside():
    """kp alone (no damping) on the lightly damped plant misses the gain margin; the
    deflection-rate damping makes kp 1.25 meet both (PM 48 deg at b 100; shipped: kp 0.75, b 60), while a larger kp or
    more damping than the delay allows (its own crossover near b / J_m) misses the phase margin."""
    bad = ControllerConfig.from_mapping({"torque_loop": "pid", "feedback": {"kp": 0.5, "kd_s": 0.0, "ki_1_s": 0.15,
                                                                          "deflection_damping_Nms_rad": 0.0}})
    with pytest.raises(ConfigError, match="gain margin"):
        check_margins(bad)
    assert check_margins(ControllerConfig.from_mapping({})).ok
    shipped = ControllerConfig.from_mapping({})
    assert shipped.feedback.kp == 0.75 and shipped.feedback.deflection_damping_Nms_rad == 100.0
    # the link's velocity at 150 Hz without the lag compensation, J_c 0.3, no band gain (tests/test_band_gain.py),
    # no output torque gain (tests/test_output_torque_gain.py)
    # and the drive's exact velocity (these margins' edges were found on it; the observer's lag moves them, PM 44.4 deg
    # at kp 1.25 / b 100: tests/test_motor_velocity.py checks the observer's set)
    plain = {**PREV_JC, "deflection_link_cutoff_hz": 150.0, "deflection_link_lag_compensation": False, "inertia_comp_kg_m2": 0.3,
             "band_gain": 0.0, "output_torque_gain": 0.0, "motor_velocity": "drive"}
    assert check_margins(ControllerConfig.from_mapping({"feedback": {**plain, "kp": 1.25,
                                                                     "deflection_damping_Nms_rad": 100.0}})).ok
    for kp, b in ((1.5, 100.0), (1.25, 130.0)):       # PM 44.8 and 44.5 deg: just outside
        cfg = ControllerConfig.from_mapping({"feedback": {**plain, "kp": kp, "deflection_damping_Nms_rad": b}})
        with pytest.raises(ConfigError, match="phase margin"):
            check_margins(cfg)
    just_in = check_margins(ControllerConfig.from_mapping({"feedback": {**plain, "kp": 1.4,
                                                                        "deflection_damping_Nms_rad": 100.0}}))
    assert 45.0 <= just_in.worst_phase_margin_deg < 47.0


def _stick_input_stiffness(amp_Nm: float) -> float:
    """Input stiffness [Nm/rad] of the HIL rig's distributed model (10 nodes) at rest under a
    2 Hz motor torque sine of ``amp_Nm``: slope of tau_in over the motor angle."""
    from capstan.models.plant.rig import SensorNoise, SimulatedRig
    raw = dict(load_yaml(ROOT / "config" / "hil.yaml")["hil"]["plant"])
    raw.pop("noise", None)
    raw.pop("seed", None)
    rig = SimulatedRig.from_mapping(raw)
    rig.noise = SensorNoise.none()
    for _ in range(500):
        rig.step(0.0, 0.0, 1e-3)
    q0, t0 = rig.model.q_in_rad, rig.model.tau_in_Nm
    q, t = np.zeros(1000), np.zeros(1000)
    for k in range(1000):
        rig.step(amp_Nm * math.sin(2 * math.pi * 2.0 * k * 1e-3), 0.0, 1e-3)
        q[k], t[k] = rig.model.q_in_rad - q0, rig.model.tau_in_Nm - t0
    return float(np.polyfit(q, t, 1)[0])


def test_sheath_stick_stiffness_is_what_the_distributed_model_shows():
    """The grid's stick levels against the distributed model (written apart from this
    analysis): small motions see about (N + 1) K_c, larger ones less, never below K_c;
    the grid spans K_c .. stick_stiffness_factor x K_c."""
    kc = 240.0
    small, large = _stick_input_stiffness(0.05), _stick_input_stiffness(1.0)
    f = ControllerConfig.from_mapping({}).stability.stick_stiffness_factor
    assert 0.85 * f * kc < small <= 1.02 * f * kc
    assert kc < large < small



@pytest.mark.slow
def test_loop_command_prints_strict_json_and_fails_on_missed_margins(capsys, tmp_path):
    import json

    import yaml

    from capstan.tools.cli import main
    assert main(["experiment", "loop", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out, parse_constant=lambda c: pytest.fail(f"non-strict JSON {c}"))
    assert doc["ok"] and doc["worst_gain_margin_dB"] >= 6.0 and len(doc["points"]) == 36
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"controller": LOCKSTEP_LDO}))
    assert main(["experiment", "loop", "--config", str(bad), "--json"]) == 1
    doc = json.loads(capsys.readouterr().out)
    assert not doc["ok"] and not doc["all_stable"]


def _run_step_physical(cfg: ControllerConfig, p: PlantPoint, delay: int, n: int, imu_every: float = 2.5,
                       kick_rad_s: float = 1e-2) -> np.ndarray:
    """The real Numba step in closed loop with the physical-state ZOH plant (q_m, dq_m[, q_o, dq_o]):
    load cells and the drive's velocity every cycle, the IMU's rate every ``imu_every`` cycles
    (400 Hz), a command FIFO of ``delay`` cycles and a velocity kick at cycle 10.
    Returns the motor velocity per cycle [rad/s]."""
    from capstan.controller.law.loop_model import plant_state_space
    a, b, c = plant_state_space(p, cfg.dt_s)
    x = np.zeros(a.shape[0])
    ctl = Controller(cfg)
    r = ctl.record[0]
    fifo = [0.0] * delay
    out = np.zeros(n)
    next_imu = 0.0
    for k in range(n):
        if k == 10:
            x[1] += kick_rad_s
            if p.slip:
                x[3] += kick_rad_s
        tau = float(c @ x)
        r["t_s"] = r["lc_t_s"] = r["imu_t_s"] = r["motor_t_s"] = k * cfg.dt_s
        r["T_up_in_N"], r["T_lo_in_N"] = 150.0 + tau / 0.08, 150.0 - tau / 0.08
        r["T_up_out_N"] = r["T_lo_out_N"] = 150.0
        r["q_m_rad"], r["dq_m_rad_s"] = x[0], x[1]       # the encoder's position (the observer's) and 0x606C
        r["imu_new"] = 0
        if k >= next_imu:
            r["imu_new"] = 1
            r["dq_out_rad_s"] = x[3] if p.slip else 0.0
            r["q_out_rad"] = x[2] if p.slip else 0.0
            next_imu += imu_every
        fifo.append(ctl.step())
        x = a @ x + b * fifo.pop(0)
        out[k] = x[1]
    return out


@pytest.mark.parametrize("fb,p,grows", [
    # motor acceleration: the sheath-stick mode (3300 Nm/rad) with J_m - J_c and the filter's lag rings
    ({"inertia_comp_kg_m2": 0.3, "acceleration_cutoff_hz": 10.0, "acceleration_source": "motor"},
     PlantPoint(3300.0, 0.51, 0.5), True),
    # link acceleration (IMU at 400 Hz): the link's free pendulum mode, too much compensation
    ({"inertia_comp_kg_m2": 0.6, "acceleration_cutoff_hz": 5.0}, PlantPoint(200.0, 0.51, 0.5, slip=True), True),
    # ... and the shipped amount on the same point
    ({"inertia_comp_kg_m2": 0.2, "acceleration_cutoff_hz": 5.0}, PlantPoint(200.0, 0.51, 0.5, slip=True), False),
    ({"inertia_comp_kg_m2": 0.2, "acceleration_cutoff_hz": 5.0}, PlantPoint(3300.0, 0.51, 0.5), False),
])
def test_inertia_compensation_poles_agree_with_the_step(fb, p, grows):
    """The analysis's closed loop with the inertia compensation (its acceleration filter, the
    IMU's 400 Hz sample-and-hold modelled as one extra cycle) predicts what the compiled step
    does against a physical plant: growth per window as the dominant pole says, or decay."""
    m = _quiet({"feedback": fb})
    m["feedforward"]["dead_band_rad_s"] = 0.0       # rest gate open: the linear loop the analysis has
    m["stability"] = {"gyro_noise_rad_s": 0.0}      # (allowed only for a noiseless gyro)
    cfg = ControllerConfig.from_mapping(m)
    poles = closed_loop_poles(cfg, p, 2)
    rho = float(np.max(np.abs(poles)))
    assert (rho > 1.0) == grows
    if grows:
        n_win = int(min(3000, max(100, round(math.log(20.0) / math.log(rho)))))    # x5 to x20 per window
        v = _run_step_physical(cfg, p, 2, 500 + 2 * n_win)
        a_, b_ = (np.max(np.abs(v[500 + i * n_win:500 + (i + 1) * n_win])) for i in (0, 1))
        assert 1.0 / 3.0 < (b_ / a_) / rho ** n_win < 3.0 and b_ > 2.0 * a_
    else:
        v = _run_step_physical(cfg, p, 2, 8000)
        assert np.max(np.abs(v[-1000:])) < 0.2 * np.max(np.abs(v[:1000]))


@pytest.mark.slow
def test_inertia_compensation_margins_and_its_limit():
    """J_c lowers the inertia the hand feels but eats margin: 0.3 kg m^2 from the link's
    acceleration meets PM >= 45 deg, GM >= 6 dB over the grid with the gravity model on, 0.34
    does not; without the gravity model (the link's full pendulum stiffness in slip) 0.2 does,
    0.3 does not; an amount at or above the lightest joint inertia is refused by name."""
    for jc, gravity, good in ((0.3, True, True), (0.34, True, False), (0.2, False, True), (0.3, False, False)):
        cfg = ControllerConfig.from_mapping({"feedback": {**PREV_JC, "inertia_comp_kg_m2": jc, "acceleration_cutoff_hz": 5.0,
                                                          "output_torque_gain": 0.0,
                                                          "deflection_link_lag_compensation": False},
                                             "gravity": {"enabled": gravity}})
        assert analyse(cfg).ok == good, (jc, gravity)
    ok = cfg
    j_min = 0.73 * (1 - ok.stability.inertia_tolerance) + ok.stability.link_inertia_kg_m2
    with pytest.raises(ConfigError, match="inertia_comp_kg_m2"):
        ControllerConfig.from_mapping({"feedback": {"inertia_comp_kg_m2": j_min}})
    with pytest.raises(ConfigError, match="dead_band_rad_s"):      # no rest band: gyro noise on the command
        ControllerConfig.from_mapping({"feedforward": {"enabled": False, "dead_band_rad_s": 0.0}})
    with pytest.raises(ConfigError, match="deflection_damping_Nms_rad"):   # the damping's link velocity too
        ControllerConfig.from_mapping({"feedforward": {"enabled": False, "dead_band_rad_s": 0.0},
                                       "feedback": {"inertia_comp_kg_m2": 0.0}})
    ControllerConfig.from_mapping({"feedforward": {"enabled": False, "dead_band_rad_s": 0.0},
                                   "feedback": {**OLD_LOOP, "inertia_comp_kg_m2": 0.0}})
    with pytest.raises(ConfigError, match="acceleration_source"):
        ControllerConfig.from_mapping({"feedback": {"acceleration_source": "wheel"}})


def test_inertia_compensation_is_off_at_rest():
    """At rest (joint rate inside the feedforward's rest band) the differentiated gyro noise
    does not reach the command: the same noisy run with and without J_c commands the same."""
    rng = np.random.default_rng(3)
    cmds = []
    for jc in (0.0, 0.2):
        ctl = Controller(ControllerConfig.from_mapping(_quiet({"feedback": {"inertia_comp_kg_m2": jc}})))
        r = ctl.record[0]
        noise = rng.normal(0.0, 2e-3, 4000) if jc == 0.0 else noise
        out = []
        for k in range(4000):
            r["t_s"] = r["lc_t_s"] = r["imu_t_s"] = r["motor_t_s"] = k * 1e-3
            r["T_up_in_N"] = r["T_lo_in_N"] = r["T_up_out_N"] = r["T_lo_out_N"] = 150.0
            r["imu_new"] = 1 if k % 5 in (0, 3) else 0
            r["dq_out_rad_s"] = noise[k]
            out.append(ctl.step())
        cmds.append(np.array(out))
    assert np.array_equal(cmds[0], cmds[1])
    # and the gate opens in motion: a ramp in the joint rate gives J_c x the acceleration
    ctl = Controller(ControllerConfig.from_mapping(_quiet({"feedback": {"inertia_comp_kg_m2": 0.2}})))
    r = ctl.record[0]
    for k in range(3000):
        r["t_s"] = r["lc_t_s"] = r["imu_t_s"] = r["motor_t_s"] = k * 1e-3
        r["T_up_in_N"] = r["T_lo_in_N"] = r["T_up_out_N"] = r["T_lo_out_N"] = 150.0
        r["imu_new"] = 1 if k % 5 in (0, 3) else 0
        r["dq_out_rad_s"] = 0.05 + 2.0 * k * 1e-3          # 2 rad/s^2
        u = ctl.step()
    assert u == pytest.approx(0.2 * 2.0, rel=1e-3)


def test_one_gyro_noise_sample_beyond_the_rest_band_does_not_kick_the_command():
    """A single IMU sample beyond the rest gate's lower edge (noise past 4 sigma, about one in
    16000 samples; seen in a HIL log as a 3-cycle 0.04 Nm blip at J_c 0.3) does not open the
    inertia compensation: the command equals the one without J_c. A joint that keeps moving
    (two samples in a row and more outside) gets it, and smoothly: the gate acts before the
    acceleration's low-pass, so the command does not step when it opens or closes."""
    def run(jc: float, rate) -> np.ndarray:
        ctl = Controller(ControllerConfig.from_mapping(_quiet({"feedback": {"inertia_comp_kg_m2": jc}})))
        r = ctl.record[0]
        out = []
        for k in range(600):
            r["t_s"] = r["lc_t_s"] = r["imu_t_s"] = r["motor_t_s"] = k * 1e-3
            r["T_up_in_N"] = r["T_lo_in_N"] = r["T_up_out_N"] = r["T_lo_out_N"] = 150.0
            r["imu_new"] = 1 if k % 5 in (0, 3) else 0
            r["dq_out_rad_s"] = rate(k)                 # band 0.01: lower edge at 0.008 rad/s
            out.append(ctl.step())
        return np.array(out)

    def spike(k: int) -> float:
        return 0.009 if 200 <= k < 203 else 0.0

    def stroke(k: int) -> float:                       # 2 rad/s^2 up for 0.1 s, then down to rest
        t = (k - 200) * 1e-3
        return 0.0 if k < 200 or t > 0.2 else 2.0 * min(t, 0.2 - t)
    assert np.array_equal(run(0.3, spike), run(0.0, spike))
    u = run(0.3, stroke) - run(0.0, stroke)
    assert np.max(u) > 0.3 * 0.3 * 2.0                 # J_c x a reaches the command while moving
    # the gate closes at 8 mrad/s while the joint still slows at 2 rad/s^2: a gate on the output would
    # drop J_c x a (0.57 Nm) in one cycle; on the input the low-pass (5 Hz: 3 % per cycle) lets it decay
    assert np.max(np.abs(np.diff(u))) < 0.1 * np.max(np.abs(u))


def test_acceleration_filter_is_the_step():
    """A(z) of the analysis reproduces the compiled step's response to a motor-velocity pulse
    (motor source, rest gate open) to rounding: u = J_c A(z) dq_m (on the drive's velocity: the observer's own
    paths are tests/test_motor_velocity.py's)."""
    from capstan.controller.law.loop_model import acceleration_filter
    m = _quiet({"feedback": {"inertia_comp_kg_m2": 0.2, "acceleration_cutoff_hz": 7.0, "acceleration_source": "motor",
                             "ki_1_s": 0.0, "motor_velocity": "drive"}})
    m["feedforward"]["dead_band_rad_s"] = 0.0
    m["stability"] = {"gyro_noise_rad_s": 0.0}
    cfg = ControllerConfig.from_mapping(m)
    ctl = Controller(cfg)
    r = ctl.record[0]
    v = np.zeros(300)
    v[5] = 1e-2
    u = np.zeros(len(v))
    for k in range(len(v)):
        r["t_s"] = r["lc_t_s"] = r["imu_t_s"] = r["motor_t_s"] = k * cfg.dt_s
        r["T_up_in_N"] = r["T_lo_in_N"] = r["T_up_out_N"] = r["T_lo_out_N"] = 150.0
        r["imu_new"] = 1
        r["dq_m_rad_s"] = v[k]
        u[k] = ctl.step()
    a = acceleration_filter(cfg)
    assert np.max(np.abs(u - 0.2 * signal.lfilter(a[0], a[1], v))) < 1e-9 * np.max(np.abs(u))


@pytest.mark.parametrize("gravity_model", [True, False])
def test_slip_points_keep_the_gravity_models_residual_as_the_step_does(gravity_model):
    """In slip the step's gravity model (m_g_l sin q_out, a positive feedback of the link angle)
    cancels the link's gravity stiffness; the analysis keeps only the residual
    (``stability.gravity_model_error``). Against the compiled step closed on the full link
    (gravity stiffness 3.78 Nm/rad) with a gravity model 25 % short: J_c 0.6 decays as the
    residual point's poles say, and grows as the full-stiffness point says when the gravity
    model is off. The loop's dominant pole sets the rate in both (within x3 per window)."""
    from capstan.controller.law.stability import plant_points, slip_link_stiffness_Nm_rad
    m = _quiet({"feedback": {"inertia_comp_kg_m2": 0.6, "acceleration_cutoff_hz": 5.0, "ki_1_s": 0.0}})
    m["gravity"] = {"enabled": gravity_model, "m_g_l_Nm": 3.78 * 0.75}
    m["feedforward"]["dead_band_rad_s"] = 0.0
    m["stability"] = {"gyro_noise_rad_s": 0.0, "gravity_model_error": 0.25, "link_stiffness_Nm_rad": 3.78}
    cfg = ControllerConfig.from_mapping(m)
    k_seen = slip_link_stiffness_Nm_rad(cfg, cfg.stability)
    assert k_seen == pytest.approx(0.945 if gravity_model else 3.78)
    assert all(p.link_stiffness_Nm_rad == k_seen for p in plant_points(cfg, cfg.stability) if p.slip)
    real = PlantPoint(200.0, 0.51, 0.5, slip=True, link_stiffness_Nm_rad=3.78)
    seen = PlantPoint(200.0, 0.51, 0.5, slip=True, link_stiffness_Nm_rad=k_seen)
    poles = closed_loop_poles(cfg, seen, 2)
    osc = poles[np.abs(np.angle(poles)) > 2 * math.pi * 0.1 * cfg.dt_s]      # the link's mode, not the drift
    rho = float(np.max(np.abs(osc)))
    assert (rho > 1.0) == (not gravity_model)
    n_win = 2000
    v = _run_step_physical(cfg, real, 2, 500 + 3 * n_win)
    a_, b_ = (np.max(np.abs(v[500 + i * n_win:500 + (i + 1) * n_win])) for i in (1, 2))
    assert 1.0 / 3.0 < (b_ / a_) / rho ** n_win < 3.0
    assert (b_ > a_) == (not gravity_model)
