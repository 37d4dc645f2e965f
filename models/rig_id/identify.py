"""Identify a rig's plant from its two identification runs (link held, link free): what the
controller needs, each value with its uncertainty and how it was found.

Where both runs determine a parameter (K_c, J_m, b_m: the free run's sweeps also deflect the
cables and accelerate the motor), the two estimates are combined by their inverse variances and
half their difference is added in quadrature as a systematic term: two runs of different
motion that disagree by more than their statistics say show a model error the sandwich
covariance of one run cannot see. Every value fitted from measured torques also carries the
torques' calibrated scale uncertainty (:data:`TORQUE_SCALE_REL_STDERR` unless given).

Friction: the reduced model (paper eq 21) on the free run's transmission loss
(:mod:`capstan.models.rig_id.friction`); its magnitude scales with the measured pretension and
the bending the drawings give (:class:`RigGeometry`).
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass, field, replace
from typing import Any

from capstan.models.common.errors import ConfigError, ModelError
from capstan.models.rig_id.excitation import require_positive
from capstan.models.rig_id.fits import Estimate, LinkFit, MotorFit, fit_link, fit_motor, fit_stiffness
from capstan.models.rig_id.friction import fit_friction
from capstan.models.rig_id.runs import RigRun


@dataclass(frozen=True)
class RigGeometry:
    """What the drawings give (SI): pulley radii and the sheath's total bending.

    :raises ConfigError: on a non-positive value.
    """

    r_in_m: float = 0.04
    r_out_m: float = 0.04
    theta_rad: float = 3.0

    def __post_init__(self) -> None:
        require_positive(self, ("r_in_m", "r_out_m", "theta_rad"), "geometry")


#: relative 1-sigma uncertainty of the load cells' (and the drive's) torque scale after calibration [-]:
#: every value fitted from those torques (K_c, J_m, b_m, m g l, J_l, b_l, tau_fc) scales with it, and no
#: run can see it (the simulated rig's realistic cells carry +-0.3 % per channel); pass the calibration's own
TORQUE_SCALE_REL_STDERR = 0.005


def combine(a: Estimate, b: Estimate, method: str) -> Estimate:
    """Inverse-variance mean of two estimates of one quantity, half their difference added in
    quadrature to its standard error (a systematic term when the runs disagree)."""
    wa, wb = 1.0 / max(a.stderr, 1e-300) ** 2, 1.0 / max(b.stderr, 1e-300) ** 2
    v = (wa * a.value + wb * b.value) / (wa + wb)
    se = math.hypot(1.0 / math.sqrt(wa + wb), 0.5 * (a.value - b.value))
    return Estimate(v, se, a.unit, f"{method}: held {a.value:.4g} +- {a.stderr:.2g}, free {b.value:.4g} +- {b.stderr:.2g}")


@dataclass
class RigIdentification:
    """The identified plant (every value an :class:`Estimate`, SI).

    :ivar friction: reduced-model friction (``tau_fc``, ``zeta_s``, ``eta_s_rad_s``, ``alpha_s_rad``,
        ``b_vis``, ``mu_theta``, ``mu``, ``T0`` and the transmission ratio ``ratio``).
    :ivar io_delay_cycles: the command's delay that fits the motor best [cycles].
    """

    K_c: Estimate
    J_m: Estimate
    b_m: Estimate
    m_g_l: Estimate
    J_l: Estimate
    b_l: Estimate
    friction: dict[str, Estimate]
    io_delay_cycles: int
    geometry: RigGeometry
    provenance: dict[str, Any] = field(default_factory=dict)

    def plant_for_tuning(self) -> "RigIdentification":
        """What :func:`capstan.controller.law.tuning.tune_controller` takes (this identification)."""
        return self

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping (JSON/YAML-safe): each estimate as {value, stderr, unit, method}."""
        out: dict[str, Any] = {k: getattr(self, k).to_dict() for k in ("K_c", "J_m", "b_m", "m_g_l", "J_l", "b_l")}
        out["friction"] = {k: e.to_dict() for k, e in self.friction.items()}
        out["io_delay_cycles"] = self.io_delay_cycles
        g = self.geometry
        out["geometry"] = {"r_in_m": g.r_in_m, "r_out_m": g.r_out_m, "theta_rad": g.theta_rad}
        out["provenance"] = dict(self.provenance)
        return out


def with_scale(e: Estimate, rel: float) -> Estimate:
    """``e`` with a relative scale uncertainty ``rel`` added in quadrature."""
    return replace(e, stderr=math.hypot(e.stderr, rel * e.value))


def identify_rig(held: RigRun, free: RigRun, geometry: RigGeometry | None = None,
                 provenance: dict[str, Any] | None = None,
                 torque_scale_rel_stderr: float = TORQUE_SCALE_REL_STDERR) -> RigIdentification:
    """Fit the rig's plant from a link-held and a link-free run.

    :param provenance: what to record with the result (runs' logs, dates); the fit adds its own.
    :param torque_scale_rel_stderr: the torque measurements' relative scale uncertainty (the
        calibration's), added to every value fitted from them.
    :raises ModelError: if a run carries no information for a parameter (the message names it).
    :raises ConfigError: on pulley radii that disagree with the runs'.
    """
    geo = geometry if geometry is not None else RigGeometry(held.r_in_m, held.r_out_m)
    for run in (held, free):
        if not (math.isclose(run.r_in_m, geo.r_in_m) and math.isclose(run.r_out_m, geo.r_out_m)):
            raise ConfigError("geometry", f"pulley radii {geo.r_in_m:g} / {geo.r_out_m:g} m differ from the run "
                              f"{run.source}'s {run.r_in_m:g} / {run.r_out_m:g} m")
    k_h, m_h = fit_stiffness(held), fit_motor(held)
    try:         # the free run's sweeps deflect the cables and move the motor too: a second estimate
        k_f: Estimate | None = fit_stiffness(free)
        m_f: MotorFit | None = fit_motor(free)
    except ModelError:
        k_f = m_f = None
    link: LinkFit = fit_link(free)
    if not link.m_g_l.value > 0.0:
        raise ModelError(f"free run: m g l fitted as {link.m_g_l.value:.3f} Nm (<= 0); is the link free and the IMU sign right?")
    prov = {"fitted_at": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "held_run": held.source, "free_run": free.source,
            "held_cycles": len(held), "free_cycles": len(free),
            "tau_m_source": "drive's reported torque" if held.tau_m_is_measured else "torque command",
            "motor_rmse_Nm": {"held": m_h.rmse_Nm, "free": m_f.rmse_Nm if m_f else None}, "link_rmse_Nm": link.rmse_Nm}
    prov.update(provenance or {})
    rel = float(torque_scale_rel_stderr)
    prov["torque_scale_rel_stderr"] = rel
    fr = fit_friction(free, geo.theta_rad)
    fr.update({k: with_scale(fr[k], rel) for k in ("tau_fc", "b_vis", "mu_theta", "mu")})
    return RigIdentification(
        K_c=with_scale(combine(k_h, k_f, "K_c from both runs") if k_f else k_h, rel),
        J_m=with_scale(combine(m_h.J_m, m_f.J_m, "J_m from both runs") if m_f else m_h.J_m, rel),
        b_m=with_scale(combine(m_h.b_m, m_f.b_m, "b_m from both runs") if m_f else m_h.b_m, rel),
        m_g_l=with_scale(link.m_g_l, rel), J_l=with_scale(link.J_l, rel), b_l=with_scale(link.b_l, rel),
        friction=fr,
        io_delay_cycles=max(m_h.delay_cycles, m_f.delay_cycles if m_f else 0),
        geometry=geo, provenance=prov)
