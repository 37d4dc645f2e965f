"""``capstan rig bringup``: check -> calibrate -> identify -> tune -> verify, then one atomic write.

Each step moves the rig only through :func:`capstan.tools.rig.step_run.run_profile` (the
daemon, the START limits, zero torque on any limit, an MCAP log per move). A step that
finds a mismatch names it and the workflow stops before any loop is armed; with ``fix``
the corrections a config can carry (the IMU sign, the load-cell scales) are applied, the
check is run again with them, and they go into the tuned config. Nothing is written unless
every step passed.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

from capstan.tools.rig.calibrate import CalibrationResult, calibrate
from capstan.tools.rig.check import CheckResult, Finding, analyse_check
from capstan.tools.rig.identify_step import identify, library_missing, tune
from capstan.tools.rig.profiles import CheckMove
from capstan.tools.rig.start_config import BringupStop, RigStart
from capstan.tools.rig.step_run import StepData, run_profile
from capstan.tools.rig.tuned import provenance_comment, tuned_mapping, write_atomic
from capstan.tools.rig.verify_step import verify

log = logging.getLogger("capstan.rig")

#: check-move torque as a share of the START torque limit [-]
CHECK_TORQUE_SHARE = 1.0


@dataclass
class BringupReport:
    """What ``capstan rig bringup --json`` prints."""

    ok: bool = False
    step: str = ""
    reason: str = ""
    findings: list[dict[str, Any]] = field(default_factory=list)
    fixes: dict[str, dict[str, Any]] = field(default_factory=dict)
    check: dict[str, Any] = field(default_factory=dict)
    calibration: dict[str, Any] = field(default_factory=dict)
    identification: dict[str, Any] = field(default_factory=dict)
    tuning: dict[str, Any] = field(default_factory=dict)
    verify: dict[str, Any] = field(default_factory=dict)
    logs: list[str] = field(default_factory=list)
    out: str | None = None
    wall_s: float = 0.0
    steps_s: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def with_devices(start: RigStart, overrides: Mapping[str, Mapping[str, Any]]) -> RigStart:
    """START with device keys replaced (corrections, calibration)."""
    dev = {role: {**sec, **overrides.get(role, {})} for role, sec in start.devices.items()}
    return dataclasses.replace(start, devices=dev)


def _stop_text(findings: list[Finding]) -> str:
    return "; ".join(f"{f.key}: {f.text}" for f in findings)


def run_check(start: RigStart, report: BringupReport) -> tuple[StepData, CheckMove, CheckResult]:
    """The check move and its verdict.

    :raises BringupStop: a limit, a device that does not move or answer.
    """
    move = CheckMove(tau_limit_Nm=CHECK_TORQUE_SHARE * start.limits.tau_max_Nm,
                     rest_s=start.calibration.rest_s)
    data = run_profile(start, "check", "check move", move, move.max_duration_s)
    report.logs.append(str(data.log_path))
    sign = float(start.devices["imu"].get("sign", 1.0))
    return data, move, analyse_check(data, move.windows, start.drawing.r_in_m, start.drawing.r_out_m, sign)


def bringup(start: RigStart, out: str | Path, fix: bool = False,
            hold_link: Callable[[bool], None] | None = None,
            base_controller: Mapping[str, Any] | None = None,
            tuned_start: RigStart | None = None,
            before_verify: Callable[[], None] | None = None) -> BringupReport:
    """Run the workflow; the report says how far it got and why it stopped.

    :param hold_link: clamps (True) / releases (False) the link for the held run; None: no
        way to hold it (the workflow then stops before identify, saying so).
    :param base_controller: the controller section whose structure the tuning scales
        (default: the shipped ``config/rig.yaml``'s).
    :param tuned_start: the START whose device sections the tuned config gets (default
        ``start``; a served rig's: with ``auto`` ports).
    :param before_verify: called before the tuned loop runs (at a rig: asks the person to
        take the link and move it gently while it runs).
    """
    rep = BringupReport()
    t0 = time.monotonic()
    overrides: dict[str, dict[str, Any]] = {}
    step = "check"
    try:
        ts = time.monotonic()
        data, move, res = run_check(start, rep)
        rep.check = res.evidence
        if res.findings:
            rep.findings = [dataclasses.asdict(f) for f in res.findings]
            if not fix or not all(f.fix for f in res.findings):
                raise BringupStop("check", _stop_text(res.findings))
            for f in res.findings:
                for role, keys in f.fix.items():
                    overrides.setdefault(role, {}).update(keys)
            rep.fixes = {k: dict(v) for k, v in overrides.items()}
            log.info("check: correcting %s and checking again", rep.fixes)
            data, move, res = run_check(with_devices(start, overrides), rep)
            rep.check = res.evidence
            if res.findings:
                raise BringupStop("check", "after the correction: " + _stop_text(res.findings))
        rep.steps_s["check"] = time.monotonic() - ts
        step = "calibrate"
        ts = time.monotonic()
        cal: CalibrationResult = calibrate(data, move.windows, with_devices(start, overrides))
        rep.calibration = {"evidence": cal.evidence, "load_cells": cal.load_cells}
        if cal.findings:
            rep.findings += [dataclasses.asdict(f) for f in cal.findings]
            if not fix or not cal.load_cells:
                raise BringupStop("calibrate", _stop_text(cal.findings))
            overrides.setdefault("load_cells", {}).update(cal.load_cells)
            rep.fixes.setdefault("load_cells", {}).update(cal.load_cells)
            log.info("calibrate: scales corrected to %s; checking again", cal.load_cells["scale_N_per_mV_V"])
            data, move, res = run_check(with_devices(start, overrides), rep)
            if res.findings:
                raise BringupStop("calibrate", "after the scale correction: " + _stop_text(res.findings))
            cal = calibrate(data, move.windows, with_devices(start, overrides))
            rep.calibration = {"evidence": cal.evidence, "load_cells": cal.load_cells}
            if cal.findings:
                raise BringupStop("calibrate", "after the scale correction: " + _stop_text(cal.findings))
        overrides.setdefault("load_cells", {}).update(cal.load_cells)
        rep.steps_s["calibrate"] = time.monotonic() - ts
        step = "identify"
        missing = library_missing()
        if missing:
            raise BringupStop("identify", f"calibrated, but the identification library is not available "
                                          f"({missing}): no tuned config written")
        if hold_link is None:
            raise BringupStop("identify", "calibrated; the held run needs the link clamped: run `capstan rig "
                                          "bringup` at a terminal (it asks when to clamp), no tuned config written")
        ts = time.monotonic()
        started = with_devices(start, overrides)
        ident, runs, excitation = identify(started, overrides, hold_link)
        rep.logs += [str(r.log_path) for r in runs]
        rep.identification = ident.to_dict()
        rep.steps_s["identify"] = time.monotonic() - ts
        step = "tune"
        ts = time.monotonic()
        if base_controller is None:
            from capstan.models.common.config_tools import load_yaml
            from capstan.tools.offline.shipped import config_path
            base_controller = load_yaml(config_path("rig.yaml"))["controller"]
        result = tune(ident, base_controller)
        rep.tuning = dict(result.report)
        rep.steps_s["tune"] = time.monotonic() - ts
        step = "verify"
        ts = time.monotonic()
        if before_verify is not None:
            before_verify()
        checked = verify(started, result.controller, overrides)
        rep.verify = checked.to_dict()
        if checked.log_path:
            rep.logs.append(str(checked.log_path))
        rep.steps_s["verify"] = time.monotonic() - ts
        mapping = tuned_mapping(tuned_start or start, result.controller, overrides)
        header = ("# Tuned by `capstan rig bringup` from " + str(start.source) + "; every plant value and gain\n"
                  "# below was measured or chosen on this rig. Provenance:\n")
        prov = {"date": cal.evidence.get("date"), "logs": rep.logs, "check": rep.check,
                "corrections": rep.fixes, "calibration": cal.evidence, "identification": rep.identification,
                "excitation": excitation, "tuning": rep.tuning, "verify": rep.verify}
        rep.out = str(write_atomic(out, mapping, header + provenance_comment(prov)))
        rep.ok, rep.step = True, "verify"
    except BringupStop as exc:
        rep.step, rep.reason = exc.step or step, exc.reason
        log.error("bring-up stopped in %s: %s", rep.step, exc.reason)
    rep.wall_s = time.monotonic() - t0
    return rep
