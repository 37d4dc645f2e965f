"""The discrete-time torque loop exactly as the 1 kHz step runs it, as transfer functions.

Everything is a polynomial ratio in ``z^-1`` (``(num, den)`` numpy arrays, ascending
powers of ``z^-1``), built from the *same* coefficient functions the step uses
(:mod:`capstan.controller.law.ldo`), so the analysis cannot drift from the code.

Loop, per cycle ``k`` (``F``: tau_in low-pass, ``Dd``: filtered derivative on the
measurement, ``Q``/``QP``: the observer filters, ``u``: the command)::

    u (1 - Q F z^-1) = (1 + kp) ref - F (kp + Dd + QP) tau_in          LDO
    u                = (1 + kp) ref - F (kp + Dd + ki T / (1 - z^-1)) tau_in     PID

so the feedback controller from the measured ``tau_in`` to ``u`` is
``C = F (kp + Dd + QP) / (1 - Q F z^-1)`` (LDO) and the loop gain is
``L = C z^-d Pd``: ``Pd`` the plant from applied motor torque to ``tau_in`` discretised
with a zero-order hold (scipy ``cont2discrete``), ``d`` the extra I/O delay in cycles
(CANopen RPDO/SYNC/drive update and sensor transport beyond the hold).

Plant, linearised (SI, torques at the motor side, ``r_in = r_out``; :mod:`capstan.controller.law.loop_plant`):

* ``stick`` — the transmission friction holds the output: ``P = K/(J s^2 + B s + K)``;
* ``slip``  — friction constant (no incremental effect), the link free:
  ``P = K M_l / (M_m M_l + K (M_m + M_l))`` with ``M_m = J_m s^2 + B_m s`` and
  ``M_l = J_l s^2 + b_l s + k_g`` (link inertia, damping, gravity stiffness).

Margins and peaks are read off the frequency response on a dense grid with the
crossings refined by interpolation; closed-loop stability from the roots of
``den_C den_P + num_C num_P z^-d`` (all inside the unit circle).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from scipy import signal

from capstan.controller.law.config import AccelerationSource, ControllerConfig, TorqueLoop
from capstan.controller.law.feedback_config import deflection_link_lead_s, observer_inertia_kg_m2
from capstan.controller.law.ldo import (band_pass_sos, derivative_filter_coefficients, lowpass_alpha,
                                        output_peak_biquad, q_filter_coefficients, qpinv_filter_coefficients)
from capstan.controller.law.loop_plant import (PlantPoint, plant_continuous, plant_discrete,  # noqa: F401 (re-exported)
                                               plant_link_velocity_continuous, plant_position_continuous,
                                               plant_state_space, plant_velocity_continuous)
from capstan.controller.law.observer.motor_velocity import (HISTORY, MotorVelocitySource, observer_gains, observer_matrices,
                                                   observer_responses)

TF = tuple[np.ndarray, np.ndarray]


def _mul(a: TF, b: TF) -> TF:
    # np.convolve, not np.polymul: polymul strips leading zeros, i.e. the delays z^-k

    return np.convolve(a[0], b[0]), np.convolve(a[1], b[1])


def _padd(a: np.ndarray, b: np.ndarray, sign: float = 1.0) -> np.ndarray:
    """``a + sign b`` for ascending-power coefficient arrays (padded at the end)."""
    n = max(len(a), len(b))
    out = np.zeros(n)
    out[:len(a)] += a
    out[:len(b)] += sign * np.asarray(b)
    return out


def _add(a: TF, b: TF) -> TF:
    return _padd(np.convolve(a[0], b[1]), np.convolve(b[0], a[1])), np.convolve(a[1], b[1])


def tau_in_filter(cfg: ControllerConfig) -> TF:
    """``F(z)`` of the tau_in low-pass ``y = a y + (1 - a) x`` (1 when off)."""
    a = lowpass_alpha(cfg.tau_in_cutoff_hz, cfg.dt_s)
    return np.array([1.0 - a]), np.array([1.0, -a])


def derivative_filter(cfg: ControllerConfig) -> TF:
    """``Dd(z) = b0 (1 - z^-1) / (1 + a1 z^-1)`` of the filtered derivative (on tau_in)."""
    fb = cfg.feedback
    b0, a1 = derivative_filter_coefficients(fb.kd_s, fb.derivative_cutoff_hz, cfg.dt_s)
    return np.array([b0, -b0]), np.array([1.0, a1])


def band_filter(cfg: ControllerConfig) -> TF:
    """``k_b BP(z)``: the band gain on the error (``feedback.band_gain``; 0 when off), the step's two
    biquads (:func:`capstan.controller.law.ldo.band_pass_sos`) multiplied out."""
    fb = cfg.feedback
    if fb.band_gain == 0.0:
        return np.array([0.0]), np.array([1.0])
    sos = band_pass_sos(fb.band_low_hz, fb.band_high_hz, cfg.dt_s)
    out: TF = (np.array([fb.band_gain]), np.array([1.0]))
    for b0, b1, b2, a1, a2 in sos:
        out = _mul(out, (np.array([b0, b1, b2]), np.array([1.0, a1, a2])))
    return out


def controller_tf(cfg: ControllerConfig) -> TF:
    """Feedback path ``C(z)``: measured tau_in -> command u (sign: ``u = -C tau_in + ...``)."""
    F = tau_in_filter(cfg)
    fb = cfg.feedback
    inner = _add((np.array([fb.kp]), np.array([1.0])), derivative_filter(cfg))
    if fb.band_gain != 0.0:
        inner = _add(inner, band_filter(cfg))
    if cfg.torque_loop == TorqueLoop.LDO:
        bp, ap = qpinv_filter_coefficients(cfg.q_cutoff_hz, cfg.dt_s, cfg.plant.stiffness_Nm_rad,
                                           cfg.plant.motor_inertia_kg_m2, cfg.plant.motor_damping_Nms_rad)
        inner = _add(inner, (bp, ap))
        bq, aq = q_filter_coefficients(cfg.q_cutoff_hz, cfg.dt_s)
        qf = _mul((bq, aq), F)
        # 1 - Q F z^-1 = (den - z^-1 num) / den
        one_minus = (_padd(qf[1], np.concatenate(([0.0], qf[0])), -1.0), qf[1])
        c = _mul(F, inner)
        return _mul(c, (one_minus[1], one_minus[0]))
    integ = (np.array([fb.ki_1_s * cfg.dt_s]), np.array([1.0, -1.0]))
    return _mul(F, _add(inner, integ) if fb.ki_1_s > 0 else inner)


def reference_tf(cfg: ControllerConfig) -> TF:
    """Open path ``R(z)`` from the torque reference to u: ``(1 + kp + k_b BP) / (1 - Q F z^-1)`` (LDO)."""
    g: TF = (np.array([1.0 + cfg.feedback.kp]), np.array([1.0]))
    if cfg.feedback.band_gain != 0.0:
        g = _add(g, band_filter(cfg))
    if cfg.torque_loop != TorqueLoop.LDO:
        return g
    bq, aq = q_filter_coefficients(cfg.q_cutoff_hz, cfg.dt_s)
    qf = _mul((bq, aq), tau_in_filter(cfg))
    return _mul(g, (qf[1], _padd(qf[1], np.concatenate(([0.0], qf[0])), -1.0)))


def reference_response(cfg: ControllerConfig, f_hz: np.ndarray) -> np.ndarray:
    """``R + K_i + b H_r`` at ``f_hz``: a term added to the output torque asked for -> u (torques at the motor side).

    It reaches u through the reference path :func:`reference_tf` ``R``, the PID's integral on the error
    ``K_i = ki T / (1 - z^-1)`` and the deflection damping's reference rate ``b H_r``
    (:func:`deflection_reference_filter`). Summed as responses: the expanded polynomial of the sum loses the
    low frequencies to rounding (poles near z = 1)."""
    fb, dt = cfg.feedback, cfg.dt_s
    resp = freq_response(reference_tf(cfg), f_hz, dt)
    if cfg.torque_loop != TorqueLoop.LDO and fb.ki_1_s > 0.0:
        resp = resp + freq_response((np.array([fb.ki_1_s * dt]), np.array([1.0, -1.0])), f_hz, dt)
    if fb.deflection_damping_Nms_rad != 0.0:
        resp = resp + fb.deflection_damping_Nms_rad * freq_response(deflection_reference_filter(cfg), f_hz, dt)
    return resp


def output_torque_response(cfg: ControllerConfig, f_hz: np.ndarray) -> np.ndarray:
    """``k_o Ho (R + K_i + b H_r)`` at ``f_hz``: the measured output torque -> u, negated (``u = -this tau_out``).

    ``Ho`` the step's filter on e_out (:func:`output_torque_filter`); the term enters the torque reference
    (:func:`reference_response`). The gravity model's part of e_out is left out as in the slip points' residual
    link stiffness (stability.slip_link_stiffness_Nm_rad)."""
    return (cfg.feedback.output_torque_gain * freq_response(output_torque_filter(cfg), f_hz, cfg.dt_s)
            * reference_response(cfg, f_hz))


def link_inertia_response(cfg: ControllerConfig, f_hz: np.ndarray) -> np.ndarray:
    """``J_lc (r_in/r_out)^2 A_l (1 + k_o Ho) (R + K_i + b H_r)`` at ``f_hz``: the link's velocity -> u, the link
    inertia compensation
    (``feedback.link_inertia_comp_kg_m2``): added to the output torque asked for, so also to e_out, whose gain
    ``k_o Ho`` it passes. ``A_l`` :func:`link_inertia_filter`. Only in slip (0 when off)."""
    fb = cfg.feedback
    if fb.link_inertia_comp_kg_m2 == 0.0:
        return np.zeros(len(np.atleast_1d(f_hz)), dtype=complex)
    ratio = cfg.plant.r_in_m / cfg.plant.r_out_m
    g = 1.0 + fb.output_torque_gain * freq_response(output_torque_filter(cfg), f_hz, cfg.dt_s)
    a_l = freq_response(link_inertia_filter(cfg), f_hz, cfg.dt_s)
    return (fb.link_inertia_comp_kg_m2 * ratio**2 * a_l
            * g * reference_response(cfg, f_hz))


def output_torque_filter(cfg: ControllerConfig) -> TF:
    """``Ho``: the step's filter on e_out, a first-order low-pass at ``feedback.output_torque_cutoff_hz``
    times its peak filter ``1 + g BP`` (``feedback.output_torque_peak_gain`` > 0; the step's biquad,
    :func:`capstan.controller.law.ldo.output_peak_biquad`)."""
    fb = cfg.feedback
    a = lowpass_alpha(fb.output_torque_cutoff_hz, cfg.dt_s)
    lp: TF = (np.array([1.0 - a]), np.array([1.0, -a]))
    if fb.output_torque_peak_gain <= 0.0:
        return lp
    b0, b1, b2, a1, a2 = output_peak_biquad(fb.output_torque_peak_gain, fb.output_torque_peak_hz,
                                            fb.output_torque_peak_q, cfg.dt_s)
    return _mul(lp, (np.array([b0, b1, b2]), np.array([1.0, a1, a2])))


def acceleration_filter(cfg: ControllerConfig, source: AccelerationSource | None = None) -> TF:
    """``A(z)``: velocity -> the step's acceleration [1/s], of ``source`` (default: the inertia
    compensation's, ``feedback.acceleration_source``; the deflection damping's lead always takes the link's).

    Motor source: ``(1 - a)(1 - z^-1) / (T (1 - a z^-1))``. Link source: the IMU's rate
    is differentiated per 400 Hz sample and held; modelled at 1 kHz as the same difference
    with one cycle more delay (the sample-and-hold's mean age, 1.25 ms), and ``r_in/r_out``.
    """
    a = lowpass_alpha(cfg.feedback.acceleration_cutoff_hz, cfg.dt_s)
    g = (1.0 - a) / cfg.dt_s
    if (cfg.feedback.acceleration_source if source is None else source) == AccelerationSource.LINK:
        g /= cfg.plant.r_in_m / cfg.plant.r_out_m
        return np.array([0.0, g, -g]), np.array([1.0, -a])
    return np.array([g, -g]), np.array([1.0, -a])


def link_inertia_filter(cfg: ControllerConfig) -> TF:
    """``A_l(z)``: the link's velocity -> the link inertia compensation's acceleration at the motor side [1/s]:
    the link source's difference per IMU sample as in :func:`acceleration_filter` (one cycle more delay,
    ``r_in/r_out``), the step's low-pass at ``feedback.link_inertia_cutoff_hz`` instead of J_c's, and its
    high-pass ``x - LP[x]`` at ``feedback.link_inertia_highpass_hz``, ``h (1 - z^-1) / (1 - h z^-1)``."""
    fb = cfg.feedback
    a = lowpass_alpha(fb.link_inertia_cutoff_hz, cfg.dt_s)
    h = lowpass_alpha(fb.link_inertia_highpass_hz, cfg.dt_s)
    g = (1.0 - a) / (cfg.dt_s * cfg.plant.r_in_m / cfg.plant.r_out_m)
    return _mul((np.array([0.0, g, -g]), np.array([1.0, -a])), (np.array([h, -h]), np.array([1.0, -h])))


def deflection_link_filter(cfg: ControllerConfig) -> TF:
    """``H_l(z)``: link velocity dq_out -> the motor velocity it implies in the deflection-rate
    damping, ``(r_out/r_in) (1 - a) z^-1 / (1 - a z^-1)``: the IMU's 400 Hz sample-and-hold as
    one cycle of delay (as in :func:`acceleration_filter`) and the step's first-order low-pass
    at ``feedback.deflection_link_cutoff_hz``."""
    a = lowpass_alpha(cfg.feedback.deflection_link_cutoff_hz, cfg.dt_s)
    g = (1.0 - a) * cfg.plant.r_out_m / cfg.plant.r_in_m
    return np.array([0.0, g]), np.array([1.0, -a])


def deflection_reference_filter(cfg: ControllerConfig) -> TF:
    """``H_r(z)``: the reference (tau_in_des less gravity) -> the deflection rate it asks for
    [rad/s per Nm], ``(1 - a)(1 - z^-1) / (T K_c (1 - a z^-1))``: the step's low-pass at
    ``feedback.deflection_reference_cutoff_hz``, backward difference, ``1 / plant.stiffness_Nm_rad``.

    A reference path (the torque reference and the friction feedforward, not linear and left out
    of this analysis as elsewhere), so not part of the loop. The gravity model is left out of it
    in the step: its rate is ``m_g_l dq_out``, a positive feedback of the link's velocity that
    undamps the free link's slow mode (0.2 Hz) at every slip point of the grid for b >= 40."""
    a = lowpass_alpha(cfg.feedback.deflection_reference_cutoff_hz, cfg.dt_s)
    g = (1.0 - a) / (cfg.dt_s * cfg.plant.stiffness_Nm_rad)
    return np.array([g, -g]), np.array([1.0, -a])


def acceleration_velocity_tf(cfg: ControllerConfig, p: PlantPoint) -> TF:
    """The plant's velocity that feeds the inertia compensation (motor or link), continuous."""
    if cfg.feedback.acceleration_source == AccelerationSource.LINK:
        return plant_link_velocity_continuous(p)
    return plant_velocity_continuous(p)


def observer_delay_cycles(cfg: ControllerConfig) -> int:
    """Which past command the motor velocity observer takes as acting on the motor: ``u[k-1-d]``, ``d`` the
    configured I/O delay (``stability.io_delay_cycles``, at most the step's history allows)."""
    return min(cfg.stability.io_delay_cycles, HISTORY - 1)


def motor_velocity_response(cfg: ControllerConfig, p: PlantPoint, delay_cycles: int, f_hz: np.ndarray) -> np.ndarray:
    """The motor velocity the step reads, per unit command u, at ``f_hz`` (the loop's delay ``delay_cycles``).

    ``drive``: the plant's velocity ``z^-d P_v``. ``observer`` (:mod:`capstan.controller.law.observer.motor_velocity`):
    ``H_q z^-d P_q + H_a (z^-(1+d_o) - z^-d P) / J_m``, ``P_q`` the motor's position, ``P`` tau_in, ``d_o``
    :func:`observer_delay_cycles` (which may differ from the plant's ``d``: the delay's jitter)."""
    fb, dt = cfg.feedback, cfg.dt_s
    if fb.motor_velocity == MotorVelocitySource.DRIVE:
        return freq_response(plant_discrete(p, dt, delay_cycles, plant_velocity_continuous(p)), f_hz, dt)
    h_q, h_a = observer_responses(observer_gains(fb.motor_velocity_observer_hz, fb.motor_velocity_bias_hz, dt), dt, f_hz)
    pq = freq_response(plant_discrete(p, dt, delay_cycles, plant_position_continuous(p)), f_hz, dt)
    pt = freq_response(plant_discrete(p, dt, delay_cycles), f_hz, dt)
    u_own = np.exp(-2j * math.pi * np.asarray(f_hz) * dt * (1 + observer_delay_cycles(cfg)))
    return h_q * pq + h_a * (u_own - pt) / observer_inertia_kg_m2(cfg)


def encoder_response(cfg: ControllerConfig, f_hz: np.ndarray) -> np.ndarray:
    """The motor velocity the step reads per unit position noise (the encoder's quantisation) at ``f_hz``: the
    observer's ``H_q``, or 0 with the drive's velocity (its own quantisation is not modelled here)."""
    fb = cfg.feedback
    if fb.motor_velocity == MotorVelocitySource.DRIVE:
        return np.zeros(len(np.atleast_1d(f_hz)), dtype=complex)
    return observer_responses(observer_gains(fb.motor_velocity_observer_hz, fb.motor_velocity_bias_hz, cfg.dt_s), cfg.dt_s, f_hz)[0]


def motor_velocity_to_command(cfg: ControllerConfig, f_hz: np.ndarray) -> np.ndarray:
    """The command per unit motor velocity read (negated: ``u = -this v_m``): the damping ``b`` less J_c's
    ``A`` (motor source; faded gains as configured)."""
    fb = cfg.feedback
    out = np.full(len(np.atleast_1d(f_hz)), fb.deflection_damping_Nms_rad, dtype=complex)
    if fb.inertia_comp_kg_m2 != 0.0 and fb.acceleration_source == AccelerationSource.MOTOR:
        out = out - fb.inertia_comp_kg_m2 * freq_response(acceleration_filter(cfg), f_hz, cfg.dt_s)
    return out


def loop_response(cfg: ControllerConfig, p: PlantPoint, delay_cycles: int,
                  f_hz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(C, L)`` at ``f_hz``: the tau_in feedback path and the loop gain broken at the plant
    input, ``L = z^-d (C P - J_c A P_v - link_inertia_response P_v + b (P_v - (H_l + lead A) P_o)
    [+ output_torque_response P in slip])`` (the inertia compensations are
    positive feedback of the acceleration, so it enters with a minus sign; the deflection-rate
    damping ``b`` is negative feedback of the motor velocity less the link's, :func:`deflection_link_filter`,
    led by ``lead`` (:func:`capstan.controller.law.feedback_config.deflection_link_lead_s`) times the link's
    acceleration through J_c's filter ``A``)."""
    c = freq_response(controller_tf(cfg), f_hz, cfg.dt_s)
    loop = c * freq_response(plant_discrete(p, cfg.dt_s, delay_cycles), f_hz, cfg.dt_s)
    jc = cfg.feedback.inertia_comp_kg_m2
    vel = acceleration_velocity_tf(cfg, p)
    b = cfg.feedback.deflection_damping_Nms_rad
    v_m = (motor_velocity_response(cfg, p, delay_cycles, f_hz)
           if b != 0.0 or (jc != 0.0 and cfg.feedback.acceleration_source == AccelerationSource.MOTOR) else None)
    if jc != 0.0 and cfg.feedback.acceleration_source == AccelerationSource.MOTOR:
        loop = loop - jc * freq_response(acceleration_filter(cfg), f_hz, cfg.dt_s) * v_m
    elif jc != 0.0 and np.any(vel[0]):
        pv = plant_discrete(p, cfg.dt_s, delay_cycles, vel)
        loop = loop - jc * freq_response(_mul(acceleration_filter(cfg), pv), f_hz, cfg.dt_s)
    if cfg.feedback.link_inertia_comp_kg_m2 != 0.0 and p.slip:    # positive feedback of the link's acceleration
        pvo = plant_discrete(p, cfg.dt_s, delay_cycles, plant_link_velocity_continuous(p))
        loop = loop - link_inertia_response(cfg, f_hz) * freq_response(pvo, f_hz, cfg.dt_s)
    if b != 0.0:    # - b (v_m - H_l dq_out) on the command
        defl = v_m
        if p.slip:
            pvo = plant_discrete(p, cfg.dt_s, delay_cycles, plant_link_velocity_continuous(p))
            defl = defl - freq_response(_mul(deflection_link_filter(cfg), pvo), f_hz, cfg.dt_s)
            lead = deflection_link_lead_s(cfg)      # + lead x the link's acceleration (J_c's filter A)
            if lead != 0.0:
                defl = defl - lead * freq_response(_mul(acceleration_filter(cfg, AccelerationSource.LINK), pvo),
                                                   f_hz, cfg.dt_s)
        loop = loop + b * defl
    if p.slip and cfg.feedback.output_torque_gain != 0.0:  # + k_o Ho (R + K_i + b H_r) P: tau_out = tau_in in slip
        loop = loop + output_torque_response(cfg, f_hz) * freq_response(plant_discrete(p, cfg.dt_s, delay_cycles),
                                                                         f_hz, cfg.dt_s)
    return c, loop


def freq_response(tf: TF, f_hz: np.ndarray, dt_s: float) -> np.ndarray:
    """Complex response of an ascending-z^-1 ratio at ``f_hz``."""
    zi = np.exp(-2j * math.pi * np.asarray(f_hz) * dt_s)
    return np.polyval(tf[0][::-1], zi) / np.polyval(tf[1][::-1], zi)


class _Block:
    """A small discrete SISO block in state space (from its ascending-z^-1 ratio)."""

    def __init__(self, tf: TF) -> None:
        n = max(len(tf[0]), len(tf[1]))
        num = np.zeros(n)
        den = np.zeros(n)
        num[:len(tf[0])] = tf[0]
        den[:len(tf[1])] = tf[1]
        if n == 1 or not np.any(num):
            self.A, self.B, self.C, self.D = (np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)),
                                              np.array([[num[0] / den[0] if n == 1 else 0.0]]))
        else:
            with warnings.catch_warnings():     # a leading zero (a pure delay) is stripped, not a problem
                warnings.simplefilter("ignore", signal.BadCoefficients)
                self.A, self.B, self.C, self.D = signal.tf2ss(num, den)
        self.n = self.A.shape[0]

    def step(self, x: np.ndarray, u: float) -> tuple[float, np.ndarray]:
        y = float((self.C @ x).sum() + self.D[0, 0] * u)
        return y, self.A @ x + self.B[:, 0] * u


def closed_loop_matrix(cfg: ControllerConfig, p: PlantPoint, delay_cycles: int) -> np.ndarray:
    """The closed loop's state-transition matrix, built by probing one cycle of the loop
    (the step's signal flow with small well-conditioned blocks) with unit states.

    Its eigenvalues are the closed-loop poles; unlike the roots of the loop's
    characteristic polynomial (poles clustered near z = 1 at 1 kHz make those wrong by
    ~1e-3) they are accurate to rounding.
    """
    fb = cfg.feedback
    ldo = cfg.torque_loop == TorqueLoop.LDO
    F1, F2 = _Block(tau_in_filter(cfg)), _Block(tau_in_filter(cfg))
    Dd = _Block(derivative_filter(cfg))
    if ldo:
        QP = _Block(qpinv_filter_coefficients(cfg.q_cutoff_hz, cfg.dt_s, cfg.plant.stiffness_Nm_rad,
                                              cfg.plant.motor_inertia_kg_m2, cfg.plant.motor_damping_Nms_rad))
        Q = _Block(q_filter_coefficients(cfg.q_cutoff_hz, cfg.dt_s))
    else:
        QP = Q = _Block((np.array([0.0]), np.array([1.0])))
    ag, bg, cg = plant_state_space(p, cfg.dt_s)
    jc = fb.inertia_comp_kg_m2
    lead = deflection_link_lead_s(cfg)
    none = (np.array([0.0]), np.array([1.0]))
    link = fb.acceleration_source == AccelerationSource.LINK
    # J_c's acceleration (its source), and the link's for the lead when J_c takes the motor's
    jlc = fb.link_inertia_comp_kg_m2 * (cfg.plant.r_in_m / cfg.plant.r_out_m) ** 2 if p.slip else 0.0
    Acc = _Block(acceleration_filter(cfg) if jc != 0.0 or (lead != 0.0 and link) else none)
    AccL = _Block(acceleration_filter(cfg, AccelerationSource.LINK) if lead != 0.0 and not link else none)
    AccJ = _Block(link_inertia_filter(cfg) if jlc != 0.0 else none)
    v_index = (3 if p.slip else -1) if link else 1      # plant states (q_m, dq_m[, q_o, dq_o])
    b_defl = fb.deflection_damping_Nms_rad
    Hl = _Block(deflection_link_filter(cfg) if b_defl != 0.0 else (np.array([0.0]), np.array([1.0])))
    d = int(delay_cycles)
    # plant, tau_in filter, derivative, Q P^-1, observer's filter of u[k-1], Q, u[k-1], integral, delay,
    # motor acceleration filter, the link velocity's filter of the deflection-rate damping, the link's
    # acceleration filter of its lead (only with J_c on the motor's), the band gain's band-pass
    # (with ki = 0 the step's integral stays 0: a constant, not a mode of the loop, so no state)
    integral = not ldo and fb.ki_1_s != 0.0
    Bd = _Block(band_filter(cfg))
    # the output torque's gain: its low-pass on tau_out (= tau_in in slip, not moved by the motor in stick)
    # and the deflection damping's reference rate, which the term moves
    k_o = fb.output_torque_gain if p.slip else 0.0
    Ho = _Block(output_torque_filter(cfg) if k_o != 0.0 else none)
    Hr = _Block(deflection_reference_filter(cfg) if (k_o != 0.0 or jlc != 0.0) and b_defl != 0.0 else none)
    # the motor velocity observer (q^, v^) and the commands u[k-1] ... u[k-HISTORY] it takes its input from
    obs = fb.motor_velocity == MotorVelocitySource.OBSERVER and (b_defl != 0.0 or (jc != 0.0 and not link))
    if obs:
        Fo, Go, Ko = observer_matrices(observer_gains(fb.motor_velocity_observer_hz, fb.motor_velocity_bias_hz, cfg.dt_s), cfg.dt_s)
        d_o, j_inv = observer_delay_cycles(cfg), 1.0 / observer_inertia_kg_m2(cfg)
    sizes = [ag.shape[0], F1.n, Dd.n, QP.n, F2.n if ldo else 0, Q.n, 1 if ldo else 0, 1 if integral else 0, d, Acc.n, Hl.n,
             AccL.n, Bd.n, Ho.n, Hr.n, AccJ.n, 3 if obs else 0, HISTORY if obs else 0]
    idx = np.cumsum([0] + sizes)
    n = int(idx[-1])

    def one(x: np.ndarray) -> np.ndarray:
        xs = [x[idx[i]:idx[i + 1]] for i in range(len(sizes))]
        out = [None] * len(sizes)
        y = float(cg @ xs[0])
        tf_, out[1] = F1.step(xs[1], y)
        dd, out[2] = Dd.step(xs[2], tf_)
        qp, out[3] = QP.step(xs[3], tf_)
        v_m = float(xs[0][1])
        out[16], out[17] = xs[16], xs[17]
        if obs:     # the step's observer on the position, its input the command u[k-1-d_o] and tau_in (raw)
            xo = Fo @ xs[16] + Go * ((float(xs[17][d_o]) - y) * j_inv) + Ko * float(xs[0][0])
            out[16], v_m = xo, float(xo[1])
        v = (float(xs[0][v_index]) if v_index >= 0 else 0.0) if link else v_m
        acc, out[9] = Acc.step(xs[9], v)
        acc_j, out[15] = AccJ.step(xs[15], float(xs[0][3]) if p.slip else 0.0)
        t_link = jlc * acc_j                     # the link inertia compensation's term (motor side)
        ho, out[13] = Ho.step(xs[13], y - t_link)
        ref = t_link - k_o * ho                  # the output torque's terms in the reference
        bd, out[12] = Bd.step(xs[12], tf_ - ref)      # the band gain on the error: -k_b BP (tau_in - ref)
        if ldo:
            m, out[4] = F2.step(xs[4], float(xs[6][0]))
            q, out[5] = Q.step(xs[5], m)
            out[7] = xs[7]
            u = -(fb.kp * (tf_ - ref) + dd + qp + bd) + q + ref
        else:
            out[4], out[5], out[6] = xs[4], xs[5], xs[6]
            integ = float(xs[7][0]) - fb.ki_1_s * cfg.dt_s * (tf_ - ref) if integral else 0.0
            out[7] = np.array([integ]) if integral else xs[7]
            u = -(fb.kp * (tf_ - ref) + dd + bd) + integ + ref
        v_ref, out[14] = Hr.step(xs[14], ref)
        u += b_defl * v_ref
        u += jc * acc
        v_link, out[10] = Hl.step(xs[10], float(xs[0][3]) if p.slip else 0.0)
        acc_l, out[11] = AccL.step(xs[11], float(xs[0][3]) if p.slip else 0.0)
        u -= b_defl * (v_m - v_link - lead * (acc if link else acc_l))
        if obs:
            out[17] = np.concatenate(([u], xs[17][:-1]))
        if ldo:
            out[6] = np.array([u])      # the observer's u[k-1] is the applied command, J_c term included
        if d:
            w = float(xs[8][0])
            out[8] = np.concatenate((xs[8][1:], [u]))
        else:
            w = u
            out[8] = xs[8]
        out[0] = ag @ xs[0] + bg * w
        return np.concatenate(out)

    return np.column_stack([one(e) for e in np.eye(n)])


def closed_loop_poles(cfg: ControllerConfig, p: PlantPoint, delay_cycles: int) -> np.ndarray:
    """Closed-loop poles (eigenvalues of :func:`closed_loop_matrix`)."""
    return np.linalg.eigvals(closed_loop_matrix(cfg, p, delay_cycles))
