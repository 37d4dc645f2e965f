"""The identify and tune steps: the identification runs through the daemon, the fits and the
gains from the identification library (:mod:`capstan.models.rig_id`,
:mod:`capstan.controller.law.tuning`).

Two runs, as the paper identified its rig: the link **held** (clamped near hanging; a
multisine on the motor: K_c, J_m, b_m, the I/O delay) and the link **free** (a slow angle
sweep plus a multisine in closed loop on the motor angle: m g l, J_l, the friction). Both
move within the START limits; the library's own ``within_limits`` is checked every cycle on
top of the bring-up's (:class:`capstan.tools.rig.step_run.ProfileController`).
"""

from __future__ import annotations

import importlib
import logging
from dataclasses import dataclass
from typing import Any, Callable, Mapping

from capstan.tools.rig.start_config import BringupStop, RigStart
from capstan.tools.rig.step_run import StepData, run_profile

log = logging.getLogger("capstan.rig")


def library_missing() -> str:
    """"" if the identification and tuning library is importable, else what is missing."""
    missing = []
    for mod, names in (("capstan.models.rig_id", ("held_excitation", "free_excitation", "identify_rig",
                                                   "RigRun", "RigGeometry", "ExcitationLimits")),
                       ("capstan.controller.law.tuning", ("tune_controller",))):
        try:
            m = importlib.import_module(mod)
        except ImportError:
            missing.append(mod)
            continue
        missing += [f"{mod}.{n}" for n in names if not hasattr(m, n)]
    return ", ".join(missing)


@dataclass
class ExcitationProfile:
    """A library excitation as a bring-up profile (its limit check raises a stop)."""

    excitation: Any
    step: str = "identify"

    def torque_Nm(self, t_s: float, r: Any) -> float:
        q_m, dq_m = float(r["q_m_rad"]), float(r["dq_m_rad_s"])
        why = self.excitation.within_limits(q_m, dq_m)
        if why:
            raise BringupStop(self.step, f"excitation left its limits: {why}")
        return float(self.excitation.torque_Nm(t_s, q_m, dq_m))

    def done(self, t_s: float) -> bool:
        return t_s >= float(self.excitation.duration_s)


def rig_run(data: StepData, start: RigStart, lc_override: Mapping[str, Any] | None = None) -> Any:
    """The library's run object of one logged move (the cycle records as columns)."""
    from capstan.models.rig_id import RigRun
    cols = {name: data.col(name) for name in data.records.dtype.names}
    cols["t_s"] = data.t_s
    cols["tau_m_cmd_Nm"] = data.col("tau_m_raw_Nm")
    return RigRun.from_arrays(cols, start.drawing.r_in_m, start.drawing.r_out_m, source=str(data.log_path))


def identify(start: RigStart, overrides: Mapping[str, Mapping[str, Any]],
             hold_link: Callable[[bool], None]) -> tuple[Any, list[StepData], dict[str, Any]]:
    """Run the held and the free excitation and fit the rig.

    :param overrides: device keys the check and calibration corrected.
    :param hold_link: called with True before the held run (clamp the link) and False after.
    :raises BringupStop: on a limit or a device fault during a run, or a fit that fails.
    """
    from capstan.models.common.errors import CapstanError
    from capstan.models.rig_id import ExcitationLimits, RigGeometry, free_excitation, held_excitation, identify_rig
    L = start.limits
    lim = ExcitationLimits(tau_max_Nm=L.tau_max_Nm, dq_max_rad_s=L.dq_m_max_rad_s, q_max_rad=L.q_m_range_rad * 0.8)
    runs: list[StepData] = []
    hold_link(True)
    try:
        held = held_excitation(lim)
        runs.append(run_profile(start, "identify", "identify_held", ExcitationProfile(held),
                                float(held.duration_s) + 5.0, overrides))
    finally:
        hold_link(False)
    free = free_excitation(lim)
    runs.append(run_profile(start, "identify", "identify_free", ExcitationProfile(free),
                            float(free.duration_s) + 5.0, overrides))
    d = start.drawing
    try:
        ident = identify_rig(rig_run(runs[0], start), rig_run(runs[1], start),
                             RigGeometry(r_in_m=d.r_in_m, r_out_m=d.r_out_m, theta_rad=d.theta_rad))
    except CapstanError as exc:
        raise BringupStop("identify", f"the fit failed: {type(exc).__name__}: {exc}") from None
    return ident, runs, {"held": held.describe(), "free": free.describe()}


def tune(ident: Any, base_controller: Mapping[str, Any]) -> Any:
    """Gains for the identified plant.

    :raises BringupStop: if no gain set meets the margins on the identified plant.
    """
    from capstan.controller.law.tuning import tune_controller
    from capstan.models.common.errors import CapstanError
    try:
        return tune_controller(ident.plant_for_tuning(), dict(base_controller))
    except CapstanError as exc:
        raise BringupStop("tune", f"no gain set meets the margins on the identified plant: {exc}") from None
