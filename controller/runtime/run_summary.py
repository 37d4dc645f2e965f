"""What one run of the daemon's loop reports: its life-cycle phase and its summary."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from enum import IntEnum
from typing import Any


class Phase(IntEnum):
    """Where the loop is in its life cycle."""

    ARMING = 0
    RUNNING = 1
    RAMPING = 2
    STOPPED = 3
    FAULTED = 4


@dataclass
class RunSummary:
    """Outcome of one :meth:`Daemon.run` (JSON-friendly via :meth:`to_dict`)."""

    cycles: int = 0
    missed: int = 0
    overruns: int = 0
    faults: list[str] = field(default_factory=list)
    dropped_log_records: int = 0
    log_path: str | None = None
    timing: dict[str, float] = field(default_factory=dict)
    phase: str = Phase.STOPPED.name
    threads: list[str] = field(default_factory=list)
    cpu_s: dict[str, float] = field(default_factory=dict)
    loop_wall_s: float = 0.0
    #: wake-to-wake interval that ended at the faulted cycle [s] (0 without a fault); longer
    #: than a sensor timeout, the process itself was not run (host stall), see :data:`STALL_PERIODS`
    fault_gap_s: float = 0.0
    #: serial link counters per device (good/bad frames, resyncs, bytes skipped, counter gaps)
    links: dict[str, dict[str, int]] = field(default_factory=dict)
    #: command quality over the running cycles (controller/runtime/command_quality.py)
    command: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of all fields."""
        return asdict(self)
