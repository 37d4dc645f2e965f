"""CAN timing of the simulated drive's command path: the torque reaches the motor late, a PDO is lost.

A real CiA 402 drive in cyclic synchronous torque mode takes the target (0x6071) of the
RPDO received before a SYNC over *at* that SYNC, and its current loop applies it one or more
cycles later; on a loaded bus, or when the master's frame misses the drive's window, the
take-over slips by a cycle; a frame that never arrives leaves the drive on the previous
target. :class:`CommandDelayLine` models that, seeded (reproducible):

* every SYNC the drive takes over its current target; that target reaches the motor
  ``d`` SYNCs later, ``d`` drawn uniformly from ``command_delay_cycles`` (default 1..3);
  a target never overtakes a newer one (a newer target that is due first supersedes the
  older, which is then never applied);
* each RPDO is lost with probability ``command_loss_rate`` (default 1e-3): the drive keeps
  the previous target and controlword (the caller drops the frame).

``can_timing: ideal`` is the labelled, kinder-than-a-rig option: no delay line at all (the target is
applied as the RPDO arrives, as the simulated drive did before this model).
"""

from __future__ import annotations

import heapq
from collections import Counter
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from capstan.models.common.config_tools import get_choice, get_float, get_int
from capstan.models.common.errors import ConfigError

CAN_TIMING_MODES = ("realistic", "ideal")


@dataclass(frozen=True)
class CanTimingSettings:
    """CAN timing of the simulated drive (the ``hil.drive`` keys).

    :ivar mode: ``realistic`` (delay line and losses) or ``ideal`` (none: labelled, kinder than a rig).
    :ivar command_delay_cycles: (fewest, most) SYNC periods from take-over to the motor.
    :ivar command_loss_rate: probability that one RPDO is lost [0..1).
    :ivar seed: seed of the draws.
    """

    mode: str = "realistic"
    command_delay_cycles: tuple[int, int] = (1, 3)
    command_loss_rate: float = 1e-3
    seed: int = 0

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any], prefix: str) -> "CanTimingSettings":
        """Read ``can_timing``, ``command_delay_cycles``, ``command_loss_rate``, ``seed`` of ``cfg``.

        :raises ConfigError: naming the key and the reason.
        """
        d = cls()
        delay = cfg.get("command_delay_cycles", list(d.command_delay_cycles))
        if isinstance(delay, int) and not isinstance(delay, bool):
            delay = [delay, delay]
        if (not isinstance(delay, (list, tuple)) or len(delay) != 2
                or not all(isinstance(v, int) and not isinstance(v, bool) for v in delay)
                or not 0 <= delay[0] <= delay[1] <= 50):
            raise ConfigError(f"{prefix}.command_delay_cycles",
                              f"must be [fewest, most] whole SYNC periods with 0 <= fewest <= most <= 50, "
                              f"got {delay!r}")
        return cls(get_choice(cfg, "can_timing", CAN_TIMING_MODES, prefix, d.mode), (delay[0], delay[1]),
                   get_float(cfg, "command_loss_rate", prefix, d.command_loss_rate, min_value=0.0, max_value=0.5),
                   get_int(cfg, "seed", prefix, d.seed, min_value=0))

    def delay_line(self) -> "CommandDelayLine | None":
        """The delay line these settings ask for (None for ``ideal``)."""
        if self.mode == "ideal":
            return None
        return CommandDelayLine(self.command_delay_cycles, self.command_loss_rate, self.seed)


class CommandDelayLine:
    """Seeded delay and loss of the torque target between the bus and the motor (module docstring).

    Not thread-safe: the simulated drive calls it under its lock.

    :param delay_cycles: (fewest, most) SYNC periods from take-over to the motor.
    :param loss_rate: probability that one RPDO is lost.
    :param seed: seed of the draws.
    """

    def __init__(self, delay_cycles: tuple[int, int] = (1, 3), loss_rate: float = 1e-3, seed: int = 0) -> None:
        self.delay_cycles = (int(delay_cycles[0]), int(delay_cycles[1]))
        self.loss_rate = float(loss_rate)
        self._rng = np.random.default_rng(seed)
        self._queue: list[tuple[int, int, int]] = []   # (due SYNC, sequence, target)
        self._seq = 0
        self._applied_seq = -1
        self._taken_at: dict[int, int] = {}
        #: RPDOs seen / lost
        self.frames = 0
        self.lost = 0
        #: how many targets reached the motor after how many SYNCs
        self.delays: Counter[int] = Counter()
        #: targets superseded by a newer one due earlier (never applied)
        self.superseded = 0

    def frame_lost(self) -> bool:
        """Draw the fate of one received RPDO: True if it is lost (the caller drops it)."""
        self.frames += 1
        if self.loss_rate > 0 and self._rng.random() < self.loss_rate:
            self.lost += 1
            return True
        return False

    def take(self, sync: int, target: int) -> None:
        """The drive takes ``target`` over at SYNC number ``sync``; it is due a drawn delay later."""
        lo, hi = self.delay_cycles
        d = lo if lo == hi else int(self._rng.integers(lo, hi + 1))
        heapq.heappush(self._queue, (sync + d, self._seq, target))
        self._taken_at[self._seq] = sync
        self._seq += 1

    def due(self, sync: int) -> int | None:
        """The target that reaches the motor at SYNC ``sync`` (None: the motor keeps its target)."""
        out = None
        while self._queue and self._queue[0][0] <= sync:
            _, seq, target = heapq.heappop(self._queue)
            taken = self._taken_at.pop(seq)
            if seq > self._applied_seq:
                self._applied_seq = seq
                self.delays[sync - taken] += 1
                out = target
            else:
                self.superseded += 1
        return out

    def reset(self) -> None:
        """Forget the targets in flight (the drive left OPERATION ENABLED)."""
        self._queue.clear()
        self._taken_at.clear()
        self._applied_seq = self._seq - 1

    def stats(self) -> dict[str, Any]:
        """Counts for a run summary: frames, lost, superseded, delay histogram."""
        return {"frames": self.frames, "lost": self.lost, "superseded": self.superseded,
                "delay_cycles": {int(k): int(v) for k, v in sorted(self.delays.items())}}
