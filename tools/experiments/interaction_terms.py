"""What each term of the shipped torque loop does to the interaction torque: the interaction
experiment (:mod:`capstan.tools.experiments.interaction`) with one term switched off or one
loop property changed at a time (``capstan experiment interaction --terms``).

Every variant runs the shipped controller (config defaults, friction feedforward at the
reference) on the same condition, seed and duration, so the differences are the term's
share of mean |tau_h|. Each variant's loop is also checked with the loop analysis
(:func:`capstan.controller.law.stability.analyse`): a variant that misses the margins is
not a loop the daemon would start, whatever its mean |tau_h|.

Variants (:data:`TERM_VARIANTS`):

* ``shipped`` — feedforward + kp and the band gain with the deflection-rate damping (faded in with
  motion) + integral trim + inertia compensation, 2-cycle delay, IMU 400 Hz;
* ``no_band_gain`` — the band gain on the error off (the loop before it);
* ``no_deflection_damping`` (kp kept) / ``no_torque_feedback`` (kp 0, no damping, J_c 0.3: the
  loop before the damping) / ``kp_always_on`` (no fade at rest);
* ``no_feedforward`` / ``no_inertia_comp`` / ``no_integral_trim`` — that term off;
* ``motor_velocity_drive`` — the damping and J_c read the drive's velocity object as reported instead of the
  motor velocity observer (on realistic devices: b x its 1 ms count difference in whole rpm);
* ``no_link_inertia_comp`` — the link inertia compensation off; ``before_link_inertia_comp`` — the set
  shipped before it (b 80, J_c's acceleration at 5 Hz, k_o 2 with its peak at 1.5 Hz);
* ``no_output_peak`` — the output torque gain's peak off; ``inertia_comp_link`` — J_c 0.2 from the
  link's acceleration (b 60, link rate 30 Hz, lead), the set shipped before the peak;
* ``inertia_comp_motor`` — the inertia compensation from the motor's acceleration (J_c 0.45, faded
  with kp and b; b 80, link rate at 80 Hz without the lead): the largest inertia compensation inside
  the margins, reachable by config (:data:`MOTOR_INERTIA_COMP`);
* ``narrow_rest_gate`` — the feedforward's rest band at its smallest accepted value (2 x the
  gyro noise), i.e. the gate's onset delay almost removed;
* ``no_delay`` — the command acts in the cycle it is computed (the lock-step idealisation);
* ``imu_1khz`` — the IMU (gate, feedforward and differentiated acceleration) at 1 kHz;
* ``gravity_only`` — no friction feedforward, no inertia compensation: the uncompensated joint
  of the same loop (the like-for-like baseline); ``gravity_only_no_torque_feedback`` the same
  for the loop before;
* ``paper_pid_gravity_only`` — the paper's gravity-only PID with its lock-step gains (kp 5): the
  experiment's historical "uncompensated" row. Its torque loop hides the motor inertia, but it
  misses the margins with the delay (it rings at the sheath-stick mode in HIL).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

from capstan.controller.law.config import ControllerConfig
from capstan.controller.law.stability import analyse
from capstan.models.common.errors import OperatingRangeError
from capstan.tools.experiments.interaction import CONDITIONS, controller_mapping, run_interaction


@dataclass(frozen=True)
class TermVariant:
    """One variant of the shipped loop.

    :ivar loop: ``shipped`` (config defaults) or a paper loop (``pid``/``ldo``, lock-step gains).
    :ivar feedforward: friction feedforward on (at the reference).
    :ivar extra: controller mapping merged over the condition's (sections merged key by key).
    :ivar delay_cycles: command delay [cycles]; None: the experiment's.
    :ivar imu_rate_hz: the rig's IMU rate [Hz].
    """

    name: str
    description: str
    loop: str = "shipped"
    feedforward: bool = True
    extra: dict[str, Any] = field(default_factory=dict)
    delay_cycles: int | None = None
    imu_rate_hz: float = 400.0


_NO_JC = {"feedback": {"inertia_comp_kg_m2": 0.0}}
#: the loop before the deflection-rate damping: no torque feedback (kp 0), no damping, J_c 0.3
_PREV = {"kp": 0.0, "deflection_damping_Nms_rad": 0.0, "rest_gate_cutoff_hz": 0.0, "inertia_comp_kg_m2": 0.3,
         "acceleration_source": "link", "acceleration_cutoff_hz": 5.0,
         "band_gain": 0.0, "output_torque_gain": 0.0, "link_inertia_comp_kg_m2": 0.0}
#: uncompensated: no inertia compensation and no output torque gain (it compensates friction and inertia too)
_UNCOMPENSATED = {"feedback": {"inertia_comp_kg_m2": 0.0, "output_torque_gain": 0.0, "link_inertia_comp_kg_m2": 0.0}}

#: the inertia compensation from the motor's acceleration (faded in with kp and the damping): J_c 0.45
#: with b 80 and the link rate at 80 Hz, no lead (the lead is link-acceleration feedback that shares J_c's
#: margin): PM 51.6 deg, GM 8.5 dB (slip, K 200, J_m -30 %)
MOTOR_INERTIA_COMP = {"inertia_comp_kg_m2": 0.45, "acceleration_source": "motor", "deflection_damping_Nms_rad": 80.0,
                      "deflection_link_cutoff_hz": 80.0, "deflection_link_lag_compensation": False}
#: J_c as shipped before the output torque gain's peak: 0.2 from the link's acceleration, b 60, link rate 30 Hz, lead
LINK_INERTIA_COMP = {"inertia_comp_kg_m2": 0.2, "acceleration_source": "link", "deflection_damping_Nms_rad": 60.0,
                     "deflection_link_cutoff_hz": 30.0, "deflection_link_lag_compensation": True}
#: the set shipped before the link inertia compensation: b 80, J_c's acceleration at 5 Hz, k_o 2 with its peak at
#: 1.5 Hz, J_lc 0 (PM 51.1 deg, GM 13.3 dB, grip PM 31.7 deg)
BEFORE_LINK_INERTIA = {"deflection_damping_Nms_rad": 80.0, "acceleration_cutoff_hz": 5.0, "output_torque_gain": 2.0,
                       "output_torque_peak_hz": 1.5, "link_inertia_comp_kg_m2": 0.0}

TERM_VARIANTS: tuple[TermVariant, ...] = (
    TermVariant("shipped", "feedforward + kp 0.75 + band gain 2.5 (0.3-2 Hz) + deflection damping"
                           " (b 100, link rate 80 Hz) + integral trim + inertia compensation (0.45, motor's, 3 Hz)"
                           " + output torque gain 2.5 (10 Hz, x2 peak at 2 Hz) + link inertia compensation"
                           " (0.04, 0.3-3 Hz); motor velocity from the encoder's position (observer 25 Hz)"),
    TermVariant("motor_velocity_drive", "the damping and J_c on the drive's 0x606C as reported (before the observer)",
                extra={"feedback": {"motor_velocity": "drive"}}),
    TermVariant("no_link_inertia_comp", "link inertia compensation off, the rest shipped",
                extra={"feedback": {"link_inertia_comp_kg_m2": 0.0}}),
    TermVariant("before_link_inertia_comp", "the set before the link inertia compensation (b 80, J_c's 5 Hz, k_o 2,"
                                            " peak at 1.5 Hz)", extra={"feedback": BEFORE_LINK_INERTIA}),
    TermVariant("no_output_torque_gain", "output torque gain off (the loop before it)",
                extra={"feedback": {"output_torque_gain": 0.0}}),
    TermVariant("no_band_gain", "band gain off (the loop before it)", extra={"feedback": {"band_gain": 0.0}}),
    TermVariant("no_deflection_damping", "deflection-rate damping off, kp kept",
                extra={"feedback": {"deflection_damping_Nms_rad": 0.0}}),
    TermVariant("no_torque_feedback", "kp 0 and no deflection damping (the loop before)", extra={"feedback": _PREV}),
    TermVariant("kp_always_on", "kp and damping also at rest (no rest gate; output torque gain off: it needs the gate)",
                extra={"feedback": {"rest_gate_cutoff_hz": 0.0, "output_torque_gain": 0.0}}),
    TermVariant("no_feedforward", "friction feedforward off", feedforward=False),
    TermVariant("no_inertia_comp", "inertia compensation off", extra=_NO_JC),
    TermVariant("inertia_comp_motor", "J_c 0.45 from the motor's acceleration (faded), b 80, link rate 80 Hz",
                extra={"feedback": MOTOR_INERTIA_COMP}),
    TermVariant("no_output_peak", "the output torque gain's peak off", extra={"feedback": {"output_torque_peak_gain": 0.0}}),
    TermVariant("inertia_comp_link", "J_c 0.2 from the link's acceleration, b 60, link rate 30 Hz, lead (the set before)",
                extra={"feedback": LINK_INERTIA_COMP}),
    TermVariant("no_integral_trim", "integral trim off (ki 0)", extra={"feedback": {"ki_1_s": 0.0}}),
    TermVariant("narrow_rest_gate", "rest band 2 x gyro noise (0.004 rad/s)",
                extra={"feedforward": {"dead_band_rad_s": 0.004}}),
    TermVariant("no_delay", "command acts in its own cycle (lock-step)", delay_cycles=0),
    TermVariant("imu_1khz", "IMU at 1 kHz instead of 400 Hz", imu_rate_hz=1000.0),
    TermVariant("gravity_only", "uncompensated: no feedforward, no inertia compensation, no output torque gain",
                feedforward=False, extra=_UNCOMPENSATED),
    TermVariant("gravity_only_no_torque_feedback", "uncompensated, kp 0 and no damping (the loop before)",
                feedforward=False, extra={"feedback": {**_PREV, "inertia_comp_kg_m2": 0.0, "output_torque_gain": 0.0}}),
    TermVariant("paper_pid_gravity_only", "paper's gravity-only PID, lock-step gains (kp 5)",
                loop="pid", feedforward=False),
)


def run_terms(duration_s: float, delay_cycles: int, conditions: tuple[str, ...] = tuple(CONDITIONS),
              seed: int = 0, variants: tuple[TermVariant, ...] = TERM_VARIANTS,
              progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Every variant on every condition.

    :param delay_cycles: the command delay of the variants that do not set their own [cycles].
    :returns: ``{"variants": {name: {description, margins_ok, worst_phase_margin_deg,
        worst_gain_margin_dB}}, "results": {condition: {name: metrics}}}``; the metrics are
        :func:`run_interaction`'s plus ``delta_vs_shipped_Nm`` (mean |tau_h| minus the shipped one).
    :raises ConfigError: if a variant's controller mapping is invalid.
    """
    out: dict[str, Any] = {"delay_cycles": int(delay_cycles), "duration_s": float(duration_s),
                           "variants": {}, "results": {}}
    for v in variants:
        cfg = ControllerConfig.from_mapping(controller_mapping(CONDITIONS[conditions[0]], v.loop, v.feedforward,
                                                               extra=v.extra))
        rep = analyse(cfg)
        out["variants"][v.name] = {"description": v.description, "margins_ok": rep.ok,
                                   "worst_phase_margin_deg": rep.worst_phase_margin_deg,
                                   "worst_gain_margin_dB": rep.worst_gain_margin_dB}
    for cname in conditions:
        cond = CONDITIONS[cname]
        res: dict[str, Any] = {}
        for v in variants:
            d = delay_cycles if v.delay_cycles is None else v.delay_cycles
            try:
                res[v.name] = run_interaction(cond, controller_mapping(cond, v.loop, v.feedforward, extra=v.extra),
                                              duration_s, seed, delay_cycles=d, imu_rate_hz=v.imu_rate_hz)
            except OperatingRangeError as exc:
                res[v.name] = {"mean_abs_tau_h_Nm": math.nan, "error": str(exc), "faulted": 1.0}
            if progress is not None:
                progress(f"{cname} {v.name}: mean |tau_h| = {res[v.name]['mean_abs_tau_h_Nm']:.3f} Nm")
        ref = res[variants[0].name]["mean_abs_tau_h_Nm"]
        for m in res.values():
            m["delta_vs_shipped_Nm"] = m["mean_abs_tau_h_Nm"] - ref
        out["results"][cname] = res
    return out


def format_terms(out: dict[str, Any]) -> str:
    """The breakdown as a text table (mean |tau_h| overall and per phase [Nm], margins)."""
    lines = [f"term breakdown, {out['duration_s']:.1f} s per run, command delay {out['delay_cycles']} cycles "
             f"unless the variant says otherwise; mean |tau_h| [Nm]"]
    for cname, res in out["results"].items():
        lines.append(f"\n{cname}")
        lines.append(f"  {'variant':<24}{'mean':>7}{'delta':>8}{'accel':>7}{'decel':>7}{'rest':>7}  margins")
        for name, m in res.items():
            v = out["variants"][name]
            marg = (f"ok (PM {v['worst_phase_margin_deg']:.0f} deg, GM {v['worst_gain_margin_dB']:.1f} dB)"
                    if v["margins_ok"] else "MISSED")
            if "error" in m:
                lines.append(f"  {name:<24}  stopped: {m['error']}")
                continue
            lines.append(f"  {name:<24}{m['mean_abs_tau_h_Nm']:>7.3f}{m['delta_vs_shipped_Nm']:>+8.3f}"
                         f"{m['mean_abs_tau_h_accel_Nm']:>7.3f}{m['mean_abs_tau_h_decel_Nm']:>7.3f}"
                         f"{m['mean_abs_tau_h_rest_Nm']:>7.3f}  {marg}  {v['description']}")
    return "\n".join(lines)
