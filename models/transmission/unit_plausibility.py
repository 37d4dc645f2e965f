"""Plausible ranges of the torsional unit's fitted parameters for a cable transmission
(:mod:`capstan.models.transmission.stick_slip`, fitted by the closure's dynamic baseline).

A parameter outside its range is reported with the reason, never silently accepted: as
implausible when it lies outside even with its uncertainty (:func:`split_by_uncertainty`), else
as a warning that it is weakly determined.
"""

from __future__ import annotations

import numpy as np

#: the elastic path's damping as a time constant d_in / K_in beyond this is implausible [s]
D_IN_TAU_MAX_S = 0.1


def plausibility(params: dict[str, float], target_Nm: np.ndarray, v95_rad_s: float) -> dict[str, str]:
    """``{name: reason}`` of parameters outside their plausible range for a cable transmission."""
    span = float(np.ptp(target_Nm)) if target_Nm.size else 0.0
    out: dict[str, str] = {}
    zs = params.get("zeta_s", 1.0)
    if zs > 3.0:
        out["zeta_s"] = f"{zs:.3g} > 3: a stiction peak three times the sliding friction"
    tfc = params.get("tau_fc_Nm", 0.0)
    if span > 0.0 and tfc > span:
        out["tau_fc_Nm"] = f"{tfc:.3g} Nm exceeds the whole span of the target ({span:.3g} Nm)"
    eta = params.get("eta_s_rad_s", v95_rad_s)
    if eta > 10.0 * v95_rad_s and zs - 1.0 > 1e-3:    # (with zeta_s = 1, eta_s has no effect)
        out["eta_s_rad_s"] = f"{eta:.3g} rad/s is beyond 10x the run's 95th-percentile speed ({v95_rad_s:.3g} rad/s)"
    bv = params.get("b_vis_Nms_rad", 0.0)
    if span > 0.0 and bv * v95_rad_s > span:
        out["b_vis_Nms_rad"] = f"viscous torque at the 95th-percentile speed ({bv * v95_rad_s:.3g} Nm) exceeds the target span"
    d_in, K_in = params.get("d_in_Nms_rad", 0.0), params.get("K_in_Nm_rad", 0.0)
    if d_in > 0.0 and K_in > 0.0 and d_in / K_in > D_IN_TAU_MAX_S:
        out["d_in_Nms_rad"] = (f"time constant d_in / K_in = {1e3 * d_in / K_in:.3g} ms of the elastic path exceeds "
                               f"{1e3 * D_IN_TAU_MAX_S:.0f} ms")
    for k in ("K_c_Nm_rad", "K_in_Nm_rad", "k_out_Nm_rad"):
        if k in params and not 1e-3 <= params[k] <= 1e6:
            out[k] = f"{params[k]:.3g} Nm/rad outside [1e-3, 1e6]"
    return out


#: half-width of the interval a value must leave the plausible range by, in standard errors (95 %)
Z_95 = 1.96


def split_by_uncertainty(implausible: dict[str, str], params: dict[str, float], stderr: dict[str, float],
                         target_Nm: np.ndarray, v95_rad_s: float) -> tuple[dict[str, str], list[str]]:
    """``(established, weak)``: the entries of ``implausible`` (from :func:`plausibility`) whose
    parameter is outside its range even moved by :data:`Z_95` standard errors either way, and
    warnings for the others — a value whose own 95 % interval reaches the plausible range is
    weakly determined, not evidence of an implausible transmission (e.g. a stiction peak
    ζ_s 3.5 ± 1.7 that acts only below a few mrad/s)."""
    established: dict[str, str] = {}
    weak: list[str] = []
    for name, reason in implausible.items():
        se = float(stderr.get(name, 0.0))
        inside = se > 0.0 and any(
            name not in plausibility({**params, name: params[name] + sign * Z_95 * se}, target_Nm, v95_rad_s)
            for sign in (-1.0, 1.0))
        if inside:
            weak.append(f"{name}: {reason}, but {params[name]:.3g} +- {se:.2g} reaches the plausible range within "
                        f"{Z_95} standard errors: weakly determined, not established")
        else:
            established[name] = reason
    return established, weak
