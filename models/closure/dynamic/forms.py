"""The closure's driving forms: which measured boundary signals drive the dynamic baseline's
simulation and which channel it predicts (:mod:`capstan.models.closure.dynamic.baseline`).

Driving forms (:class:`DrivingForm`), chosen from the channels a run carries
(:func:`choose_form`) and stated in the report:

``OUTPUT_HELD`` -- the output is held at a (per-run) constant torque (std of tau_out
    below ``HELD_FRACTION`` of tau_in's): q_in and tau_out drive, tau_in is predicted.
    ``K_in (q_in - x) - g tau_out = f``; ``tau_in = K_in (q_in - x) + c_in``.
``TESTBED`` -- tau_in drives the declared environment ``tau_out = k_out q + b_out dq``
    (eq 22; fitted when no environment is declared): eq (20) with the friction state,
    ``(b_out) v + f = rho tau_in - k_out x``; tau_out is predicted.
``LINK`` -- the output is a link moved by unmeasured forces (hand, gravity; table meta
    ``output: link``, written by the daemon's log mapping): tau_out (output load cells) and
    q_in (motor encoder, gear-scaled) drive the unit of ``OUTPUT_HELD``; tau_in is predicted;
    ``g = r_in / r_out`` is the pulleys' (1 / the angle ratio), not fitted. Two parameters
    shape the stick-to-slip transition here: the friction law's exponent ``dahl_exp``
    (:mod:`capstan.models.transmission.stick_slip`; 1 = Dahl) and a damping of the elastic
    path ``d_in`` [Nm s/rad] (Kelvin-Voigt: ``tau_in = K_in (q_in - x) + d_in (dq_in - v) +
    c_in``, node balance ``K_in (q_in - x) + d_in (dq_in - v) - g tau_out = f + b_vis v``;
    dq_in by the zero-phase Savitzky-Golay derivative). After a reversal of the distributed
    sheath tau_in rises at 2000-3000 Nm/rad (the cable up to the first gripping node), then
    ever less steeply; one spring K_in (~600 Nm/rad) into the Dahl law breaks away 5-10 ms
    late, which a fitted sensor latency otherwise absorbs. ``OUTPUT_HELD``: fixed at 1 / 0.
    The link angle (IMU, ~0.5 mrad noise) does not drive: x ~500 Nm/rad it is ~0.25 Nm.
``ANGLES`` -- both pulley angles drive the node of the unit:
    ``K_h (q_in - x) - K_h (x - rho q_out) = f`` with ``K_h = 2 K_c``; tau_out (and tau_in)
    are predicted; the fit uses both torques.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from capstan.models.closure.signals import Signals
from capstan.models.common.errors import ModelError

#: the output counts as held when std(tau_out) < HELD_FRACTION * std(tau_in) (every run)
HELD_FRACTION = 0.1


class DrivingForm(IntEnum):
    """Which measured boundary signals drive the simulation (module docstring)."""

    OUTPUT_HELD = 0
    TESTBED = 1
    ANGLES = 2
    LINK = 3


@dataclass(frozen=True)
class FormSpec:
    """A driving form as stated in the report: the channel predicted, the driving signals."""

    form: DrivingForm
    target: str
    driving: tuple[str, ...]
    reason: str


def held_output(sig: Signals) -> bool:
    """True when every run's tau_out is constant compared with its tau_in (a held output)."""
    for a, b in sig.segments():
        if b - a < 2 or np.std(sig.tau_out_Nm[a:b]) >= HELD_FRACTION * max(np.std(sig.tau_in_Nm[a:b]), 1e-12):
            return False
    return len(sig) > 0


def choose_form(sig: Signals) -> FormSpec:
    """The driving form for ``sig`` (see the module docstring for the order).

    :raises ModelError: if the runs carry none of the needed channel sets.
    """
    has_angles = sig.q_in_rad is not None
    if held_output(sig):
        if not has_angles:
            raise ModelError("the output torque is held constant, so tau_in must be predicted, and that needs "
                             "the input angle q_in (not in the runs)")
        return FormSpec(DrivingForm.OUTPUT_HELD, "tau_in", ("q_in", "tau_out"),
                        "tau_out is held at a constant torque per run (it carries no transmission dynamics)")
    if sig.environment is not None:
        return FormSpec(DrivingForm.TESTBED, "tau_out", ("tau_in", "environment"),
                        "the runs declare the output environment tau_out = k_out q_out + b_out dq_out")
    if sig.output_link:
        if not has_angles:
            raise ModelError("the runs declare a link output (output: link): its dynamics are not simulated, so the "
                             "input angle q_in (the motor angle) must drive the input side, and the runs lack it; "
                             "use the static baseline (--baseline static)")
        return FormSpec(DrivingForm.LINK, "tau_in", ("q_in", "tau_out"),
                        "the output is a link moved by unmeasured forces (hand, gravity): the measured output torque "
                        "and the input angle drive, tau_in is predicted")
    if has_angles:
        return FormSpec(DrivingForm.ANGLES, "tau_out", ("q_in", "q_out"),
                        "both pulley angles are measured and no output environment is declared")
    return FormSpec(DrivingForm.TESTBED, "tau_out", ("tau_in", "environment (fitted)"),
                    "no input angle and no declared environment: the environment k_out, b_out is fitted")


PARAM_NAMES = {DrivingForm.OUTPUT_HELD: ("K_in_Nm_rad", "g_out", "tau_fc_Nm", "k_pre_Nm_rad", "zeta_s", "eta_s_rad_s", "b_vis_Nms_rad",
                                    "offset_in_Nm", "dahl_exp", "d_in_Nms_rad"),
          DrivingForm.TESTBED: ("k_out_Nm_rad", "b_out_Nms_rad", "tau_fc_Nm", "k_pre_Nm_rad", "zeta_s", "eta_s_rad_s",
                                "b_vis_Nms_rad", "offset_out_Nm"),
          DrivingForm.LINK: ("K_in_Nm_rad", "g_out", "tau_fc_Nm", "k_pre_Nm_rad", "zeta_s", "eta_s_rad_s", "b_vis_Nms_rad",
                             "offset_in_Nm", "dahl_exp", "d_in_Nms_rad"),
          DrivingForm.ANGLES: ("K_c_Nm_rad", "tau_fc_Nm", "k_pre_Nm_rad", "zeta_s", "eta_s_rad_s", "b_vis_Nms_rad",
                               "offset_in_Nm", "offset_out_Nm")}


#: forms whose unit is driven by q_in and tau_out and predicts tau_in
INPUT_PREDICTED = (DrivingForm.OUTPUT_HELD, DrivingForm.LINK)


def param_names(form: DrivingForm) -> tuple[str, ...]:
    """Names of the form's parameters, in the order of the fitted vector."""
    return PARAM_NAMES[form]


def param_vector(form: DrivingForm, params: dict[str, float]) -> np.ndarray:
    """The named parameters as the fitted vector (order of :func:`param_names`)."""
    return np.array([params[n] for n in PARAM_NAMES[form]])
