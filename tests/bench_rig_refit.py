"""Refit a bring-up's identify and tune steps from its two logged runs, optionally with one
identified value changed (which input keeps the tuning from passing?)::

    python tests/bench_rig_refit.py HELD.mcap FREE.mcap [--delay N] [--jm-stderr S]

Prints the identification and the tuning's verdict (docs/results/bring-up.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import time

from capstan.controller.log.reader import read_log
from capstan.models.common.config_tools import load_yaml
from capstan.models.common.errors import CapstanError
from capstan.models.rig_id import RigGeometry, identify_rig
from capstan.tools.offline.shipped import config_path
from capstan.tools.rig.identify_step import rig_run, tune
from capstan.tools.rig.start_config import RigStart
from capstan.tools.rig.step_run import StepData


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("held")
    ap.add_argument("free")
    ap.add_argument("--start", default=str(config_path("rig_start.yaml")))
    ap.add_argument("--delay", type=int, default=None, help="replace the identified I/O delay [cycles]")
    ap.add_argument("--jm-stderr", type=float, default=None, help="replace J_m's standard error [kg m^2]")
    a = ap.parse_args()
    st = RigStart.load(a.start)
    runs = []
    for p in (a.held, a.free):
        d = read_log(p)
        runs.append(StepData(p, d.records[d.records["phase"] == 1], p))
    t0 = time.monotonic()
    d = st.drawing
    ident = identify_rig(rig_run(runs[0], st), rig_run(runs[1], st), RigGeometry(d.r_in_m, d.r_out_m, d.theta_rad))
    if a.delay is not None:
        ident = dataclasses.replace(ident, io_delay_cycles=a.delay)
    if a.jm_stderr is not None:
        ident = dataclasses.replace(ident, J_m=dataclasses.replace(ident.J_m, stderr=a.jm_stderr))
    print({k: (v["value"], v["stderr"]) for k, v in ident.to_dict().items() if isinstance(v, dict) and "value" in v},
          "io_delay_cycles", ident.io_delay_cycles)
    try:
        res = tune(ident, load_yaml(config_path("rig.yaml"))["controller"])
        print("tuned: factor", res.factor, res.report["stability"])
    except CapstanError as exc:
        print("not tuned:", exc)
    print(f"{time.monotonic() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
