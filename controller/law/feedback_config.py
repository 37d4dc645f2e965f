"""The ``controller.feedback`` section: the torque loop's gains on the tau_in error and the
inertia compensation (``inertia_comp_kg_m2`` x an acceleration, see
:mod:`capstan.controller.law.step`), with their parsing and validation."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Mapping

from capstan.controller.law.observer.motor_velocity import MotorVelocitySource
from capstan.models.common.config_tools import get_bool, get_choice, get_float, reject_unknown
from capstan.models.common.errors import ConfigError


class AccelerationSource(IntEnum):
    """Where the inertia compensation takes its acceleration from."""

    MOTOR = 0       # the drive's motor velocity, differentiated every cycle
    LINK = 1        # the IMU's rate of turn, differentiated on each new sample (400 Hz)


@dataclass(frozen=True)
class FeedbackGains:
    """C(s) on the tau_in error; ``ki_1_s`` only in the PID loop."""

    kp: float = 0.75
    kd_s: float = 0.0
    derivative_cutoff_hz: float = 40.0
    ki_1_s: float = 0.15
    integral_limit_Nm: float = 5.0
    #: inertia compensation [kg m^2] (0 = off): ``+ inertia_comp_kg_m2 * a`` on the command, ``a``
    #: the link's (IMU rate) or the motor's (drive velocity) acceleration at the motor side
    #: [rad/s^2], differentiated and low-passed at ``acceleration_cutoff_hz`` [Hz], off at rest
    #: (the feedforward's rest band); the hand feels ``J_m - inertia_comp_kg_m2``. From the motor's
    #: acceleration and with ``rest_gate_cutoff_hz`` > 0 it is also faded in and out with kp and the
    #: deflection damping (without that damping the loop with it rings the stick mode: it acts as a
    #: smaller motor inertia, which moves the deflection modes up)
    inertia_comp_kg_m2: float = 0.45
    acceleration_cutoff_hz: float = 3.0
    acceleration_source: AccelerationSource = AccelerationSource.MOTOR
    #: damping of the transmission's deflection rate [Nm s/rad] (0 = off):
    #: ``- deflection_damping_Nms_rad * (dq_m - (r_out/r_in) LP[g dq_out])`` on the command, dq_m the
    #: drive's motor velocity (every cycle), dq_out the IMU rate (per sample, held) low-passed at
    #: ``deflection_link_cutoff_hz`` [Hz] (gated at rest like the inertia compensation only when
    #: ``rest_gate_cutoff_hz`` is 0; with the fade the whole term is faded out at rest instead): it damps
    #: the motor against the cable (the stick and sheath-stick modes) and is 0 in a steady motion.
    #: The deflection the torque reference asks for is not braked: its rate
    #: ``d/dt LP[tau_in_des - gravity] / plant.stiffness_Nm_rad`` (low-pass at
    #: ``deflection_reference_cutoff_hz`` [Hz]) is subtracted (friction flips, torque reference)
    deflection_damping_Nms_rad: float = 100.0
    deflection_link_cutoff_hz: float = 80.0
    deflection_reference_cutoff_hz: float = 2.0
    #: 0: kp and the deflection damping always act. > 0: only while the joint moves (the
    #: feedforward's debounced rest gate on dq_out, as for the inertia compensation), faded in and out
    #: by a first-order low-pass at this cutoff [Hz]: at rest the command then carries neither the
    #: load cells' noise x kp nor the encoder velocity's quantisation x b, and the loop at rest is
    #: the kp = 0, b = 0 one (the start-up check covers both ends and the middle)
    rest_gate_cutoff_hz: float = 5.0
    #: add ``tau a`` to the link's velocity in the damping, ``a`` the inertia compensation's link acceleration
    #: (5 Hz) and ``tau = 1 / (2 pi deflection_link_cutoff_hz) + dt`` the low-pass's and the IMU hold's
    #: lag: a lagging link velocity reads as deflection while the joint accelerates and brakes the hand
    #: like an inertia b tau; compensated, the low-pass can keep the gyro noise and the 400 Hz hold's
    #: staircase off the command. The link's acceleration also with ``acceleration_source: motor`` (then
    #: differentiated and filtered on its own, as J_c's would be with the link source). It adds link-acceleration feedback
    #: like J_c: with it J_c 0.3 misses the phase margin (43 deg), J_c 0.2 meets it (50 deg, GM 9.1 dB)
    deflection_link_lag_compensation: bool = False
    #: extra gain on the tau_in error in a band [Nm/Nm] (0 = off): ``+ band_gain * BP[e]`` on the command,
    #: BP a 4th-order Butterworth band-pass ``band_low_hz``-``band_high_hz`` [Hz] (the strokes' band).
    #: Loop gain where the hand moves, not at the sheath-stick mode (13-30 Hz, where kp is capped) nor at
    #: the free link's slow mode in slip (0.2 Hz, where an integral's lag undamps it); faded with kp
    band_gain: float = 2.5
    band_low_hz: float = 0.3
    band_high_hz: float = 2.0
    #: gain on the output torque's error [Nm/Nm] (0 = off): ``+ output_torque_gain * LP[e_out]`` on the output
    #: torque reference, ``e_out = tau_g + tau_out_ref - r_out (T_up_out - T_lo_out)`` from the output load
    #: cells, low-passed at ``output_torque_cutoff_hz`` [Hz], faded with kp (off at rest). In motion e_out is
    #: the hand's torque less the link's own inertia torque: what the sheath's friction and the motor add to
    #: the link's impedance is divided by ``1 + output_torque_gain``. In the loop only in slip (in stick the
    #: output torque does not follow the motor), where it adds ``k_o LP (R + b H_r) P`` (loop_model)
    output_torque_gain: float = 2.5
    output_torque_cutoff_hz: float = 10.0
    #: a peak on that term: ``LP[e_out] x (1 + output_torque_peak_gain BP)``, BP a unit-gain second-order
    #: band-pass at ``output_torque_peak_hz`` [Hz] with quality ``output_torque_peak_q``: the gain is
    #: ``output_torque_gain (1 + peak_gain)`` at the peak (where fast strokes swing the link on the hand) and
    #: about ``output_torque_gain`` at the grip and two-mass modes (4-13 Hz), where a higher gain shakes a
    #: firmly held link. 0 = off
    output_torque_peak_gain: float = 1.0
    output_torque_peak_hz: float = 2.0
    output_torque_peak_q: float = 1.5
    #: link inertia compensation [kg m^2] (0 = off): ``+ link_inertia_comp_kg_m2 (r_in/r_out) A[a]`` on the
    #: output torque asked for (and so in e_out), ``A[a]`` the link's acceleration from the IMU rate at the motor
    #: side (differentiated per sample and gated at rest as J_c's with the link source, whatever J_c's source: a
    #: firmly held link does not accelerate, the motor still does), and faded with kp when that fades. The
    #: cable then pushes the link's own inertia torque for the hand, which feels ``J_l - link_inertia_comp_kg_m2``
    #: of it; needs the output torque's gain to hold that torque against the sheath's friction. Below the link's
    #: inertia (stability.link_inertia_kg_m2, config check); in the loop as positive acceleration feedback
    #: through the reference path, in stick and slip (loop_model)
    link_inertia_comp_kg_m2: float = 0.04
    #: its own first-order low-pass [Hz] and a first-order high-pass [Hz] on that acceleration: a lag at the
    #: grip modes (4-8 Hz, where a hand holding the link firmly swings it) acts as negative damping there, and
    #: at the free link's slow mode (0.2-0.5 Hz) the high-pass turns the low-pass's lag into a lead
    link_inertia_cutoff_hz: float = 3.0
    link_inertia_highpass_hz: float = 0.3
    #: the motor velocity the damping and the motor-source inertia compensation read: ``observer`` forms it from
    #: the motor's position (the encoder counts) and the torques on the motor
    #: (:mod:`capstan.controller.law.observer.motor_velocity`), with its error dynamics at ``motor_velocity_observer_hz``
    #: [Hz]; ``drive`` takes the drive's velocity object as reported (a 1 ms count difference or whole rpm on a
    #: real drive: b x its quantisation steps the command)
    motor_velocity: MotorVelocitySource = MotorVelocitySource.OBSERVER
    motor_velocity_observer_hz: float = 25.0
    #: the pole [Hz] of its third state, the acceleration the torques do not explain (offsets, friction, J_m's
    #: error x the acceleration); above ~2 Hz it weakens a firm grip's damping (grip PM 42.7 deg at 2 Hz, 23.6 at 4)
    motor_velocity_bias_hz: float = 2.0
    #: the observer's model inertia as a fraction of ``plant.motor_inertia_kg_m2``: lighter than the motor, the
    #: estimate leads above the observer's cutoff, heavier it lags. 0.82 (0.6 of 0.73 kg m^2): with J_m -30 % the
    #: lag of a nominal model costs the sheath-stick phase margin (PM 34.9 deg at 1.0, 49.5 at 0.82, 53.5 at 0.7),
    #: while J_m's error x a stroke's acceleration, which the third state follows only up to its pole, raises the
    #: felt torque (fast strokes 0.449 Nm at 0.82, 0.471-0.484 at 0.7)
    motor_velocity_inertia_factor: float = 0.82


def feedback_from_mapping(c: Mapping[str, Any], p: str, fd: FeedbackGains, nyq: float) -> FeedbackGains:
    """Validate the ``feedback`` mapping ``c`` (dotted prefix ``p``; defaults ``fd``; Nyquist ``nyq`` [Hz]).

    :raises ConfigError: naming the key: unknown key, wrong type or out of range.
    """
    reject_unknown(c, {"kp", "kd_s", "derivative_cutoff_hz", "ki_1_s", "integral_limit_Nm",
                       "inertia_comp_kg_m2", "acceleration_cutoff_hz", "acceleration_source",
                       "deflection_damping_Nms_rad", "deflection_link_cutoff_hz", "deflection_reference_cutoff_hz",
                       "rest_gate_cutoff_hz", "deflection_link_lag_compensation", "band_gain", "band_low_hz",
                       "band_high_hz", "output_torque_gain", "output_torque_cutoff_hz",
                       "output_torque_peak_gain", "output_torque_peak_hz", "output_torque_peak_q",
                       "link_inertia_comp_kg_m2", "link_inertia_cutoff_hz", "link_inertia_highpass_hz",
                       "motor_velocity", "motor_velocity_observer_hz", "motor_velocity_bias_hz",
                       "motor_velocity_inertia_factor"}, p)
    source = AccelerationSource[get_choice(c, "acceleration_source", ("motor", "link"), p,
                                           fd.acceleration_source.name.lower()).upper()]
    lag = get_bool(c, "deflection_link_lag_compensation", p, fd.deflection_link_lag_compensation)
    out = FeedbackGains(
        get_float(c, "kp", p, fd.kp, min_value=0.0),
        get_float(c, "kd_s", p, fd.kd_s, min_value=0.0),
        get_float(c, "derivative_cutoff_hz", p, fd.derivative_cutoff_hz, min_value=0.0,
                  min_exclusive=True, max_value=0.45 * nyq),
        get_float(c, "ki_1_s", p, fd.ki_1_s, min_value=0.0),
        get_float(c, "integral_limit_Nm", p, fd.integral_limit_Nm, min_value=0.0),
        get_float(c, "inertia_comp_kg_m2", p, fd.inertia_comp_kg_m2, min_value=0.0),
        get_float(c, "acceleration_cutoff_hz", p, fd.acceleration_cutoff_hz, min_value=0.0,
                  min_exclusive=True, max_value=0.45 * nyq),
        source,
        get_float(c, "deflection_damping_Nms_rad", p, fd.deflection_damping_Nms_rad, min_value=0.0,
                  max_value=1e4),
        get_float(c, "deflection_link_cutoff_hz", p, fd.deflection_link_cutoff_hz, min_value=0.0,
                  min_exclusive=True, max_value=0.45 * nyq),
        get_float(c, "deflection_reference_cutoff_hz", p, fd.deflection_reference_cutoff_hz, min_value=0.0,
                  min_exclusive=True, max_value=0.45 * nyq),
        get_float(c, "rest_gate_cutoff_hz", p, fd.rest_gate_cutoff_hz, min_value=0.0, max_value=0.45 * nyq),
        lag,
        get_float(c, "band_gain", p, fd.band_gain, min_value=0.0, max_value=100.0),
        get_float(c, "band_low_hz", p, fd.band_low_hz, min_value=0.0, min_exclusive=True, max_value=0.45 * nyq),
        get_float(c, "band_high_hz", p, fd.band_high_hz, min_value=0.0, min_exclusive=True, max_value=0.45 * nyq),
        get_float(c, "output_torque_gain", p, fd.output_torque_gain, min_value=0.0, max_value=100.0),
        get_float(c, "output_torque_cutoff_hz", p, fd.output_torque_cutoff_hz, min_value=0.0, min_exclusive=True,
                  max_value=0.45 * nyq),
        get_float(c, "output_torque_peak_gain", p, fd.output_torque_peak_gain, min_value=0.0, max_value=20.0),
        get_float(c, "output_torque_peak_hz", p, fd.output_torque_peak_hz, min_value=0.0, min_exclusive=True,
                  max_value=0.45 * nyq),
        get_float(c, "output_torque_peak_q", p, fd.output_torque_peak_q, min_value=0.3, max_value=30.0),
        get_float(c, "link_inertia_comp_kg_m2", p, fd.link_inertia_comp_kg_m2, min_value=0.0),
        get_float(c, "link_inertia_cutoff_hz", p, fd.link_inertia_cutoff_hz, min_value=0.0, min_exclusive=True,
                  max_value=0.45 * nyq),
        get_float(c, "link_inertia_highpass_hz", p, fd.link_inertia_highpass_hz, min_value=0.0, min_exclusive=True,
                  max_value=0.45 * nyq),
        MotorVelocitySource[get_choice(c, "motor_velocity", ("observer", "drive"), p,
                                       fd.motor_velocity.name.lower()).upper()],
        get_float(c, "motor_velocity_observer_hz", p, fd.motor_velocity_observer_hz, min_value=0.0,
                  min_exclusive=True, max_value=0.2 * nyq),
        get_float(c, "motor_velocity_bias_hz", p, fd.motor_velocity_bias_hz, min_value=0.0, min_exclusive=True,
                  max_value=0.2 * nyq),
        get_float(c, "motor_velocity_inertia_factor", p, fd.motor_velocity_inertia_factor, min_value=0.0,
                  min_exclusive=True, max_value=2.0))
    if out.output_torque_gain > 0.0 and out.rest_gate_cutoff_hz <= 0.0:
        raise ConfigError(f"{p}.output_torque_gain", "needs rest_gate_cutoff_hz > 0: without the fade the output load "
                          f"cells' noise x the gain reaches the command at rest, got {out.output_torque_gain}")
    if out.band_high_hz <= out.band_low_hz:
        raise ConfigError(f"{p}.band_high_hz", f"must be above band_low_hz {out.band_low_hz} Hz, got {out.band_high_hz}")
    return out


def inertia_comp_faded(fb: FeedbackGains) -> bool:
    """True when the inertia compensation is faded in and out with kp and the deflection damping:
    from the motor's acceleration with ``rest_gate_cutoff_hz`` > 0."""
    return fb.acceleration_source == AccelerationSource.MOTOR and fb.rest_gate_cutoff_hz > 0.0


def observer_inertia_kg_m2(cfg: Any) -> float:
    """The motor velocity observer's model inertia [kg m^2]: ``feedback.motor_velocity_inertia_factor`` x
    ``plant.motor_inertia_kg_m2``. ``cfg``: a ControllerConfig."""
    return cfg.feedback.motor_velocity_inertia_factor * cfg.plant.motor_inertia_kg_m2


def deflection_link_lead_s(cfg: Any) -> float:
    """The lead [s] on the link's velocity in the deflection damping (0 when off or without damping):
    the low-pass's time constant ``1 / (2 pi deflection_link_cutoff_hz)`` plus one cycle ``dt_s`` (the
    IMU's 400 Hz hold, as the loop analysis models it). ``cfg``: a ControllerConfig."""
    fb = cfg.feedback
    if not fb.deflection_link_lag_compensation or fb.deflection_damping_Nms_rad == 0.0:
        return 0.0
    return 1.0 / (2.0 * math.pi * fb.deflection_link_cutoff_hz) + cfg.dt_s
