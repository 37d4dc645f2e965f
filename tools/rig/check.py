"""The check's verdict on one :class:`capstan.tools.rig.profiles.CheckMove`: do the motor
encoder, the load cells and the IMU agree with the command on directions, channel order
and axis?

The two holds (after a positive and after a negative move) are compared: ``D x`` is a
signal's mean over the last part of the positive hold minus that of the negative hold.
What a healthy rig shows, for a positive command difference:

* the drive's encoder moves positive (the drive's own sense);
* the upper cable tightens and the lower one slackens: ``D T_up_in, D T_up_out > 0``,
  ``D T_lo_out, D T_lo_in < 0``; on each cable the input-side change is the larger (the
  sheath's friction takes torque from input to output on the way, either way);
* the IMU's joint angle moves positive, by about ``D q_m r_in / r_out`` (less the cables'
  stretch), and its rate integrates to its angle.

Each departure is named (:class:`Finding`); which device is wrong follows from which
sensors disagree with the others (e.g. IMU and load cells against the command while the
encoder follows it: the motor turns the joint the wrong way).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from capstan.tools.rig.step_run import StepData

#: reported channel names, in the amplifier's order
CHANNELS = ("T_up_in_N", "T_up_out_N", "T_lo_out_N", "T_lo_in_N")
#: what each channel should do for a positive move: +1 tighten, -1 slacken; input side?
EXPECTED = ((+1, True), (+1, False), (-1, False), (-1, True))
#: smallest tension change a connected channel shows over the check move [N]
MIN_TENSION_CHANGE_N = 3.0
#: the IMU must see at least this fraction of the joint motion the motor implies [-]
MIN_IMU_SHARE = 0.3


@dataclass(frozen=True)
class Finding:
    """One mismatch: ``key`` names the device/setting, ``text`` says what was seen;
    ``fix`` is the config change that corrects it (device section -> keys), if any."""

    key: str
    text: str
    fix: dict[str, dict[str, Any]] = field(default_factory=dict)


@dataclass
class CheckResult:
    """The check's measurements (``evidence``) and its findings."""

    findings: list[Finding]
    evidence: dict[str, Any]

    @property
    def ok(self) -> bool:
        return not self.findings


def window_means(data: StepData, windows: list[tuple[str, float, float]]) -> dict[str, dict[str, float]]:
    """Mean of every numeric field over each labelled window."""
    t = data.t_s
    out: dict[str, dict[str, float]] = {}
    for label, a, b in windows:
        m = (t >= a) & (t < b)
        if not m.any():
            continue
        out[label] = {name: float(np.mean(data.records[name][m].astype(float)))
                      for name in data.records.dtype.names}
    return out


def analyse_check(data: StepData, windows: list[tuple[str, float, float]], r_in_m: float,
                  r_out_m: float, imu_sign: float = 1.0) -> CheckResult:
    """Name every direction, order or axis mismatch the move shows.

    :param imu_sign: the IMU sign the run was made with (the fix flips it).
    """
    w = window_means(data, windows)
    missing = {"rest", "hold_pos", "hold_neg"} - set(w)
    if missing:
        return CheckResult([Finding("check", f"the move has no {', '.join(sorted(missing))} window")], {})
    P, N = w["hold_pos"], w["hold_neg"]

    def D(name: str) -> float:
        return P[name] - N[name]

    d_cmd = D("tau_m_raw_Nm")
    s = 1.0 if d_cmd > 0 else -1.0
    ev: dict[str, Any] = {"d_tau_cmd_Nm": d_cmd, "d_tau_drive_Nm": D("tau_m_meas_Nm"), "d_q_m_rad": D("q_m_rad"),
                          "d_q_out_rad": D("q_out_rad"), "d_T_N": [D(c) for c in CHANNELS]}
    findings: list[Finding] = []
    # -- the drive's own sense: encoder and reported torque against its command
    enc = s * D("q_m_rad")
    if s * D("tau_m_meas_Nm") < 0:
        findings.append(Finding("motor.torque_sign", f"the drive reports its torque against its command "
                                                     f"({D('tau_m_meas_Nm'):+.2f} Nm for {d_cmd:+.2f} Nm)"))
    if enc < 0:
        findings.append(Finding("motor.encoder_direction",
                                f"the motor encoder moved {D('q_m_rad'):+.3f} rad for a {d_cmd:+.2f} Nm command "
                                f"difference: the drive's position sense runs against its torque"))
    # -- load cells: which channels tighten, which slacken, input side larger
    dT = np.array(ev["d_T_N"]) * s
    dead = [CHANNELS[k] for k in range(4) if abs(dT[k]) < MIN_TENSION_CHANGE_N]
    cable_sign = 0
    if dead:
        findings.append(Finding("load_cells.channels", f"channel(s) {', '.join(dead)} changed by less than "
                                                       f"{MIN_TENSION_CHANGE_N} N over the move: not connected?"))
    else:
        pos = [k for k in range(4) if dT[k] > 0]
        if len(pos) != 2:
            findings.append(Finding("load_cells.channel_order",
                                    f"{', '.join(CHANNELS[k] for k in pos) or 'no channel'} tightened and the "
                                    f"others slackened: two channels of each cable expected"))
        else:
            inferred = infer_order(dT)
            if set(pos) == {0, 1}:
                cable_sign = 1
            elif set(pos) == {2, 3}:
                cable_sign = -1
            if cable_sign == 0:
                findings.append(Finding("load_cells.channel_order",
                                        f"channels {CHANNELS[pos[0]]} and {CHANNELS[pos[1]]} moved together: they "
                                        f"are wired to the same cable (inferred order {inferred})"))
            ev["load_cell_order_inferred"] = inferred
            wrong_side = [CHANNELS[k] for k in range(4) if inferred[k] is not None
                          and EXPECTED[inferred[k]][1] != EXPECTED[k][1]]
            if cable_sign != 0 and wrong_side:
                findings.append(Finding("load_cells.channel_order",
                                        f"input- and output-side channels swapped: {', '.join(wrong_side)} "
                                        f"(the input side changes more than the output side; inferred "
                                        f"order {inferred})"))
    # -- IMU: sees the joint move, about the right amount, with the right sign
    d_q_out = s * D("q_out_rad")
    implied = abs(D("q_m_rad")) * r_in_m / r_out_m
    ev["imu_share"] = abs(d_q_out) / implied if implied > 0 else float("nan")
    imu_dir = 0
    if not abs(d_q_out) >= MIN_IMU_SHARE * implied:
        findings.append(Finding("imu.joint_axis",
                                f"the IMU saw {D('q_out_rad'):+.3f} rad while the motor implies {implied:.3f} rad "
                                f"of joint motion: the joint does not turn about the configured sensor axis"))
    else:
        imu_dir = 1 if d_q_out > 0 else -1
    # -- who disagrees: encoder (drive sense), cables, IMU
    enc_dir = 1 if enc > 0 else -1
    if enc_dir > 0 and cable_sign != 0 and imu_dir != 0:
        if cable_sign < 0 and imu_dir < 0:
            findings.append(Finding("motor.direction",
                                    "a positive command moved the link negative (the lower cable tightened and the "
                                    "IMU turned negative while the encoder followed the command): the motor's "
                                    "positive sense runs against the joint (or both the IMU sign and the "
                                    "load-cell cables are swapped)"))
        elif imu_dir < 0:
            findings.append(Finding("imu.sign", "the IMU turned negative while the encoder and the cables moved "
                                                "positive: the IMU sign is flipped",
                                    {"imu": {"sign": -imu_sign}}))
        elif cable_sign < 0:
            findings.append(Finding("load_cells.channel_order",
                                    "the lower cable's channels tightened on a positive move while encoder and "
                                    "IMU agree with the command: upper and lower load-cell channels are swapped"))
    return CheckResult(findings, ev)


def infer_order(dT: np.ndarray) -> list[int | None]:
    """For each reported channel, the true channel it behaves like (index into
    :data:`CHANNELS`), from the sign of its change and the in/out magnitude order within
    its cable; None where two channels share a sign pattern that cannot be split."""
    out: list[int | None] = [None] * 4
    pos = [k for k in range(4) if dT[k] > 0]
    neg = [k for k in range(4) if dT[k] <= 0]
    for group, (inside, outside) in ((pos, (0, 1)), (neg, (3, 2))):
        if len(group) != 2:
            continue
        a, b = sorted(group, key=lambda k: -abs(dT[k]))
        out[a], out[b] = inside, outside
    return out
