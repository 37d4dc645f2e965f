"""The bring-up's last step, **verify**: the tuned loop itself runs on the rig for a short time,
before its config is written.

The daemon runs the tuned controller (the gains and plant values the tune step chose, the
device sections with the check's corrections and the calibration) against the same devices,
with the START limits as the loop's limits, for :data:`VERIFY_S`. At a rig a person moves the
link by hand meanwhile (the interactive command asks for it); on the simulated rig the link
hangs in the tuned gravity compensation. The step reports what a person feels and what the
motor gets:

* felt torque — the output cable torque ``r_out (T_up_out - T_lo_out)`` less the tuned gravity
  model, mean and 95th percentile of its magnitude [Nm] (what the hand holds besides the
  link's own inertia);
* command quality — the daemon's own statistics over the running cycles (command change per
  cycle rms, share of command power above 20 Hz, cycles at the rate clamp).

It refuses (no config written) when the tuned loop faults, or when it rings: most of the
command's power above 20 Hz *and* a command change per cycle above :data:`RINGING_CHANGE_Nm`
(the quiet shipped loop changes its command by ~3e-5 Nm per cycle at rest in HIL, a loop
ringing at its margin by ~1 Nm per cycle).
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from capstan.controller.runtime.config import DaemonConfig
from capstan.controller.runtime.daemon import Daemon
from capstan.controller.runtime.run_summary import Phase
from capstan.models.common.errors import CapstanError, ControlFaultError, DriverError
from capstan.tools.rig.start_config import BringupStop, RigStart
from capstan.tools.rig.step_run import loop_limits, repeat_after_host_stalls, stalled_host
from capstan.tools.rig.tuned import tuned_mapping

log = logging.getLogger("capstan.rig")

#: how long the tuned loop runs [s]
VERIFY_S = 5.0
#: a command share above 20 Hz at or above this ... [-]
RINGING_HF_SHARE = 0.8
#: ... together with a command change per cycle rms at or above this is ringing [Nm]
RINGING_CHANGE_Nm = 0.1


@dataclass
class VerifyResult:
    """What the verify run measured (see the module docstring)."""

    cycles: int
    felt_mean_Nm: float
    felt_p95_Nm: float
    command: dict[str, float] = field(default_factory=dict)
    log_path: str | None = None
    rings: bool = False

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def verify_mapping(start: RigStart, controller: Mapping[str, Any],
                   overrides: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """The daemon config of the verify run: the tuned config, logging under ``<log dir>/verify``,
    memory not locked, the START limits as the loop's limits."""
    m = tuned_mapping(start, controller, overrides, log_dir=str(start.log_dir / "verify"))
    L = start.limits
    m["realtime"] = {**m["realtime"], "lock_memory": False}
    m["loop"] = {**m["loop"], "limits": loop_limits(L)}
    ctl = dict(m["controller"])
    safety = dict(ctl.get("safety", {}))
    safety["tau_max_Nm"] = min(float(safety.get("tau_max_Nm", L.tau_max_Nm)), L.tau_max_Nm)
    ctl["safety"] = safety
    m["controller"] = ctl
    return m


def felt_torque_Nm(records: np.ndarray, r_out_m: float) -> np.ndarray:
    """|r_out (T_up_out - T_lo_out) - tau_g| of the running cycles [Nm] (``tau_g`` the tuned
    gravity model the step logged)."""
    run = records[records["phase"] == int(Phase.RUNNING)]
    tau_out = r_out_m * (run["T_up_out_N"].astype(float) - run["T_lo_out_N"].astype(float))
    return np.abs(tau_out - run["tau_g_Nm"].astype(float))


def verify(start: RigStart, controller: Mapping[str, Any], overrides: Mapping[str, Mapping[str, Any]],
           duration_s: float = VERIFY_S) -> VerifyResult:
    """Run the tuned loop for ``duration_s`` and measure it.

    :raises BringupStop: the tuned loop faulted or a device failed (torque zero, drive
        disabled, the reason in one line), or it rings (see the module docstring).
    """
    from capstan.controller.log.reader import read_log

    cfg = DaemonConfig.from_mapping(verify_mapping(start, controller, overrides), source=start.source)
    Path(cfg.logging.dir).mkdir(parents=True, exist_ok=True)
    def once() -> tuple[Daemon, str]:
        daemon = Daemon(cfg)
        try:
            daemon.run(duration_s=duration_s)
        except ControlFaultError as exc:
            text = (f"the tuned loop faulted: {exc.reason} (torque zero, drive disabled; log "
                    f"{daemon.summary.log_path}); no tuned config written")
            if stalled_host(exc.reason):
                return daemon, text
            raise BringupStop("verify", text) from None
        except (DriverError, CapstanError) as exc:
            raise BringupStop("verify", f"{type(exc).__name__}: {exc} (torque zero); no tuned config written") from None
        return daemon, ""
    s = repeat_after_host_stalls("verify", "verify", once).summary
    felt = np.zeros(0)
    if s.log_path:
        felt = felt_torque_Nm(read_log(s.log_path).records, start.drawing.r_out_m)
    cmd = dict(s.command)
    rings = (cmd.get("cmd_hf_share", 0.0) >= RINGING_HF_SHARE
             and cmd.get("cmd_change_rms_Nm", 0.0) >= RINGING_CHANGE_Nm)
    res = VerifyResult(s.cycles, float(np.mean(felt)) if len(felt) else math.nan,
                       float(np.percentile(felt, 95)) if len(felt) else math.nan, cmd, s.log_path, rings)
    log.info("verify: %d cycles, felt torque mean %.3f Nm (p95 %.3f), command change %.4f Nm/cycle rms, "
             "%.0f %% above 20 Hz, %d rate-limit hits", res.cycles, res.felt_mean_Nm, res.felt_p95_Nm,
             cmd.get("cmd_change_rms_Nm", math.nan), 100 * cmd.get("cmd_hf_share", math.nan),
             int(cmd.get("rate_limit_hits", 0)))
    if rings:
        raise BringupStop("verify", f"the tuned loop rings: {100 * cmd['cmd_hf_share']:.0f} % of the command above "
                                    f"20 Hz, change {cmd['cmd_change_rms_Nm']:.3f} Nm/cycle rms (log {s.log_path}); "
                                    f"no tuned config written")
    return res
