"""Open-loop replay of the controller on logged cycle records (the library part of
``capstan replay``, also used by the logging benchmark).

Only the fields the loop writes before the step (``cycle`` and
``capstan.controller.law.records.MEASUREMENT_FIELDS``) are copied from the log into the
controller's record; everything the step computes is recomputed from a fresh controller.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import numpy as np

from capstan.controller.log.record_bytes import copy_fields
from capstan.models.common.errors import ConfigError, DataFormatError

@dataclass
class ReplayResult:
    """Outcome of one replay.

    :ivar replayed: records with the step outputs recomputed.
    :ivar max_abs_dtau_m_Nm: max |replayed - logged| of ``tau_m_cmd_Nm`` (inf if a NaN
        appears on one side only).
    :ivar n_different: cycles whose command differs in any bit.
    :ivar first_different: index of the first such cycle, -1 if none.
    :ivar wall_s: time spent stepping [s].
    :ivar cpu_s: CPU time of the process while stepping [s] (``wall_s`` without the
        waits for a CPU on a loaded machine).
    """

    replayed: np.ndarray
    max_abs_dtau_m_Nm: float
    n_different: int
    first_different: int
    wall_s: float
    cpu_s: float = 0.0


#: a NaN payload no controller computes; detects whether the step wrote in place
_SENTINEL = np.array([0x7FF4DEADBEEF0001], dtype=np.uint64).view(np.float64)[0]


class _Done(Exception):
    """The batch path stepped every record."""


class _NoInPlace(Exception):
    """The controller did not write its outputs into a swapped-in record."""


def merge_config(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    """Deep merge: mappings merge key by key, any other value in ``override`` replaces."""
    out = copy.deepcopy(dict(base))
    for k, v in override.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = merge_config(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def build_controller(cfg: Mapping[str, Any]) -> Any:
    """A fresh, warmed-up :class:`capstan.controller.law.core.Controller` from a daemon config mapping.

    :raises ConfigError: if the ``controller`` section is missing or invalid.
    """
    from capstan.controller.law.config import ControllerConfig
    from capstan.controller.law.core import Controller
    section = cfg.get("controller")
    if not isinstance(section, Mapping):
        raise ConfigError("controller", "missing from the config (the log stores none?)")
    ctl = Controller(ControllerConfig.from_mapping(section))
    ctl.warmup()
    return ctl


def replay_records(records: np.ndarray, ctl: Any, input_fields: tuple[str, ...],
                   output_fields: tuple[str, ...], command_field: str = "tau_m_cmd_Nm",
                   progress: Callable[[int, int], None] | None = None) -> ReplayResult:
    """Step ``ctl`` once per logged record on the logged inputs.

    :param ctl: object with ``record`` (shape (1,) structured array) and ``step()``.
    :param input_fields: fields copied from the log before each step.
    :param output_fields: fields the step writes (recomputed); all other fields of the
        result are copied from the log (timing).
    :raises DataFormatError: if the log lacks an input field or the command field.
    """
    from capstan.controller.law.records import LOOP_GATING_FIELDS, PHASE_ARMING

    dtype = ctl.record.dtype
    n = len(records)
    for name in (*input_fields, command_field):
        if name not in (records.dtype.names or ()):
            raise DataFormatError(f"log has no field '{name}' needed for replay")
    out = np.zeros(n, dtype)
    copy_fields(out, records, input_fields)
    # the loop's gating: cycles it did not step (arming) and the factor it applied
    gated = all(f in (records.dtype.names or ()) for f in LOOP_GATING_FIELDS)
    if gated:
        stepped = records["phase"] != PHASE_ARMING
        scale = records["cmd_scale"].astype(np.float64)
    else:                                   # a log of a loop without gating: every cycle stepped
        stepped = np.ones(n, bool)
        scale = np.ones(n)
    todo = np.flatnonzero(stepped)
    step = ctl.step
    own_record = ctl.record
    t0, cpu0 = time.perf_counter(), time.process_time()
    batch = getattr(ctl, "step_many", None)
    try:
        if callable(batch):
            # compiled loop over the records in place (capstan Controller), in slices so
            # the progress callback runs
            if progress is not None:
                progress(0, n)
            for a in range(0, todo.size, 1 << 16):
                batch(out, todo[a:a + (1 << 16)])
                if progress is not None:
                    progress(int(todo[min(a + (1 << 16), todo.size) - 1]), n)
            raise _Done
        # fast path: point the controller's record at row i of the result, so the step
        # reads the logged inputs there and writes its outputs in place
        if todo.size:
            i = int(todo[0])
            ctl.record = out[i:i + 1]
            out[command_field][i] = _SENTINEL           # must be overwritten by the step
            tau = np.float64(step())
            if out[command_field][i:i + 1].view(np.uint64)[0] != tau.view(np.uint64):
                raise _NoInPlace
            if progress is not None:
                progress(0, n)
            for k in range(1, todo.size):
                i = int(todo[k])
                ctl.record = out[i:i + 1]
                step()
                if progress is not None and not k & 0xFFFF:
                    progress(i, n)
    except _Done:
        pass
    except _NoInPlace:
        # the controller does not step on whatever ``record`` refers to: copy in and out
        ctl.record = own_record
        ctl.reset()
        inp = out.copy()
        rec_u8 = own_record.view(np.uint8)
        in_u8 = inp.view(np.uint8).reshape(n, dtype.itemsize)
        out_u8 = out.view(np.uint8).reshape(n, dtype.itemsize)
        for k in range(todo.size):
            i = int(todo[k])
            rec_u8[:] = in_u8[i]
            step()
            out_u8[i] = rec_u8
            if progress is not None and not k & 0xFFFF:
                progress(i, n)
    finally:
        ctl.record = own_record
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    if progress is not None:
        progress(n, n)
    for name in dtype.names:
        if name not in output_fields and name not in input_fields and name in (records.dtype.names or ()):
            out[name] = records[name]
    # the loop's command from the step's: gating factor, zero on any fault (as the daemon)
    cmd = out[command_field]
    faults = out["fault_bits"].astype(np.int64) if "fault_bits" in dtype.names else np.zeros(n, np.int64)
    if "ext_fault_bits" in dtype.names:
        faults |= out["ext_fault_bits"].astype(np.int64)
    with np.errstate(invalid="ignore", over="ignore"):
        cmd *= scale                        # vectorised controller.records.loop_command
    cmd[(faults != 0) | ~np.isfinite(cmd) | ~stepped] = 0.0
    a = records[command_field].astype(np.float64)
    b = out[command_field]
    differ = a.view(np.uint64) != b.view(np.uint64)
    dabs = np.abs(b - a)
    dabs[np.isnan(a) & np.isnan(b)] = 0.0
    dabs[np.isnan(dabs)] = np.inf
    first = int(np.argmax(differ)) if differ.any() else -1
    return ReplayResult(out, float(dabs.max()) if n else 0.0, int(differ.sum()), first, wall, cpu)
