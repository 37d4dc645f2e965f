"""Paper Fig. 13 on the simulated rig: the interaction experiment of :mod:`capstan.tools.experiments.interaction`
(human arm impedance backdriving the gravity-compensated link), every controller and both
feedforward placements, as a box plot of ``|tau_h|`` per condition and controller.

The conditions, controllers, plant and lock-step loop are those of :mod:`capstan.tools.experiments.interaction`;
this module only keeps the ``tau_h`` series (the box plot needs the samples, not only the means).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from capstan.controller.law.config import ControllerConfig  # noqa: E402
from capstan.controller.law.core import Controller  # noqa: E402
from capstan.models.plant.config import plant_from_mapping  # noqa: E402
from capstan.models.plant.rig import SensorNoise, SimulatedRig  # noqa: E402
from capstan.tools.experiments.interaction import CONDITIONS, LockStep, controller_mapping, plant_mapping  # noqa: E402
from capstan.tools.experiments.interaction import PAPER_CONTROLLERS as CONTROLLERS  # noqa: E402  (the paper's four)
from capstan.tools.experiments.paper.common import Settings, row, save  # noqa: E402

#: paper Fig. 13(d), left to right: uncompensated, then (slow: PID+ff, LDO+ff), (fast: PID+ff, LDO+ff) [Nm]
PAPER_FIG13 = {("any", "pid_gravity_only"): 3.370, ("slow_high_bending", "pid_ff"): 0.642,
               ("slow_high_bending", "ldo_ff"): 0.498, ("fast_low_bending", "pid_ff"): 1.334,
               ("fast_low_bending", "ldo_ff"): 0.663}
SETTLE_S = 0.5


def interaction_series(cond_name: str, loop: str, feedforward: bool, placement: str, duration_s: float,
                       seed: int) -> tuple[np.ndarray, bool]:
    """``tau_h`` series [Nm] (after the settle time) of one run, and whether the safety stage latched.

    :raises ConfigError: on a bad controller mapping. :raises OperatingRangeError: on cable slack.
    """
    cond = CONDITIONS[cond_name]
    rig = SimulatedRig(plant_from_mapping(plant_mapping(cond)), SensorNoise(), seed=seed)
    ctl = Controller(ControllerConfig.from_mapping(controller_mapping(cond, loop, feedforward, placement)))
    ls = LockStep(ctl, rig)
    n = int(round(duration_s / 1e-3))
    tau_h = np.zeros(n)
    model = rig.model
    k = 0
    for k in range(n):
        th = cond.human.torque_Nm(rig.t_s, model.q_out_rad, model.dq_out_rad_s)
        tau_h[k] = th
        ls.cycle(th)
        if ctl.faulted:
            break
    return tau_h[int(round(SETTLE_S / 1e-3)): k + 1], bool(ctl.faulted)


def fig13(settings: Settings, out_dir: Path) -> dict[str, Any]:
    """All controllers x conditions (both placements for the feedforward ones), box plot of |tau_h|."""
    t0 = time.perf_counter()
    means: dict[str, dict[str, float]] = {}
    faulted: dict[str, dict[str, bool]] = {}
    series: dict[str, dict[str, np.ndarray]] = {}
    for cname in CONDITIONS:
        means[cname], faulted[cname], series[cname] = {}, {}, {}
        for name, (loop, ff) in CONTROLLERS.items():
            for placement in (("reference", "motor") if ff else ("reference",)):
                key = name if not ff or placement == "reference" else f"{name}@{placement}"
                s, f = interaction_series(cname, loop, ff, placement, settings.interaction_s, settings.seed)
                series[cname][key] = np.abs(s)
                means[cname][key] = float(np.mean(np.abs(s)))
                faulted[cname][key] = f
    fig, axes = plt.subplots(1, len(CONDITIONS), figsize=(6.5 * len(CONDITIONS), 4.2), sharey=True)
    for ax, cname in zip(np.atleast_1d(axes), CONDITIONS):
        keys = list(series[cname])
        ax.boxplot([series[cname][k] for k in keys], showfliers=False)
        ax.set_xticks(range(1, len(keys) + 1), [k.replace("@", "\n@") for k in keys], fontsize=7)
        ax.set(ylabel="|τ_h| [Nm]", title=f"{cname} (θ={CONDITIONS[cname].theta_rad} rad)")
    png = save(fig, out_dir, "fig13_interaction.png")
    rows = []
    for cname in CONDITIONS:
        rows.append(row(f"{cname}: uncompensated (PID, gravity only)", PAPER_FIG13[("any", "pid_gravity_only")],
                        means[cname]["pid_gravity_only"], "Nm",
                        "our arm model and motion differ from the paper's human; the ratio to the compensated "
                        "cases is the comparable number"))
        for key in means[cname]:
            if key == "pid_gravity_only":
                continue
            paper = PAPER_FIG13.get((cname, key))
            note = "safety stage latched (run stopped)" if faulted[cname][key] else ""
            if paper is not None and not note:
                base = means[cname]["pid_gravity_only"]
                note = (f"reduction from uncompensated {base / means[cname][key]:.1f}x here vs "
                        f"{PAPER_FIG13[('any', 'pid_gravity_only')] / paper:.1f}x in the paper; our arm model, "
                        "motion and plant differ from the paper's human and rig")
            if key.endswith("@motor"):
                note = note or "eq (28) as printed: feedforward added to tau_m, where the observer/PD fight it"
            elif key == "ldo":
                note = note or "no feedforward"
            rows.append(row(f"{cname}: {key}", paper, means[cname][key], "Nm", note))
    return {"title": "Fig. 13: interaction torque |tau_h| per controller and condition", "rows": rows,
            "figures": [png], "data": {"mean_abs_tau_h_Nm": means, "faulted": faulted,
                                       "duration_s": settings.interaction_s},
            "wall_s": time.perf_counter() - t0}
