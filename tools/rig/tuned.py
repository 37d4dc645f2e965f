"""The bring-up's output: a complete daemon config (``capstan run`` / ``capstan hil`` accept it),
written once, atomically, at the end — a refused step leaves no file behind.

Every plant value and gain of its ``controller`` section comes from the tuning of the
identified rig; the device sections are START's with the check's corrections and the
calibration; the provenance (date, logs of every run, the fit with its uncertainties, the
calibration's evidence) heads the file as comments, which every config loader ignores.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any, Mapping

import yaml

from capstan.tools.rig.start_config import RigStart

#: the loop settings of a tuned config (as the shipped rig config)
LOOP = {"period_s": 0.001, "busy_tail_s": 0.00015, "overrun_streak_fault": 10, "sensor_fresh_s": 0.02,
        "startup_timeout_s": 5.0, "ramp_down_s": 0.2, "stats_interval_s": 1.0}


def device_sections(start: RigStart, overrides: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """START's device sections with the corrected/calibrated keys."""
    out = {role: dict(sec) for role, sec in start.devices.items()}
    for role, keys in overrides.items():
        out[role] = {**out[role], **keys}
    return out


def tuned_mapping(start: RigStart, controller: Mapping[str, Any],
                  overrides: Mapping[str, Mapping[str, Any]], log_dir: str = "runs/logs") -> dict[str, Any]:
    """The complete daemon config."""
    return {"controller": dict(controller), **device_sections(start, overrides),
            "logging": {"dir": log_dir, "ring_records": 8192, "fault_history_cycles": 500},
            "realtime": {"mode": "warn", "priority": 80, "lock_memory": True},
            "loop": dict(LOOP)}


def provenance_comment(provenance: Mapping[str, Any]) -> str:
    """The provenance as YAML comment lines (``# ...``)."""
    text = yaml.safe_dump(json.loads(json.dumps(provenance, default=str)), sort_keys=False, width=110)
    return "".join(f"# {line}\n" for line in text.splitlines())


def write_atomic(path: str | Path, mapping: Mapping[str, Any], header: str) -> Path:
    """Write ``header`` + ``mapping`` as YAML to a temporary file beside ``path``, then rename
    it over ``path`` (readers see the old file or the whole new one, never a part)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", dir=p.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(header)
            yaml.safe_dump(json.loads(json.dumps(dict(mapping))), f, sort_keys=False, width=110)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return p
