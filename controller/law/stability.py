"""Stability margins and noise gains of the torque loop with the real I/O delay, over the
plant's uncertainty (``controller.stability`` section), and the start-up check built on them.

The loop is :mod:`capstan.controller.law.loop_model` (the step's own filters as transfer
functions). For every plant point of the grid — stiffness over
``stiffness_range_Nm_rad``, motor inertia ``J_m (1 +- inertia_tolerance)``, stick and
slip — this module computes

* gain margin [dB] (smallest distance of ``|L|`` from 0 dB at a -180 deg crossing, so
  a loop that only tolerates less gain counts as well) and phase margin [deg];
* the sensitivity peak ``max |1/(1+L)|`` [dB] and its frequency;
* the closed-loop resonance: the peak of ``|C/(1+L)|`` (load-cell noise -> command), and
  the dominant pole (magnitude, frequency): an unstable loop's limit cycle sits there;
* white-noise gains to the command's standard deviation: load cells (tension noise of
  each cell -> tau_in = r_in (T_up - T_lo)) and gyro (through the feedforward's slope
  at rest, :func:`feedforward_noise_slope`, held at the IMU rate — approximated as
  white at 1 kHz);
* closed-loop stability from the poles.

:func:`check_margins` raises :class:`ConfigError` naming ``controller.feedback`` with
the margins the config would have when the worst point misses
``min_phase_margin_deg``/``min_gain_margin_dB``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from capstan.controller.law.config import ControllerConfig, StabilitySettings
from capstan.controller.law.feedback_config import inertia_comp_faded
from capstan.controller.law.loop_model import (PlantPoint, closed_loop_poles, encoder_response, freq_response,
                                               loop_response, motor_velocity_to_command, reference_tf)
from capstan.controller.law.observer.motor_velocity import encoder_noise_rad
from capstan.models.common.errors import ConfigError


@dataclass(frozen=True)
class PointResult:
    """Margins and noise figures of one plant point (SI; dB, deg, Hz)."""

    stiffness_Nm_rad: float
    motor_inertia_kg_m2: float
    slip: bool
    stable: bool
    gain_margin_dB: float
    gain_margin_at_hz: float
    phase_margin_deg: float
    phase_margin_at_hz: float
    sensitivity_peak_dB: float
    sensitivity_peak_hz: float
    resonance_hz: float
    loadcell_to_cmd_std_Nm: float
    gyro_to_cmd_std_Nm: float
    dominant_pole_abs: float = math.nan
    dominant_pole_hz: float = math.nan
    grip_stiffness_Nm_rad: float = 0.0      # > 0: a slip point with a hand of this stiffness holding the link
    encoder_to_cmd_std_Nm: float = 0.0      # the motor encoder's quantisation -> command std (motor velocity observer)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class StabilityReport:
    """All plant points and the worst figures over them.

    :ivar delay_cycles: the I/O delay the analysis used [cycles].
    """

    points: tuple[PointResult, ...]
    delay_cycles: int
    min_phase_margin_deg: float
    min_gain_margin_dB: float
    #: with ``feedback.rest_gate_cutoff_hz`` > 0 the loop fades kp and the deflection damping (and J_c
    #: from the motor's acceleration) in and out together: (factor, worst phase margin [deg], worst gain margin [dB], ok) at the faded gains
    faded: tuple[tuple[float, float, float, bool], ...] = ()
    #: the slip points with a hand holding the link (``stability.grip_stiffness_Nm_rad``) and what they need
    grip: tuple[PointResult, ...] = ()
    min_grip_phase_margin_deg: float = 0.0

    @property
    def grip_ok(self) -> bool:
        """True if every grip point is stable with at least ``min_grip_phase_margin_deg``."""
        return all(p.stable and p.phase_margin_deg >= self.min_grip_phase_margin_deg for p in self.grip)

    @property
    def worst_phase_margin_deg(self) -> float:
        return min(p.phase_margin_deg if p.stable else -math.inf for p in self.points)

    @property
    def worst_gain_margin_dB(self) -> float:
        return min(p.gain_margin_dB if p.stable else -math.inf for p in self.points)

    @property
    def all_stable(self) -> bool:
        return all(p.stable for p in self.points)

    @property
    def ok(self) -> bool:
        """True if every point is stable and meets both required margins."""
        return (self.all_stable and self.worst_phase_margin_deg >= self.min_phase_margin_deg
                and self.worst_gain_margin_dB >= self.min_gain_margin_dB and all(f[3] for f in self.faded)
                and self.grip_ok)

    def nominal(self) -> PointResult:
        """The stick point in the middle of the grid (nominal stiffness and inertia)."""
        return self.points[4]

    def to_dict(self) -> dict[str, Any]:
        return {"delay_cycles": self.delay_cycles, "ok": self.ok, "all_stable": self.all_stable,
                "worst_phase_margin_deg": self.worst_phase_margin_deg,
                "worst_gain_margin_dB": self.worst_gain_margin_dB,
                "required": {"phase_margin_deg": self.min_phase_margin_deg,
                             "gain_margin_dB": self.min_gain_margin_dB},
                "worst_sensitivity_peak_dB": max(p.sensitivity_peak_dB for p in self.points),
                "worst_loadcell_to_cmd_std_Nm": max(p.loadcell_to_cmd_std_Nm for p in self.points),
                "worst_gyro_to_cmd_std_Nm": max(p.gyro_to_cmd_std_Nm for p in self.points),
                "worst_encoder_to_cmd_std_Nm": max(p.encoder_to_cmd_std_Nm for p in self.points),
                "faded": [{"factor": f[0], "worst_phase_margin_deg": f[1], "worst_gain_margin_dB": f[2], "ok": f[3]}
                          for f in self.faded],
                "points": [p.to_dict() for p in self.points],
                "grip": {"ok": self.grip_ok, "required_phase_margin_deg": self.min_grip_phase_margin_deg,
                         "points": [p.to_dict() for p in self.grip]}}

    def summary(self) -> str:
        """One line: worst margins against the requirement."""
        text = (f"phase margin {self.worst_phase_margin_deg:.1f} deg (need >= {self.min_phase_margin_deg:g}), "
                f"gain margin {self.worst_gain_margin_dB:.1f} dB (need >= {self.min_gain_margin_dB:g})")
        bad = [(i, p) for i, p in enumerate(self.points) if not p.stable]
        if bad:
            i, p = max(bad, key=lambda ip: ip[1].dominant_pole_abs)
            mode = MODES[min(i // 9, len(MODES) - 1)]
            text += (f", closed loop UNSTABLE at {len(bad)} of {len(self.points)} plant points (worst: {mode}, "
                     f"K {p.stiffness_Nm_rad:.0f} Nm/rad, J_m {p.motor_inertia_kg_m2:.2f} kg m^2: a mode at "
                     f"{p.dominant_pole_hz:.1f} Hz growing x{p.dominant_pole_abs:.4f} per cycle)")
        for g, pm, gm, ok in self.faded:
            if not ok:
                text += (f"; with kp and the deflection damping faded to x{g:g} (rest gate): phase margin "
                         f"{pm:.1f} deg, gain margin {gm:.1f} dB")
        bad_grip = [p for p in self.grip if not (p.stable and p.phase_margin_deg >= self.min_grip_phase_margin_deg)]
        if bad_grip:
            p = min(bad_grip, key=lambda q: q.phase_margin_deg if q.stable else -math.inf)
            text += (f"; with a hand holding the link (slip, grip {p.grip_stiffness_Nm_rad:.0f} Nm/rad, K_c {p.stiffness_Nm_rad:.0f}, J_m "
                     f"{p.motor_inertia_kg_m2:.2f}): "
                     + (f"phase margin {p.phase_margin_deg:.1f} deg (need >= {self.min_grip_phase_margin_deg:g})"
                        if p.stable else f"UNSTABLE, a mode at {p.dominant_pole_hz:.1f} Hz"))
        return text + f", I/O delay {self.delay_cycles} cycles"


def feedforward_noise_slope(cfg: ControllerConfig, sigma_rad_s: float, t0_N: float = 150.0,
                            n: int = 4000) -> float:
    """Equivalent gain [Nm/(rad/s)] from white gyro noise of std ``sigma_rad_s`` at rest to
    the friction feedforward (std of the feedforward over std of the noise; 0 when off).

    Evaluated on the compiled feedforward function with a fixed seed, so thresholds,
    hysteresis or dead bands in it count as they run.
    """
    ff = cfg.feedforward
    if not ff.enabled or sigma_rad_s <= 0.0:
        return 0.0
    from capstan.controller.law.feedforward import friction_torque_per_N, rest_feedforward_series_Nm
    noise = np.random.default_rng(1).normal(0.0, sigma_rad_s, n)
    tau = rest_feedforward_series_Nm(noise, friction_torque_per_N(ff, cfg.plant.r_out_m) * t0_N, ff)
    return float(np.std(tau) / sigma_rad_s) * ff.gain


def _crossings(x: np.ndarray) -> np.ndarray:
    """Indices i where x changes sign between i and i+1."""
    return np.nonzero(np.signbit(x[:-1]) != np.signbit(x[1:]))[0]


def analyse_point(cfg: ControllerConfig, st: StabilitySettings, p: PlantPoint,
                  gyro_slope: float) -> PointResult:
    """Margins and noise gains of the loop on one plant point."""
    dt = cfg.dt_s
    poles = closed_loop_poles(cfg, p, st.io_delay_cycles)
    stable = bool(np.all(np.abs(poles) < 1.0 - 1e-9))
    i_dom = int(np.argmax(np.abs(poles)))      # the slowest-decaying (or fastest-growing) mode
    dom_abs, dom_hz = float(abs(poles[i_dom])), float(abs(np.angle(poles[i_dom])) / (2.0 * math.pi * dt))
    f = np.geomspace(0.05, 0.5 / dt * 0.9999, 12000)
    C, L = loop_response(cfg, p, st.io_delay_cycles, f)
    with np.errstate(divide="ignore"):     # L = 0 (no feedback at all): -inf dB, no crossing
        mag_db = 20.0 * np.log10(np.abs(L))
    ph = np.unwrap(np.angle(L))
    pm, f_pm = math.inf, math.nan
    for i in _crossings(mag_db):
        w = mag_db[i] / (mag_db[i] - mag_db[i + 1])
        phase = ph[i] + w * (ph[i + 1] - ph[i])
        m = 180.0 - abs((math.degrees(phase) + 180.0) % 360.0 - 180.0)   # angular distance from -180 deg
        if m < pm:
            pm, f_pm = m, f[i] + w * (f[i + 1] - f[i])
    gm, f_gm = math.inf, math.nan
    s = np.sin(ph)     # -180 deg (mod 360) crossings: imaginary part changes sign with Re < 0
    for i in _crossings(s):
        if np.real(L[i]) < 0.0:
            w = s[i] / (s[i] - s[i + 1])
            m = -(mag_db[i] + w * (mag_db[i + 1] - mag_db[i]))
            if abs(m) < abs(gm):
                gm, f_gm = m, f[i] + w * (f[i + 1] - f[i])
    S = 1.0 / (1.0 + L)
    iS = int(np.argmax(np.abs(S)))
    N = np.abs(C * S)
    iN = int(np.argmax(np.where(f > 1.0, N, 0.0)))
    # white-noise gains: uniform grid over the Nyquist band (variance = mean |H|^2)
    fu = np.linspace(0.0, 0.5 / dt, 4001)[1:]
    Cu, Lu = loop_response(cfg, p, st.io_delay_cycles, fu)
    Su = 1.0 / (1.0 + Lu)
    lc_gain = float(np.sqrt(np.mean(np.abs(Cu * Su) ** 2)))
    ref_gain = float(np.sqrt(np.mean(np.abs(freq_response(reference_tf(cfg), fu, dt) * Su) ** 2)))
    sigma_tau_in = cfg.plant.r_in_m * math.sqrt(2.0) * st.tension_noise_N
    enc_gain = float(np.sqrt(np.mean(np.abs(encoder_response(cfg, fu) * motor_velocity_to_command(cfg, fu) * Su) ** 2)))
    return PointResult(
        p.stiffness_Nm_rad, p.motor_inertia_kg_m2, p.slip, stable,
        float(gm), float(f_gm), float(pm), float(f_pm),
        float(20.0 * math.log10(abs(S[iS]))), float(f[iS]), float(f[iN]),
        lc_gain * sigma_tau_in, ref_gain * gyro_slope * st.gyro_noise_rad_s, dom_abs, dom_hz,
        encoder_to_cmd_std_Nm=enc_gain * encoder_noise_rad(st.encoder_counts_per_rev))


#: the plant modes of the grid, in the order of :func:`plant_points` (9 points each)
MODES = ("stick", "partial sheath stick", "sheath stick", "slip")


def plant_points(cfg: ControllerConfig, st: StabilitySettings) -> list[PlantPoint]:
    """The uncertainty grid: 3 stiffnesses x 3 inertias x {stick held at the output, stick
    in the sheath at x sqrt(f) and x f the stiffness (f = ``stick_stiffness_factor``), slip}.

    In sheath stick the input's stiffness depends on the amplitude: the distributed model
    of the HIL rig gives 10.7 K_c at 0.02-0.1 Nm, 6.3 K_c at 0.3 Nm, 2.1 K_c at 1 Nm
    (tests/test_torque_loop.py), hence the three stick levels."""
    k_lo, k_hi = st.stiffness_range_Nm_rad
    jm = cfg.plant.motor_inertia_kg_m2
    f = st.stick_stiffness_factor
    k_link = slip_link_stiffness_Nm_rad(cfg, st)
    out = []
    for mode, factor in zip(MODES, (1.0, math.sqrt(f), f, 1.0)):
        for k in (k_lo, 0.5 * (k_lo + k_hi), k_hi):
            for j in (jm * (1.0 - st.inertia_tolerance), jm, jm * (1.0 + st.inertia_tolerance)):
                out.append(PlantPoint(k * factor, j, cfg.plant.motor_damping_Nms_rad, mode == "slip",
                                      st.link_inertia_kg_m2, st.link_damping_Nms_rad, k_link))
    return out


def slip_link_stiffness_Nm_rad(cfg: ControllerConfig, st: StabilitySettings) -> float:
    """The link's stiffness the loop sees in slip [Nm/rad]: its gravity stiffness
    ``link_stiffness_Nm_rad`` (m g l, hanging) less what the gravity model cancels.

    The step adds ``m_g_l sin(q_out)`` to the reference: linearised, a positive feedback of the
    link angle that cancels the link's gravity stiffness, with ~3.5 ms of lag (IMU hold, I/O
    delay) that only adds ``m_g_l x 3.5 ms`` of damping. The slip points therefore keep the
    residual: ``max(k_link - m_g_l, gravity_model_error x k_link)`` with the gravity model on
    (the configured m g l may be off by ``gravity_model_error``; a model that over-compensates
    makes the hanging link drift, a static matter no loop gain changes), ``k_link`` with it off.
    tests/test_torque_loop.py checks this against the compiled step with its gravity path closed
    on the full link stiffness."""
    k_link = st.link_stiffness_Nm_rad
    if not cfg.gravity_enabled:
        return k_link
    return max(k_link - cfg.m_g_l_Nm, st.gravity_model_error * k_link)


def analyse(cfg: ControllerConfig, grip: bool = True) -> StabilityReport:
    """The loop's margins and noise gains over the configured plant range, and (``grip``) at the grip points
    (:func:`grip_points`). The faded gains are checked with the grip at x0.5, not at x0: at rest the rest gate
    also switches J_c off, and J_c on with kp and b still faded lasts only while the fade opens (~30 ms).

    :raises ConfigError: if the loop's filters cannot be built from the config.
    """
    st = cfg.stability
    try:
        slope = feedforward_noise_slope(cfg, st.gyro_noise_rad_s)
        pts = tuple(analyse_point(cfg, st, p, slope) for p in plant_points(cfg, st))
    except ValueError as exc:
        raise ConfigError("controller", f"the torque loop cannot be analysed: {exc}") from exc
    fb = cfg.feedback
    faded = []
    if fb.rest_gate_cutoff_hz > 0.0 and (fb.kp != 0.0 or fb.deflection_damping_Nms_rad != 0.0 or fb.band_gain != 0.0
                                        or fb.output_torque_gain != 0.0 or fb.link_inertia_comp_kg_m2 != 0.0
                                        or (inertia_comp_faded(fb) and fb.inertia_comp_kg_m2 != 0.0)):
        for g in FADE_FACTORS:      # the gate's low-pass moves kp, b (and a motor-source J_c) together
            sub = analyse(replace(cfg, feedback=replace(
                fb, kp=g * fb.kp, rest_gate_cutoff_hz=0.0, deflection_damping_Nms_rad=g * fb.deflection_damping_Nms_rad,
                band_gain=g * fb.band_gain, output_torque_gain=g * fb.output_torque_gain,
                link_inertia_comp_kg_m2=g * fb.link_inertia_comp_kg_m2,
                inertia_comp_kg_m2=(g if inertia_comp_faded(fb) else 1.0) * fb.inertia_comp_kg_m2)), grip=grip and g > 0.0)
            faded.append((g, sub.worst_phase_margin_deg, sub.worst_gain_margin_dB, sub.ok))
    return StabilityReport(pts, st.io_delay_cycles, st.min_phase_margin_deg, st.min_gain_margin_dB, tuple(faded),
                           grip_points(cfg, slope) if grip else (), st.min_grip_phase_margin_deg)


def grip_points(cfg: ControllerConfig, gyro_slope: float) -> tuple[PointResult, ...]:
    """The slip points with a hand holding the link: ``stability.grip_stiffness_Nm_rad`` x the K_c range's
    ends x J_m +- the tolerance, the grip's stiffness and ``grip_damping_Nms_rad`` added to the link's.

    :raises ValueError: if the loop's filters cannot be built (as :func:`analyse_point`)."""
    st = cfg.stability
    k_lo, k_hi = st.stiffness_range_Nm_rad
    jm = cfg.plant.motor_inertia_kg_m2
    k_link = slip_link_stiffness_Nm_rad(cfg, st)
    out = []
    for k_h in st.grip_stiffness_Nm_rad:
        for k in (k_lo, k_hi):
            for j in (jm * (1.0 - st.inertia_tolerance), jm * (1.0 + st.inertia_tolerance)):
                p = PlantPoint(k, j, cfg.plant.motor_damping_Nms_rad, True, st.link_inertia_kg_m2,
                               st.link_damping_Nms_rad + st.grip_damping_Nms_rad, k_link + k_h)
                out.append(replace(analyse_point(cfg, st, p, gyro_slope), grip_stiffness_Nm_rad=k_h))
    return tuple(out)


#: the factors on kp and the deflection damping the fading rest gate is checked at besides 1 (0: at rest)
FADE_FACTORS = (0.5, 0.0)


def check_margins(cfg: ControllerConfig, override: bool = False) -> StabilityReport:
    """Refuse gains outside the required margins (unless ``override``).

    :returns: the report (also when overridden, so the caller can log the margins).
    :raises ConfigError: naming ``controller.feedback`` with the margins the config would have.
    """
    rep = analyse(cfg)
    if not rep.ok and not override:
        raise ConfigError("controller.feedback",
                          f"the torque loop is not robust with the I/O delay: {rep.summary()} over "
                          f"K_c {cfg.stability.stiffness_range_Nm_rad} Nm/rad, J_m +-"
                          f"{cfg.stability.inertia_tolerance:.0%}, stick and slip "
                          f"(`capstan experiment loop` shows each point; `lab_override` starts it anyway)")
    return rep
