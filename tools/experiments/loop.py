"""``capstan experiment loop``: the torque loop's margins with the real I/O delay, and the
check of the model against a HIL (or rig) log.

    capstan experiment loop [--config config/hil.yaml] [--log RUN.mcap] [--json]

Without ``--log``: the margins, sensitivity peak, predicted closed-loop resonance and
noise gains of :func:`capstan.controller.law.stability.analyse` at every plant point.
``--json`` prints one strict JSON object (a margin without a crossing, e.g. a phase margin
when ``|L|`` never reaches 1, is ``null``). With ``--log``: from the log's cycle records

* the command -> measured motor torque lag in cycles (cross-correlation of the two),
  which the config's ``io_delay_cycles`` models;
* the command's spectrum peak and the share of its power above 20 Hz, and the peak the
  analysis predicts for the *logged* controller config at the sheath-stick plant points
  (a ringing loop shows its resonance there; a quiet one has no peak to compare).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from capstan.controller.law.config import ControllerConfig
from capstan.controller.law.stability import MODES, analyse, slip_link_stiffness_Nm_rad
from capstan.models.common.config_tools import load_yaml
from capstan.tools.offline.shipped import config_path


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``capstan experiment loop``."""
    p.add_argument("--config", default=None, help="daemon or controller config YAML (default: the shipped hil.yaml)")
    p.add_argument("--log", default=None, help="a HIL/rig MCAP log to check the delay and resonance against")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def command_lag_cycles(cmd_Nm: np.ndarray, meas_Nm: np.ndarray, max_lag: int = 10) -> int:
    """Lag [cycles] at which the measured motor torque best matches the command (least
    squares over lags 0..max_lag)."""
    n = len(cmd_Nm)
    if n <= max_lag + 10:
        return -1
    err = [float(np.mean((meas_Nm[k:] - cmd_Nm[:n - k]) ** 2)) for k in range(max_lag + 1)]
    return int(np.argmin(err))


def spectrum_figures(x: np.ndarray, dt_s: float, split_hz: float = 20.0) -> dict[str, float]:
    """Peak frequency [Hz] and share of power above ``split_hz`` of ``x`` (mean removed)."""
    x = np.asarray(x, dtype=float) - float(np.mean(x))
    p = np.abs(np.fft.rfft(x * np.hanning(len(x)))) ** 2
    f = np.fft.rfftfreq(len(x), dt_s)
    tot = float(p[1:].sum())
    return {"peak_hz": float(f[1:][np.argmax(p[1:])]) if tot > 0 else math.nan,
            "share_above_20hz": float(p[f > split_hz].sum() / tot) if tot > 0 else 0.0}


def log_check(path: Path) -> dict[str, Any]:
    """Delay and spectrum of a daemon log, with the prediction for its own controller config.

    :raises DataFormatError: if the log cannot be read.
    """
    from capstan.controller.log.reader import read_log
    d = read_log(path)
    r = d.records[d.records["phase"] == 1]
    cmd = r["tau_m_cmd_Nm"].astype(float)
    meas = r["tau_m_meas_Nm"].astype(float)
    sec = d.config.get("controller", {}) if isinstance(d.config, Mapping) else {}
    ccfg = ControllerConfig.from_mapping(sec if isinstance(sec, Mapping) else {})
    out: dict[str, Any] = {"log": str(path), "cycles": int(len(r)),
                           "measured_lag_cycles": command_lag_cycles(cmd, meas),
                           "config_io_delay_cycles": ccfg.stability.io_delay_cycles,
                           "command_std_Nm": float(np.std(cmd)),
                           "command_change_rms_Nm": float(np.sqrt(np.mean(np.diff(cmd) ** 2))) if len(cmd) > 1 else 0.0,
                           **{f"command_{k}": v for k, v in spectrum_figures(cmd, ccfg.dt_s).items()}}
    rep = analyse(ccfg)
    sheath = rep.points[18:27]          # sheath stick at the full factor (MODES)
    out["predicted_resonance_hz"] = [round(p.dominant_pole_hz if not p.stable else p.resonance_hz, 1)
                                     for p in sheath]
    out["predicted_stable"] = all(p.stable for p in sheath)
    return out


def _finite_or_null(x: Any) -> Any:
    """``x`` with every non-finite float replaced by None (e.g. PM = inf without a crossover)."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _finite_or_null(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite_or_null(v) for v in x]
    return x


def run(args: argparse.Namespace) -> int:
    """Print the analysis (and the log check); exit code 0 if the margins hold, 1 if not.

    :raises ConfigError: on an invalid config; ``DataFormatError`` on an unreadable log.
    """
    path = config_path("hil.yaml") if args.config is None else Path(args.config)
    raw = load_yaml(path)
    sec = raw.get("controller", raw) if isinstance(raw, Mapping) else {}
    cfg = ControllerConfig.from_mapping(sec)
    rep = analyse(cfg)
    k_slip = slip_link_stiffness_Nm_rad(cfg, cfg.stability)
    out: dict[str, Any] = {"config": str(path), **rep.to_dict(), "slip_link_stiffness_Nm_rad": k_slip}
    if args.log:
        out["log_check"] = log_check(Path(args.log))
    if args.json:
        print(json.dumps(_finite_or_null(out), allow_nan=False))   # inf/nan -> null: strict JSON
        return 0 if rep.ok else 1
    st = cfg.stability
    print(f"torque loop of {path}: {cfg.torque_loop.name.lower()}, kp {cfg.feedback.kp:g}, kd {cfg.feedback.kd_s:g} s, "
          f"ki {cfg.feedback.ki_1_s:g} 1/s, inertia compensation {cfg.feedback.inertia_comp_kg_m2:g} kg m^2 "
          f"({cfg.feedback.acceleration_source.name.lower()}, {cfg.feedback.acceleration_cutoff_hz:g} Hz), "
          f"I/O delay {st.io_delay_cycles} cycles")
    fb = cfg.feedback
    if fb.deflection_damping_Nms_rad or (fb.inertia_comp_kg_m2 and fb.acceleration_source.name == "MOTOR"):
        print(f"motor velocity: {fb.motor_velocity.name.lower()}" + (
            f" (from the position, {st.encoder_counts_per_rev} counts/rev, and the torques: error dynamics at "
            f"{fb.motor_velocity_observer_hz:g} Hz, its bias state at {fb.motor_velocity_bias_hz:g} Hz, model inertia "
            f"{fb.motor_velocity_inertia_factor:g} x J_m)" if fb.motor_velocity.name == "OBSERVER" else
            " (the drive's velocity object as reported)"))
    if fb.deflection_damping_Nms_rad or fb.rest_gate_cutoff_hz:
        print(f"deflection-rate damping {fb.deflection_damping_Nms_rad:g} Nm s/rad (link velocity low-pass "
              f"{fb.deflection_link_cutoff_hz:g} Hz, reference rate {fb.deflection_reference_cutoff_hz:g} Hz); "
              + (f"kp and damping only in motion, faded at {fb.rest_gate_cutoff_hz:g} Hz" if fb.rest_gate_cutoff_hz
                 else "kp and damping always on"))
    if fb.band_gain:
        print(f"band gain {fb.band_gain:g} on the error over {fb.band_low_hz:g}-{fb.band_high_hz:g} Hz "
              f"(4th-order band-pass, faded like kp)")
    if fb.output_torque_gain:
        print(f"output torque gain {fb.output_torque_gain:g} on the output load cells' error, low-pass "
              f"{fb.output_torque_cutoff_hz:g} Hz (faded like kp; in the loop at the slip points)")
        if fb.output_torque_peak_gain:
            print(f"  x (1 + {fb.output_torque_peak_gain:g} BP): a peak at {fb.output_torque_peak_hz:g} Hz, "
                  f"quality {fb.output_torque_peak_q:g}")
    if fb.link_inertia_comp_kg_m2:
        print(f"link inertia compensation {fb.link_inertia_comp_kg_m2:g} kg m^2 x the link's acceleration on the output "
              f"torque asked for, band-passed {fb.link_inertia_highpass_hz:g}-{fb.link_inertia_cutoff_hz:g} Hz "
              f"(in the loop at the slip points)")
    print(f"plant range: K_c {st.stiffness_range_Nm_rad} Nm/rad (sheath stick x{st.stick_stiffness_factor:g}), "
          f"J_m {cfg.plant.motor_inertia_kg_m2:g} +-{st.inertia_tolerance:.0%}; slip: link stiffness {k_slip:.3g} Nm/rad "
          f"(m g l {st.link_stiffness_Nm_rad:g} less the gravity model, residual >= {st.gravity_model_error:.0%})")
    print(f"{'mode':<21}{'K_c':>7}{'J_m':>6}{'stable':>7}{'GM dB':>8}{'@Hz':>7}{'PM deg':>8}{'@Hz':>7}"
          f"{'|S| dB':>8}{'res Hz':>8}{'lc->cmd':>9}{'gyro->cmd':>10}{'enc->cmd':>9}")
    for i, p in enumerate(rep.points):
        mode = MODES[min(i // 9, len(MODES) - 1)]
        print(f"{mode:<21}{p.stiffness_Nm_rad:>7.0f}{p.motor_inertia_kg_m2:>6.2f}{'yes' if p.stable else 'NO':>7}"
              f"{p.gain_margin_dB:>8.1f}{p.gain_margin_at_hz:>7.1f}{p.phase_margin_deg:>8.1f}{p.phase_margin_at_hz:>7.1f}"
              f"{p.sensitivity_peak_dB:>8.1f}{p.resonance_hz:>8.1f}{p.loadcell_to_cmd_std_Nm:>9.4f}"
              f"{p.gyro_to_cmd_std_Nm:>10.4f}{p.encoder_to_cmd_std_Nm:>9.4f}")
    for g, pm, gm, ok in rep.faded:
        print(f"faded to x{g:g} (kp {g * fb.kp:g}, damping {g * fb.deflection_damping_Nms_rad:g}): worst PM {pm:.1f} deg, "
              f"GM {gm:.1f} dB{'' if ok else ' FAILS'}")
    if rep.grip:
        w = min(rep.grip, key=lambda p: p.phase_margin_deg if p.stable else -math.inf)
        print(f"a hand holding the link ({', '.join(f'{k:g}' for k in st.grip_stiffness_Nm_rad)} Nm/rad, "
              f"{st.grip_damping_Nms_rad:g} Nm s/rad; slip, K_c and J_m corners): worst PM "
              + (f"{w.phase_margin_deg:.1f} deg at {w.phase_margin_at_hz:.1f} Hz" if w.stable else "UNSTABLE")
              + f" (grip {w.grip_stiffness_Nm_rad:g} Nm/rad; need >= {rep.min_grip_phase_margin_deg:g})")
    print(("OK: " if rep.ok else "FAILS: ") + rep.summary())
    if args.log:
        lc = out["log_check"]
        print(f"log {lc['log']}: {lc['cycles']} cycles, command -> motor torque lag {lc['measured_lag_cycles']} cycles "
              f"(config io_delay_cycles {lc['config_io_delay_cycles']}); command std {lc['command_std_Nm']:.4f} Nm, "
              f"change {lc['command_change_rms_Nm']:.4f} Nm/cycle rms, peak {lc['command_peak_hz']:.1f} Hz, "
              f"{100 * lc['command_share_above_20hz']:.1f} % of its power above 20 Hz; predicted resonance of the "
              f"logged config in sheath stick {lc['predicted_resonance_hz']} Hz "
              f"({'stable' if lc['predicted_stable'] else 'UNSTABLE: a limit cycle bounded by the clamps'})")
    return 0 if rep.ok else 1
