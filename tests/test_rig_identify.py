"""Rig identification (capstan.models.rig_id) and tuning (capstan.controller.law.tuning).

Fast: the excitation's limits, bad input, each fit on signals of a known linear model.
Slow: identification on the package's simulated rig with realistic devices for four plant
variants 20-40 % off the nominal (5 noise seeds each), on the independent dense model of
tests/independent_distributed.py (written from the paper, no package code) between a motor
and a pendulum, and the tuner on an identified plant, checked on the true plant.

Bars (issue #28): K_c, J_m and m g l within 10 % of the truth; the stated uncertainties
consistent with the error: |error| <= 3 stderr for at least 90 % of the (parameter, seed)
pairs of K_c, J_m, m g l, J_l (every seed kept and reported).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from capstan.models.common.errors import ConfigError, DataFormatError, ModelError
from capstan.models.rig_id import ExcitationLimits, RigRun, free_excitation, held_excitation
from capstan.models.rig_id.fits import Estimate, fit_link, fit_motor, fit_stiffness
from capstan.models.rig_id.identify import combine

DT = 1e-3


# ---- excitation ---------------------------------------------------------------------------------
def test_held_excitation_stays_within_the_torque_limit_and_fades_to_zero():
    lim = ExcitationLimits(tau_max_Nm=3.0, dq_max_rad_s=2.0, q_max_rad=0.5)
    exc = held_excitation(lim)
    u = np.array([exc.torque_Nm(i * DT, 0.0, 0.0) for i in range(exc.n_cycles)])
    assert np.max(np.abs(u)) <= 0.95 * 3.0 + 1e-12
    assert np.max(np.abs(u)) > 0.8 * 3.0            # the run uses the torque it may
    assert abs(u[0]) < 1e-9 and abs(u[-1]) < 1e-3    # faded in and out
    assert exc.torque_Nm(exc.duration_s + 1.0, 0.0, 0.0) == 0.0
    assert exc.describe()["kind"] == "held" and exc.describe()["limits"]["tau_max_Nm"] == 3.0


def test_free_excitation_clips_its_pd_and_names_the_limit_passed():
    lim = ExcitationLimits(tau_max_Nm=2.0, dq_max_rad_s=1.0, q_max_rad=0.4)
    exc = free_excitation(lim)
    assert exc.torque_Nm(0.0, 5.0, 0.0) == 0.0          # latches the start angle: no error at t = 0
    assert exc.torque_Nm(10.0, 5.0 - 10.0, 0.0) == 2.0  # far below the reference: clipped to +tau_max
    assert exc.torque_Nm(10.0, 5.0 + 10.0, 0.0) == -2.0
    assert exc.within_limits(5.2, 0.5) is None
    assert "angle" in exc.within_limits(5.5, 0.0)
    assert "speed" in exc.within_limits(5.0, -1.5)
    ref = exc.q_ref_rad
    assert np.max(np.abs(ref)) <= 0.8 * 0.4 + 1e-12
    assert np.max(np.abs(np.diff(ref))) / DT <= 0.5 * 1.0


def test_bad_limits_and_too_fast_sweeps_are_refused_by_name():
    with pytest.raises(ConfigError, match="limits.tau_max_Nm"):
        ExcitationLimits(tau_max_Nm=-1.0)
    with pytest.raises(ConfigError, match="limits.q_max_rad"):
        ExcitationLimits(q_max_rad=float("nan"))
    with pytest.raises(ConfigError, match="sweep_hz"):
        free_excitation(ExcitationLimits(dq_max_rad_s=0.1, q_max_rad=1.0))


# ---- runs ----------------------------------------------------------------------------------------
def _cols(n: int = 5000) -> dict[str, np.ndarray]:
    t = np.arange(n) * DT
    z = np.zeros(n)
    return {"t_s": t, "q_m_rad": z, "tau_m_cmd_Nm": z, "T_up_in_N": z + 150, "T_up_out_N": z + 150,
            "T_lo_out_N": z + 150, "T_lo_in_N": z + 150, "q_out_rad": np.sin(t)}


def test_a_run_missing_a_column_or_too_short_is_named():
    c = _cols()
    del c["T_lo_in_N"]
    with pytest.raises(DataFormatError, match="T_lo_in_N"):
        RigRun.from_arrays(c, 0.04, 0.04, "held.mcap")
    with pytest.raises(DataFormatError, match="at least"):
        RigRun.from_arrays(_cols(500), 0.04, 0.04)
    c = _cols()
    c["q_m_rad"] = c["q_m_rad"].copy()
    c["q_m_rad"][7] = np.nan
    with pytest.raises(DataFormatError, match="q_m_rad.*non-finite"):
        RigRun.from_arrays(c, 0.04, 0.04)


def test_a_motionless_run_says_what_it_lacks():
    run = RigRun.from_arrays(_cols(), 0.04, 0.04)
    with pytest.raises(ModelError, match="did not move"):
        fit_motor(run)
    with pytest.raises(ModelError, match="slid"):
        fit_stiffness(run)


# ---- fits on a known linear model -------------------------------------------------------------------
def _multisine(t: np.ndarray, freqs: np.ndarray, amp: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x, dx, ddx of a sum of sines (exact derivatives)."""
    ph = np.random.default_rng(seed).uniform(0, 2 * np.pi, len(freqs))
    w = 2 * np.pi * freqs
    arg = np.outer(t, w) + ph
    return amp * np.sin(arg).sum(1), amp * (w * np.cos(arg)).sum(1), -amp * (w ** 2 * np.sin(arg)).sum(1)


def test_motor_fit_recovers_inertia_damping_and_the_command_delay_from_a_quantised_encoder():
    J, b, delay = 0.61, 0.3, 3
    n = 20000
    t = np.arange(n) * DT
    q, dq, ddq = _multisine(t, np.linspace(0.5, 8.0, 16), 0.002, 1)
    tau_in = 2.0 * np.sin(2 * np.pi * 0.3 * t) + 40.0 * q          # any cable torque
    tau_applied = J * ddq + b * dq + tau_in
    cmd = np.r_[tau_applied[delay:], np.full(delay, tau_applied[-1])]  # the command leads what acts by `delay`
    step = 2 * np.pi / 2 ** 17
    c = _cols(n)
    T_diff = tau_in / 0.04
    c.update(q_m_rad=np.round(q / step) * step, tau_m_cmd_Nm=cmd, T_up_in_N=150 + T_diff / 2, T_lo_in_N=150 - T_diff / 2)
    fit = fit_motor(RigRun.from_arrays(c, 0.04, 0.04))
    assert fit.delay_cycles == delay
    assert fit.J_m.value == pytest.approx(J, rel=0.01)               # claim: 1 % on exact signals + quantisation
    assert fit.b_m.value == pytest.approx(b, rel=0.05)
    assert abs(fit.J_m.value - J) <= 3 * fit.J_m.stderr + 1e-3 * J


def test_link_fit_recovers_gravity_inertia_and_damping_of_a_pendulum_from_400_hz_imu_samples():
    J_l, b_l, mgl = 0.21, 0.03, 4.2
    n = 30000
    t = np.arange(n) * DT
    q, dq, ddq = _multisine(t, np.array([0.05, 0.4, 0.9, 1.7, 2.6]), 0.15, 2)
    tau_out = J_l * ddq + b_l * dq + mgl * np.sin(q) + 0.05
    held = np.floor(t * 400.0 + 1e-9).astype(int)
    new = np.r_[True, np.diff(held) > 0]
    pick = np.maximum.accumulate(np.where(new, np.arange(n), 0))
    c = _cols(n)
    c.update(q_out_rad=q[pick], imu_new=new.astype(float), T_up_out_N=150 + tau_out / 0.08, T_lo_out_N=150 - tau_out / 0.08)
    fit = fit_link(RigRun.from_arrays(c, 0.04, 0.04))
    assert fit.m_g_l.value == pytest.approx(mgl, rel=0.005)        # claim: 0.5 % on exact signals
    assert fit.J_l.value == pytest.approx(J_l, rel=0.02)
    assert fit.offset_Nm == pytest.approx(0.05, abs=0.005)


def test_combining_two_runs_that_disagree_widens_the_uncertainty():
    a, b = Estimate(100.0, 1.0, "Nm/rad"), Estimate(110.0, 1.0, "Nm/rad")
    c = combine(a, b, "K")
    assert c.value == pytest.approx(105.0)
    assert c.stderr == pytest.approx(math.hypot(1 / math.sqrt(2), 5.0))
    assert combine(a, Estimate(100.0, 1.0, "Nm/rad"), "K").stderr == pytest.approx(1 / math.sqrt(2))


# ---- the simulated rig and the independent model ---------------------------------------------------------
def _check_bars(rows: list[dict], where: str) -> None:
    """rows: per seed {param: (value, stderr, truth)}; the bars of the module docstring."""
    report = "\n".join(f"{where} seed {i}: " + ", ".join(f"{k} {v:.4g} +- {s:.2g} (true {tr:.4g})"
                                                        for k, (v, s, tr) in r.items()) for i, r in enumerate(rows))
    print(report)
    for r in rows:
        for k in ("K_c", "J_m", "m_g_l"):
            v, _, tr = r[k]
            assert abs(v / tr - 1.0) <= 0.10, f"{k} off by more than 10 %:\n{report}"
    pairs = [(k, r[k]) for r in rows for k in ("K_c", "J_m", "m_g_l", "J_l")]
    inside = sum(abs(v - tr) <= 3.0 * s for _, (v, s, tr) in pairs)
    assert inside >= 0.9 * len(pairs), f"only {inside} of {len(pairs)} errors within 3 stated stderr:\n{report}"


def _rows(ident, tr: dict[str, float]) -> dict[str, tuple[float, float, float]]:
    d = ident.to_dict()
    row = {k: (d[k]["value"], d[k]["stderr"], tr[k]) for k in ("K_c", "J_m", "m_g_l", "J_l")}
    fr = d["friction"]
    row["mu_theta"] = (fr["mu_theta"]["value"], fr["mu_theta"]["stderr"], tr["mu"] * tr["theta"])
    return row


@pytest.mark.slow
@pytest.mark.parametrize("name", ["nominal", "heavy_motor_soft", "light_motor_stiff", "bent_tight"])
def test_identifies_plant_variants_of_the_simulated_rig_with_realistic_devices(name):
    from tests.rig_id_sim import VARIANTS, identify_plant, truth
    plant = VARIANTS[name]
    tr = truth(plant) | {"theta": plant["routing"]["theta_rad"]}
    rows = [_rows(identify_plant(plant, seed)[0], tr) for seed in range(5)]
    _check_bars(rows, name)
    for r in rows:       # the friction's magnitude: mu theta (the drawings' bending may be off)
        v, s, t = r["mu_theta"]
        assert abs(v / t - 1.0) <= 0.10


@pytest.mark.slow
def test_identifies_the_independent_dense_model_between_a_motor_and_a_pendulum():
    from capstan.models.rig_id import RigGeometry, identify_rig
    from tests.rig_id_independent import IndependentRig, sample
    true = dict(K_c=300.0, mu=0.065, J_m=0.55, b_m=0.1, J_l=0.21, b_l=0.02, m_g_l=4.6)
    rig = IndependentRig(**true, n_nodes=2)
    lim = ExcitationLimits()
    held = rig.simulate(held_excitation(lim, duration_s=12.0, f_high_hz=8.0), True)
    free = rig.simulate(free_excitation(lim, duration_s=20.0, sweep_hz=0.1), False)
    rows = []
    for seed in range(5):      # the sensors do not feed back: one trajectory, five noise draws
        ident = identify_rig(RigRun.from_arrays(sample(held, seed), 0.04, 0.04, f"held {seed}"),
                             RigRun.from_arrays(sample(free, 100 + seed), 0.04, 0.04, f"free {seed}"),
                             RigGeometry(0.04, 0.04, 3.0))
        rows.append(_rows(ident, true | {"theta": 3.0}))
    _check_bars(rows, "independent")


# ---- tuning -------------------------------------------------------------------------------------------
def _shipped_controller() -> dict:
    from pathlib import Path

    import yaml
    return yaml.safe_load((Path(__file__).resolve().parents[1] / "config" / "controller.yaml").read_text())["controller"]


def _ident(K_c: float, J_m: float, m_g_l: float, J_l: float, tau_fc: float, T0: float = 145.0, rel: float = 0.01):
    """An identification as identify_rig returns it, for the given plant (stderr ``rel`` of each value)."""
    from capstan.models.rig_id import RigGeometry, RigIdentification

    def e(v: float, unit: str) -> Estimate:
        return Estimate(v, abs(v) * rel, unit)
    fr = {"tau_fc": e(tau_fc, "Nm"), "zeta_s": e(1.1, "-"), "eta_s_rad_s": e(0.02, "rad/s"),
          "alpha_s_rad": e(60.0, "s/rad"), "b_vis": e(0.01, "Nm s/rad"), "T0": e(T0, "N")}
    return RigIdentification(e(K_c, "Nm/rad"), e(J_m, "kg m^2"), e(0.1, "Nm s/rad"), e(m_g_l, "Nm"), e(J_l, "kg m^2"),
                             e(0.02, "Nm s/rad"), fr, 1, RigGeometry(0.04, 0.04, 3.0), {"runs": "synthetic"})


def test_solve_mu_inverts_the_feedforward_friction_on_the_configured_routing():
    from dataclasses import replace

    from capstan.controller.law.config import ControllerConfig
    from capstan.controller.law.feedforward import friction_torque_per_N
    from capstan.controller.law.tuning import solve_mu
    cfg = ControllerConfig.from_mapping(_shipped_controller())
    tau = friction_torque_per_N(replace(cfg.feedforward, mu=0.071), cfg.plant.r_out_m) * 133.0
    assert solve_mu(cfg, tau, 133.0) == pytest.approx(0.071, rel=1e-5)
    with pytest.raises(ModelError, match="no friction coefficient"):
        solve_mu(cfg, -1.0, 133.0)


def test_the_identified_plant_replaces_every_plant_value_and_carries_the_gains_over():
    from capstan.controller.law.config import ControllerConfig
    from capstan.controller.law.tuning import plant_controller
    base = _shipped_controller()
    m = plant_controller(_ident(K_c=310.0, J_m=0.5, m_g_l=4.9, J_l=0.23, tau_fc=1.4), base)
    cfg = ControllerConfig.from_mapping(m)           # a valid controller section
    assert (cfg.plant.stiffness_Nm_rad, cfg.plant.motor_inertia_kg_m2, cfg.m_g_l_Nm) == (310.0, 0.5, 4.9)
    st = cfg.stability
    assert st.stiffness_range_Nm_rad == pytest.approx((310.0 * 0.85, 310.0 * 1.15))   # 3 x 1 % < the 15 % floor
    assert (st.link_inertia_kg_m2, st.link_stiffness_Nm_rad, st.io_delay_cycles) == (0.23, 4.9, 2)
    b = base["feedback"]
    assert cfg.feedback.inertia_comp_kg_m2 == pytest.approx(b["inertia_comp_kg_m2"] * 0.5 / 0.73)
    assert cfg.feedback.deflection_damping_Nms_rad == pytest.approx(
        b["deflection_damping_Nms_rad"] * math.sqrt(310.0 * 0.5 / (240.0 * 0.73)))
    assert cfg.feedforward.mu != base["feedforward"]["mu"]
    wide = plant_controller(_ident(K_c=310.0, J_m=0.5, m_g_l=4.9, J_l=0.23, tau_fc=1.4, rel=0.1), base)
    assert wide["stability"]["stiffness_range_Nm_rad"] == pytest.approx([310.0 * 0.7, 310.0 * 1.3])


@pytest.mark.slow
def test_tuned_gains_pass_the_start_up_check_on_the_true_plant():
    """Tune for an identification of the light, stiff variant (K_c +35 %, J_m -30 %, link +30-40 %),
    then check the tuned gains with the variant's true values in the check (not the identified)."""
    from capstan.controller.law.config import ControllerConfig
    from capstan.controller.law.stability import analyse
    from capstan.controller.law.tuning import tune_controller
    true = dict(K_c=324.0, J_m=0.511, m_g_l=4.914, J_l=0.238)
    ident = _ident(K_c=true["K_c"] * 0.99, J_m=true["J_m"] * 0.997, m_g_l=true["m_g_l"], J_l=true["J_l"] * 0.985,
                   tau_fc=1.36)
    res = tune_controller(ident, _shipped_controller())
    print(res.report["factor"], res.report["stability"], [t for t in res.report["tried"]])
    assert res.stability.ok and 0.3 <= res.factor
    ctrl = res.controller
    ctrl["plant"].update(stiffness_Nm_rad=true["K_c"], motor_inertia_kg_m2=true["J_m"])
    ctrl["stability"].update(link_inertia_kg_m2=true["J_l"], link_stiffness_Nm_rad=true["m_g_l"])
    rep = analyse(ControllerConfig.from_mapping(ctrl))
    assert rep.ok, rep.summary()
    assert rep.worst_phase_margin_deg >= 45.0 and rep.worst_gain_margin_dB >= 6.0
