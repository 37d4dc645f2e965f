"""Gains for an identified rig (the bring-up's *tune* step), chosen with the loop model.

From a :class:`capstan.models.rig_id.identify.RigIdentification` and a base controller section
(START.yaml's, or the shipped ``config/controller.yaml``'s, whose gains were chosen for its own
``controller.plant``):

1. the plant values the controller needs are replaced by the identified ones:
   ``plant.{stiffness_Nm_rad, motor_inertia_kg_m2, motor_damping_Nms_rad, r_in_m, r_out_m}``,
   ``gravity.m_g_l_Nm``, ``feedforward.{mu, zeta_s, eta_s_rad_s, alpha_s_rad, b_vis_Nms_rad}``
   (mu such that the feedforward's own friction per Newton of pretension,
   :func:`capstan.controller.law.feedforward.friction_torque_per_N`, times the measured
   pretension gives the identified tau_fc on the base config's routing), and the start-up check's
   plant range ``stability.{stiffness_range_Nm_rad, inertia_tolerance, link_inertia_kg_m2,
   link_stiffness_Nm_rad, link_damping_Nms_rad, io_delay_cycles}`` from the identified values and
   their uncertainty (``k_sigma`` standard errors, at least ``min_tolerance``);
2. the base gains are carried to the identified plant by their physics: the inertia
   compensations in proportion to the inertia they compensate (J_m, J_l), the deflection damping
   in proportion to the motor-cable mode's critical damping ``sqrt(K_c J_m)``, the integral gain with
   the motor's damping rate ``B_m / J_m`` (never up: at rest it alone closes the loop on the
   motor-cable resonance, whose peak goes as 1 / damping); dimensionless gains (kp, band, output
   torque gains) as they are;
3. a transparency factor ``s`` on kp, the band gain, the output torque gain and both inertia
   compensations is searched (largest first, then bisection) for the largest value with which
   :func:`capstan.controller.law.stability.analyse` passes the same start-up rules the daemon
   applies (:func:`check_margins`: PM, GM, the faded gains and the grip points). The search
   screens candidates on the grid points that limited the base candidate (``analyse_point`` on
   those), and the chosen one is confirmed by the full analysis; a candidate the full analysis
   rejects is stepped down (x 0.9), or, when what fails is the loop at rest (the faded gains: the
   integral alone), its integral gain is halved (down to a tenth).
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

from capstan.controller.law.config import ControllerConfig
from capstan.controller.law.stability import (StabilityReport, analyse, analyse_point, feedforward_noise_slope,
                                              grip_points, plant_points)
from capstan.controller.law.tuning.plant_section import plant_controller, with_factor
from capstan.models.common.errors import ConfigError, ModelError
from capstan.models.rig_id.identify import RigIdentification

#: transparency factors tried first (largest first) before the bisection
FACTORS = (1.5, 1.0, 0.7, 0.5, 0.3)
#: grid points (by smallest phase-margin excess) the screening evaluates
N_SCREEN = 8


@dataclass
class TuningResult:
    """The tuned controller section and how it was found.

    :ivar controller: the complete ``controller`` mapping (``ControllerConfig.to_mapping`` form).
    :ivar report: factor chosen, margins, the candidates tried, provenance.
    """

    controller: dict[str, Any]
    factor: float
    stability: StabilityReport
    report: dict[str, Any] = field(default_factory=dict)


def _screen(cfg: ControllerConfig, idx: list[int], grip_idx: list[int]) -> float:
    """Smallest margin excess (PM - required [deg], GM - required [dB] x 3) on the screening points
    (-inf if one is unstable)."""
    st = cfg.stability
    slope = feedforward_noise_slope(cfg, st.gyro_noise_rad_s)
    pts = plant_points(cfg, st)
    worst = math.inf
    for i in idx:
        r = analyse_point(cfg, st, pts[i], slope)
        if not r.stable:
            return -math.inf
        worst = min(worst, r.phase_margin_deg - st.min_phase_margin_deg, 3.0 * (r.gain_margin_dB - st.min_gain_margin_dB))
    if grip_idx:
        gp = grip_points(cfg, slope)
        for i in grip_idx:
            r = gp[i]
            if not r.stable:
                return -math.inf
            worst = min(worst, r.phase_margin_deg - st.min_grip_phase_margin_deg)
    return worst


def _limiting(rep: StabilityReport) -> tuple[list[int], list[int]]:
    """Indices of the grid and grip points with the smallest margin excess."""
    def excess(p: Any, pm_req: float, gm_req: float) -> float:
        return -math.inf if not p.stable else min(p.phase_margin_deg - pm_req, 3.0 * (p.gain_margin_dB - gm_req))

    pm, gm = rep.min_phase_margin_deg, rep.min_gain_margin_dB
    idx = sorted(range(len(rep.points)), key=lambda i: excess(rep.points[i], pm, gm))[:N_SCREEN]
    gidx = sorted(range(len(rep.grip)), key=lambda i: excess(rep.grip[i], rep.min_grip_phase_margin_deg, -math.inf))[:2]
    return idx, gidx


def tune_controller(ident: RigIdentification, base: Mapping[str, Any], k_sigma: float = 3.0,
                    min_tolerance: float = 0.15, bisect_steps: int = 3) -> TuningResult:
    """The controller section for the identified rig with the most transparent gains that pass the
    start-up check (module docstring).

    :param base: the base ``controller`` section (a mapping as in the YAML).
    :raises ConfigError: if the base section is invalid.
    :raises ModelError: if no factor down to the smallest tried passes (write no config then).
    """
    m0 = plant_controller(ident, base, k_sigma, min_tolerance)
    tried: list[dict[str, Any]] = []

    def full(s: float) -> StabilityReport:
        rep = analyse(ControllerConfig.from_mapping(with_factor(m0, s)))
        tried.append({"factor": s, "ki_1_s": m0["feedback"]["ki_1_s"], "check": "full", "ok": rep.ok, "phase_margin_deg": rep.worst_phase_margin_deg,
                      "gain_margin_dB": rep.worst_gain_margin_dB, "grip_ok": rep.grip_ok})
        return rep

    first = full(1.0)
    idx, gidx = _limiting(first)

    def screened(s: float) -> bool:
        try:
            cfg = ControllerConfig.from_mapping(with_factor(m0, s))
        except ConfigError:
            return False
        ex = _screen(cfg, idx, gidx)
        tried.append({"factor": s, "check": "screen", "ok": ex >= 0.0, "margin_excess": ex})
        return ex >= 0.0

    good, bad = (1.0, None) if first.ok else (None, 1.0)
    for s in FACTORS:
        if (good is not None and s <= good) or (bad is not None and s >= bad):
            continue
        if screened(s):
            good = s
            break
        bad = s
    if good is None:
        raise ModelError(f"no transparency factor down to {FACTORS[-1]:g} passes the start-up check on the identified "
                         f"plant (at x1: {first.summary()})")
    if bad is not None:
        for _ in range(bisect_steps):
            mid = 0.5 * (good + bad)
            if screened(mid):
                good = mid
            else:
                bad = mid
    rep = first if good == 1.0 else full(good)
    ki_floor = 0.1 * m0["feedback"]["ki_1_s"]
    while not rep.ok:
        if rep.faded and not all(f[3] for f in rep.faded) and m0["feedback"]["ki_1_s"] > ki_floor:
            m0["feedback"]["ki_1_s"] *= 0.5      # the loop at rest (kp, b faded out) is the integral's
        else:
            good *= 0.9
        if good < FACTORS[-1] * 0.9:
            raise ModelError(f"no transparency factor passes the full start-up check: {rep.summary()}")
        rep = full(good)
    ctrl = with_factor(m0, good)
    ControllerConfig.from_mapping(ctrl)      # valid as written
    prov = {"tuned_at": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "identification": ident.provenance, "k_sigma": k_sigma, "min_tolerance": min_tolerance,
            "base_plant": dict(ControllerConfig.from_mapping(base).to_mapping()["plant"])}
    summary = {"ok": rep.ok, "summary": rep.summary(), "worst_phase_margin_deg": rep.worst_phase_margin_deg,
               "worst_gain_margin_dB": rep.worst_gain_margin_dB, "grip_ok": rep.grip_ok}
    return TuningResult(ctrl, good, rep, {"factor": good, "stability": summary, "tried": tried, "provenance": prov})
