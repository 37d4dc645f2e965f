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
   in proportion to the motor-cable mode's critical damping ``sqrt(K_c J_m)``; dimensionless gains
   (kp, band, output torque gains) as they are;
3. a transparency factor ``s`` on kp, the band gain, the output torque gain and both inertia
   compensations is searched (largest first, then bisection) for the largest value with which
   :func:`capstan.controller.law.stability.analyse` passes the same start-up rules the daemon
   applies (:func:`check_margins`: PM, GM, the faded gains and the grip points). The search
   screens candidates on the grid points that limited the base candidate (``analyse_point`` on
   those), and the chosen one is confirmed by the full analysis; a candidate the full analysis
   rejects is stepped down.
"""

from __future__ import annotations

import copy
import datetime as _dt
import math
from dataclasses import dataclass, field, replace
from typing import Any, Mapping

from scipy.optimize import brentq

from capstan.controller.law.config import ControllerConfig
from capstan.controller.law.feedforward import friction_torque_per_N
from capstan.controller.law.stability import (StabilityReport, analyse, analyse_point, feedforward_noise_slope,
                                              grip_points, plant_points)
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


def solve_mu(cfg: ControllerConfig, tau_fc_Nm: float, T0_N: float) -> float:
    """The ``feedforward.mu`` with which the feedforward gives ``tau_fc_Nm`` at pretension ``T0_N``
    on ``cfg``'s routing (the field depends on mu, so a root in (1e-5, 1)).

    :raises ModelError: if no mu in that range gives it.
    """
    def f(mu: float) -> float:
        return friction_torque_per_N(replace(cfg.feedforward, mu=mu), cfg.plant.r_out_m) * T0_N - tau_fc_Nm

    lo, hi = 1e-5, 1.0
    if not (tau_fc_Nm > 0.0 and f(lo) < 0.0 < f(hi)):
        raise ModelError(f"no friction coefficient in ({lo:g}, {hi:g}) gives tau_fc {tau_fc_Nm:.3f} Nm at "
                         f"{T0_N:.1f} N pretension on this routing")
    return float(brentq(f, lo, hi, xtol=1e-7))


def plant_controller(ident: RigIdentification, base: Mapping[str, Any], k_sigma: float = 3.0,
                     min_tolerance: float = 0.15) -> dict[str, Any]:
    """The base controller section with the identified plant, its uncertainty range and the base
    gains carried over to it (steps 1-2 of the module docstring), before the transparency search.

    :raises ConfigError: if the base section is invalid.
    :raises ModelError: if the friction cannot be expressed as a mu on the base routing.
    """
    base_cfg = ControllerConfig.from_mapping(base)
    m = base_cfg.to_mapping()
    K, J = ident.K_c.value, ident.J_m.value
    K0, J0 = base_cfg.plant.stiffness_Nm_rad, base_cfg.plant.motor_inertia_kg_m2
    Jl0 = base_cfg.stability.link_inertia_kg_m2
    g = ident.geometry
    m["plant"].update(stiffness_Nm_rad=K, motor_inertia_kg_m2=J, motor_damping_Nms_rad=max(ident.b_m.value, 0.0),
                      r_in_m=g.r_in_m, r_out_m=g.r_out_m)
    m["gravity"]["m_g_l_Nm"] = ident.m_g_l.value
    tol_k = max(k_sigma * ident.K_c.rel_stderr, min_tolerance)
    tol_j = max(k_sigma * ident.J_m.rel_stderr, min_tolerance)
    st = m["stability"]
    st.update(stiffness_range_Nm_rad=[K * (1.0 - tol_k), K * (1.0 + tol_k)], inertia_tolerance=min(tol_j, 0.9),
              link_inertia_kg_m2=ident.J_l.value, link_stiffness_Nm_rad=ident.m_g_l.value,
              link_damping_Nms_rad=max(ident.b_l.value, 0.0),
              io_delay_cycles=max(int(st["io_delay_cycles"]), int(ident.io_delay_cycles)))
    fb = m["feedback"]
    fb["inertia_comp_kg_m2"] *= J / J0
    fb["link_inertia_comp_kg_m2"] *= ident.J_l.value / Jl0
    fb["deflection_damping_Nms_rad"] *= math.sqrt(K * J / (K0 * J0))
    m = _with_factor(m, 1.0)       # the inertia compensations below what the check admits
    fr = ident.friction
    ff = m["feedforward"]
    ff["mu"] = solve_mu(ControllerConfig.from_mapping(m), fr["tau_fc"].value, fr["T0"].value)
    ff["zeta_s"] = max(fr["zeta_s"].value, ff["zeta_c"])
    ff["eta_s_rad_s"] = fr["eta_s_rad_s"].value
    ff["alpha_s_rad"] = fr["alpha_s_rad"].value
    ff["b_vis_Nms_rad"] = max(fr["b_vis"].value, 0.0)
    return m


def _with_factor(m: Mapping[str, Any], s: float) -> dict[str, Any]:
    """``m`` with the transparency gains x ``s``, the inertia compensations capped below the
    smallest inertia the check admits (x 0.9)."""
    out = copy.deepcopy(dict(m))
    fb, st = out["feedback"], out["stability"]
    for k in ("kp", "band_gain", "output_torque_gain", "inertia_comp_kg_m2", "link_inertia_comp_kg_m2"):
        fb[k] = fb[k] * s
    tol = st["inertia_tolerance"]
    fb["inertia_comp_kg_m2"] = min(fb["inertia_comp_kg_m2"], 0.9 * out["plant"]["motor_inertia_kg_m2"] * (1.0 - tol))
    fb["link_inertia_comp_kg_m2"] = min(fb["link_inertia_comp_kg_m2"], 0.9 * st["link_inertia_kg_m2"] * (1.0 - tol))
    return out


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
        rep = analyse(ControllerConfig.from_mapping(_with_factor(m0, s)))
        tried.append({"factor": s, "check": "full", "ok": rep.ok, "phase_margin_deg": rep.worst_phase_margin_deg,
                      "gain_margin_dB": rep.worst_gain_margin_dB, "grip_ok": rep.grip_ok})
        return rep

    first = full(1.0)
    idx, gidx = _limiting(first)

    def screened(s: float) -> bool:
        try:
            cfg = ControllerConfig.from_mapping(_with_factor(m0, s))
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
    while not rep.ok:
        good *= 0.9
        if good < FACTORS[-1] * 0.9:
            raise ModelError(f"no transparency factor passes the full start-up check: {rep.summary()}")
        rep = full(good)
    ctrl = _with_factor(m0, good)
    ControllerConfig.from_mapping(ctrl)      # valid as written
    prov = {"tuned_at": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "identification": ident.provenance, "k_sigma": k_sigma, "min_tolerance": min_tolerance,
            "base_plant": dict(ControllerConfig.from_mapping(base).to_mapping()["plant"])}
    summary = {"ok": rep.ok, "summary": rep.summary(), "worst_phase_margin_deg": rep.worst_phase_margin_deg,
               "worst_gain_margin_dB": rep.worst_gain_margin_dB, "grip_ok": rep.grip_ok}
    return TuningResult(ctrl, good, rep, {"factor": good, "stability": summary, "tried": tried, "provenance": prov})
