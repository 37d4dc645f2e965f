"""Calibration from the check move: the load cells' zero and scale, the gyro bias.

* **scale** — against the drive's own torque (0x6077 in units of its rated torque 0x6076):
  wherever the motor stands still (stick phases of the ramps, the holds) its equation of
  motion leaves ``tau_m = tau_in = r_in (T_up_in - T_lo_in)``, so a line through those
  samples gives the input pair's gain (1 = right) to a few tenths of a percent, and each
  input channel's own gain within the cables' small asymmetry. The output pair cannot be
  tied to the drive through the sheath's friction; its two channels are checked against each
  other (each output channel's change against its cable's input channel) for gross errors only
  (:data:`OUTPUT_PAIR_BOUNDS`).
* **zero** — at rest before the first move (no torque, link hanging) all four channels carry
  the pretension: each channel's offset is set so that it reads the four channels' mean
  (the pretension's common level stays as measured; the cells cannot be unloaded).
* **gyro bias** — the joint rate's mean at rest.

Raises nothing: returns :class:`CalibrationResult` whose findings name what is off.
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np
from scipy.signal import savgol_filter

from capstan.tools.rig.check import CHANNELS, Finding, window_means
from capstan.tools.rig.start_config import RigStart
from capstan.tools.rig.step_run import StepData

#: logged bridge signals, in the order of :data:`CHANNELS`
RAW = ("lc_up_in_mV_V", "lc_up_out_mV_V", "lc_lo_out_mV_V", "lc_lo_in_mV_V")
#: the driver's sensitivity when a config sets none [N per mV/V]
DEFAULT_SCALE = 250.0
#: a motor sample is "still" below these (Savitzky-Golay over 101 ms) [rad/s, rad/s^2]
STILL_RATE_RAD_S = 0.02
STILL_ACCEL_RAD_S2 = 0.5
#: an input channel's own gain may differ from its pair's by the cables' asymmetry (~4 %
#: on the reference rig) plus this [-]
INPUT_CHANNEL_TOLERANCE = 0.10
#: the output channels' ratio (each against its cable's input channel) spreads with the plant
#: (0.83 on the reference rig, 0.61 on tests/plants/variant_b.yaml: the sheath's friction
#: decides how much of each cable's change reaches its output side), so only a ratio outside
#: these bounds is named: a grossly wrong sensitivity, not a few percent [-]
OUTPUT_PAIR_BOUNDS = (0.45, 2.2)


@dataclass
class CalibrationResult:
    """:ivar findings: scales beyond tolerance (with the corrected keys as ``fix``).
    :ivar load_cells: the calibrated ``load_cells`` keys (``scale_N_per_mV_V``, ``offset_N``).
    :ivar evidence: what was measured, with the date."""

    findings: list[Finding]
    load_cells: dict[str, Any]
    evidence: dict[str, Any] = field(default_factory=dict)


def still_mask(data: StepData, rate: float = STILL_RATE_RAD_S, accel: float = STILL_ACCEL_RAD_S2) -> np.ndarray:
    """Cycles where the motor stands still (edges of the run excluded)."""
    q = data.col("q_m_rad")
    if len(q) < 400:
        return np.zeros(len(q), dtype=bool)
    dq = savgol_filter(q, 101, 2, deriv=1, delta=1e-3)
    ddq = savgol_filter(q, 101, 2, deriv=2, delta=1e-3)
    m = (np.abs(dq) < rate) & (np.abs(ddq) < accel)
    m[:100] = m[-100:] = False
    return m


def _slope(x: np.ndarray, y: np.ndarray) -> float:
    A = np.c_[x, np.ones_like(x)]
    return float(np.linalg.lstsq(A, y, rcond=None)[0][0])


def calibrate(data: StepData, windows: list[tuple[str, float, float]], start: RigStart,
              scale_tolerance: float | None = None) -> CalibrationResult:
    """Zero, scale and gyro bias from a check move (already checked for order and signs)."""
    tol = start.calibration.scale_tolerance if scale_tolerance is None else scale_tolerance
    lc_cfg: Mapping[str, Any] = start.devices["load_cells"]
    scale_now = np.array(lc_cfg.get("scale_N_per_mV_V") or [DEFAULT_SCALE] * 4, dtype=float)
    r_in = start.drawing.r_in_m
    m = still_mask(data)
    T = {c: data.col(c) for c in CHANNELS}
    tau_m = data.col("tau_m_meas_Nm")
    findings: list[Finding] = []
    ev: dict[str, Any] = {"date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
                          "log": data.log_path, "still_samples": int(m.sum()), "reference": "drive_torque"}
    if m.sum() < 500 or np.ptp(tau_m[m]) < 0.5:
        findings.append(Finding("calibration.scale", f"too few still samples over a torque range "
                                                     f"({int(m.sum())} samples, {np.ptp(tau_m[m]) if m.any() else 0:.2f} Nm)"))
        return CalibrationResult(findings, {}, ev)
    tau_lc = r_in * (T["T_up_in_N"] - T["T_lo_in_N"])
    pair_gain = 1.0 / _slope(tau_lc[m], tau_m[m])          # measured / true
    g_up_in = 2 * r_in / _slope(T["T_up_in_N"][m], tau_m[m])
    g_lo_in = -2 * r_in / _slope(T["T_lo_in_N"][m], tau_m[m])
    gain = np.ones(4)
    gain[0] = gain[3] = pair_gain
    ev["input_pair_gain"] = pair_gain
    ev["input_channel_gain"] = [g_up_in, g_lo_in]
    # one input channel off: the pair's gain is about the mean of the two channels' gains,
    # so with the other channel right (gain 1) the wrong one's is 2 p - 1
    dev = [abs(g_up_in / pair_gain - 1.0), abs(g_lo_in / pair_gain - 1.0)]
    if max(dev) > INPUT_CHANNEL_TOLERANCE:
        k, g_k = (0, g_up_in) if dev[0] >= dev[1] else (3, g_lo_in)
        gain[0] = gain[3] = 1.0
        gain[k] = 2.0 * pair_gain - 1.0
        findings.append(Finding("load_cells.scale_N_per_mV_V",
                                f"{CHANNELS[k]} reads {gain[k]:.3f} x its true tension (channel {g_k:.3f} x, pair "
                                f"{pair_gain:.3f} x against the drive's torque): this channel's sensitivity is wrong"))
    if abs(pair_gain - 1.0) > tol and max(dev) <= INPUT_CHANNEL_TOLERANCE:
        findings.append(Finding("load_cells.scale_N_per_mV_V",
                                f"the input load cells read {pair_gain:.3f} x the drive's torque "
                                f"(r_in (T_up_in - T_lo_in) against 0x6077 over {int(m.sum())} still samples): "
                                f"scale off by {100 * (pair_gain - 1):+.1f} %"))
    # output channels: each against its cable's input channel, at the same still samples
    ratio_up = _slope(T["T_up_in_N"][m] / gain[0], T["T_up_out_N"][m])
    ratio_lo = _slope(T["T_lo_in_N"][m] / gain[3], T["T_lo_out_N"][m])
    ev["output_over_input"] = [ratio_up, ratio_lo]
    rel = ratio_up / ratio_lo if ratio_lo != 0 else float("nan")
    ev["output_pair_ratio"] = rel
    if not OUTPUT_PAIR_BOUNDS[0] <= rel <= OUTPUT_PAIR_BOUNDS[1]:
        high = "T_up_out_N" if rel > 1 else "T_lo_out_N"
        findings.append(Finding("load_cells.scale_N_per_mV_V",
                                f"the output channels disagree by {rel:.2f} x (each against its cable's input "
                                f"channel): {high} reads high or the other low — a wrong sensitivity"))
    # zero: every channel reads the four channels' mean at rest (after the scale correction)
    w = window_means(data, windows).get("rest")
    scale_new = scale_now / gain
    out: dict[str, Any] = {"scale_N_per_mV_V": [float(s) for s in scale_new]}
    if w is not None:
        offset_now = np.array(lc_cfg.get("offset_N") or [0.0] * 4, dtype=float)
        raw_rest = np.array([w[r] for r in RAW])
        t_new = scale_new * raw_rest + offset_now / gain
        t_ref = float(np.mean(t_new))
        out["offset_N"] = [float(o) for o in (offset_now / gain + (t_ref - t_new))]
        ev["zero_N"] = [float(x) for x in t_ref - t_new]
        ev["pretension_rest_N"] = t_ref
        ev["gyro_bias_rad_s"] = w["dq_out_rad_s"]
    return CalibrationResult(findings, out, ev)
