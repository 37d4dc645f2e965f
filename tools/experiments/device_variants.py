"""The shipped controller in lock-step on the interaction conditions, per simulated-device variant:
what realistic devices (:mod:`capstan.models.plant.sensors`) cost against the ideal ones.

``python -m capstan.tools.experiments.device_variants [--duration 18] [--json]`` prints, per
condition and variant, mean |tau_h|, the command change rms, rate-limit hits, the peak command
and the lost/jittered commands (numbers for docs/results/realistic-devices.md).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from typing import Any, Sequence

from capstan.models.plant.command_path import CommandTiming
from capstan.models.plant.drive_feedback import DriveFeedbackSettings, VelocitySource
from capstan.models.plant.sensors import DeviceSettings
from capstan.tools.experiments.interaction import CONDITIONS, controller_mapping, run_interaction

_R = DeviceSettings.realistic()
_I = DeviceSettings.ideal()

#: variant name -> device settings
VARIANTS: dict[str, DeviceSettings] = {
    "ideal": _I,
    "realistic": _R,
    "realistic, velocity encoder_difference": replace(_R, drive=DriveFeedbackSettings(VelocitySource.ENCODER_DIFFERENCE)),
    "realistic, velocity whole_rpm": replace(_R, drive=DriveFeedbackSettings(VelocitySource.WHOLE_RPM)),
    "realistic, velocity exact": replace(_R, drive=DriveFeedbackSettings(VelocitySource.EXACT)),
    "ideal + vendor velocity only": replace(_I, drive=DriveFeedbackSettings()),
    "ideal + command jitter/loss only": replace(_I, command=CommandTiming()),
    "ideal + load-cell and IMU errors only": replace(_I, load_cells=_R.load_cells, imu=_R.imu),
}

KEYS = ("mean_abs_tau_h_Nm", "cmd_change_rms_Nm", "rate_limit_hits", "max_abs_cmd_Nm", "max_abs_tau_m_raw_Nm",
        "commands_lost", "commands_jittered", "faulted")


def run(duration_s: float, delay_cycles: int = 2, seed: int = 0,
        conditions: Sequence[str] = tuple(CONDITIONS)) -> dict[str, Any]:
    """``{condition: {variant: metrics}}`` for the shipped controller with feedforward."""
    out: dict[str, Any] = {}
    for cname in conditions:
        cond = CONDITIONS[cname]
        mapping = controller_mapping(cond, "shipped", True)
        out[cname] = {name: {k: v for k, v in run_interaction(cond, mapping, duration_s, seed,
                                                                delay_cycles=delay_cycles, devices=dev).items()
                             if k in KEYS}
                      for name, dev in VARIANTS.items()}
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Print the table (or JSON)."""
    p = argparse.ArgumentParser(prog="python -m capstan.tools.experiments.device_variants", description=__doc__)
    p.add_argument("--duration", type=float, default=18.0, help="simulated seconds per run")
    p.add_argument("--delay-cycles", type=int, default=2, help="nominal command delay [cycles]")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true")
    a = p.parse_args(argv)
    res = run(a.duration, a.delay_cycles, a.seed)
    if a.json:
        print(json.dumps(res, indent=1))
        return 0
    for cname, rows in res.items():
        print(f"\n{cname} ({a.duration:.0f} s, shipped_ff, nominal delay {a.delay_cycles} cycles, seed {a.seed})")
        print("| devices | mean abs tau_h [Nm] | cmd change rms [Nm/cycle] | rate-limit hits | peak cmd [Nm] "
              "| peak raw demand [Nm] | lost / jittered cmds |")
        print("|---|---|---|---|---|---|---|")
        for name, m in rows.items():
            print(f"| {name} | {m['mean_abs_tau_h_Nm']:.3f} | {m['cmd_change_rms_Nm']:.3f} | "
                  f"{m['rate_limit_hits']:.0f} | {m['max_abs_cmd_Nm']:.1f} | {m['max_abs_tau_m_raw_Nm']:.1f} | "
                  f"{m['commands_lost']:.0f} / {m['commands_jittered']:.0f} |")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
