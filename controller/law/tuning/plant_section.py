"""The identified plant in a controller section (steps 1-2 of :mod:`capstan.controller.law.tuning.search`):
the plant values, the start-up check's plant range from the identified uncertainty, the base
gains carried over by their physics, and ``feedforward.mu`` from the feedforward's own friction."""

from __future__ import annotations

import copy
import math
from dataclasses import replace
from typing import Any, Mapping

from scipy.optimize import brentq

from capstan.controller.law.config import ControllerConfig
from capstan.controller.law.feedforward import friction_torque_per_N
from capstan.models.common.errors import ModelError
from capstan.models.rig_id.identify import RigIdentification


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
    # at rest (kp, b faded out) the integral alone closes the loop on the motor-cable resonance, whose
    # peak |P| ~ 1 / (2 zeta) over omega x ki / omega: keep ki / (omega zeta) = 2 J ki / B_m as the base had it
    B0, B = base_cfg.plant.motor_damping_Nms_rad, max(ident.b_m.value, 0.0)
    if B0 > 0.0:
        fb["ki_1_s"] *= min(1.0, (B / J) / (B0 / J0))
    m = with_factor(m, 1.0)       # the inertia compensations below what the check admits
    fr = ident.friction
    ff = m["feedforward"]
    ff["mu"] = solve_mu(ControllerConfig.from_mapping(m), fr["tau_fc"].value, fr["T0"].value)
    ff["zeta_s"] = max(fr["zeta_s"].value, ff["zeta_c"])
    ff["eta_s_rad_s"] = fr["eta_s_rad_s"].value
    ff["alpha_s_rad"] = fr["alpha_s_rad"].value
    ff["b_vis_Nms_rad"] = max(fr["b_vis"].value, 0.0)
    return m


def with_factor(m: Mapping[str, Any], s: float) -> dict[str, Any]:
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
