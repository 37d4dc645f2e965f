"""The torque command's way from the controller to the motor, as a CAN link delivers it.

On the rig the daemon computes a command every 1 ms and sends it in an RPDO after the SYNC;
the drive applies the newest RPDO it holds at its next cycle. Nominally that is a fixed
delay of ``delay_cycles`` (the daemon's ``controller.stability.io_delay_cycles``, 2), but:

* a late daemon cycle or a busy bus makes a frame miss its SYNC: that command arrives one
  (or more) cycle(s) later, and an early one a cycle sooner — ``jitter_cycles`` either way,
  for a fraction ``jitter_probability`` of the commands;
* a frame that is not sent at all (an overrun cycle) or lost (an error frame and a full
  transmit queue) never arrives: the drive holds the previous command (CiA 402 CST keeps
  the last target torque), a fraction ``loss_probability``.

CAN delivers the frames of one COB-ID in order, so a frame that is late holds up the ones
behind it (arrival times never decrease); if several arrive within one cycle the drive sees
the newest (its RPDO buffer is overwritten).

Magnitudes (the realistic default, :data:`REALISTIC_TIMING`): 5 % of the commands one cycle
early or late — the scheduling latency of a non-real-time host at 1 kHz (docs/benchmarks-hil.md
measured wake-up latencies of several ms under load, so a cycle missing its SYNC is common) —
and 0.1 % lost (an overrun streak shorter than the daemon's overrun fault). With
``delay_cycles`` 2 the command reaches the motor 1–3 cycles late.

:class:`CommandPath` is independent of the rig: the lock-step experiments put it between the
controller and :class:`capstan.models.plant.rig.SimulatedRig`; the simulated CANopen drive
can hold one between its RPDO and the torque it applies.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from capstan.models.common.config_tools import get_float, get_int, reject_unknown


@dataclass(frozen=True)
class CommandTiming:
    """How irregularly commands arrive (the fixed part of the delay is the caller's).

    :ivar jitter_cycles: largest deviation from the nominal delay [cycles].
    :ivar jitter_probability: fraction of commands that deviate (uniform over ±1..±jitter_cycles).
    :ivar loss_probability: fraction of commands that never arrive.
    """

    jitter_cycles: int = 1
    jitter_probability: float = 0.05
    loss_probability: float = 0.001

    @staticmethod
    def ideal() -> "CommandTiming":
        """Every command arrives exactly ``delay_cycles`` late."""
        return CommandTiming(0, 0.0, 0.0)

    @property
    def is_ideal(self) -> bool:
        """True if no command deviates and none is lost."""
        return (self.jitter_cycles == 0 or self.jitter_probability == 0.0) and self.loss_probability == 0.0

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any], prefix: str, default: "CommandTiming") -> "CommandTiming":
        """Parse a ``command`` section; absent keys keep ``default``'s values.

        :raises ConfigError: on unknown keys or values out of range.
        """
        reject_unknown(cfg, {"jitter_cycles", "jitter_probability", "loss_probability"}, prefix)
        return CommandTiming(
            get_int(cfg, "jitter_cycles", prefix, default.jitter_cycles, min_value=0, max_value=5),
            get_float(cfg, "jitter_probability", prefix, default.jitter_probability, min_value=0.0, max_value=1.0),
            get_float(cfg, "loss_probability", prefix, default.loss_probability, min_value=0.0, max_value=0.5),
        )


#: the realistic default (see the module docstring for the magnitudes)
REALISTIC_TIMING = CommandTiming()


class CommandPath:
    """Delays, jitters and drops commands; returns what the motor applies each cycle.

    :param timing: the irregularity.
    :param delay_cycles: nominal delay [cycles] (0: the command acts in its own cycle).
    :param seed: seed of the jitter/loss draws (runs are reproducible).
    :param initial_Nm: what the motor applies before the first command arrives [Nm].
    """

    def __init__(self, timing: CommandTiming, delay_cycles: int, seed: int = 0, initial_Nm: float = 0.0) -> None:
        if delay_cycles < 0:
            raise ValueError(f"delay_cycles must be >= 0, got {delay_cycles}")
        self.timing = timing
        self.delay_cycles = int(delay_cycles)
        self._rng = np.random.default_rng([int(seed), 0xC0DE])
        self._queue: deque[tuple[int, float]] = deque()     # (arrival cycle, command)
        self._cycle = 0
        self._last_arrival = -1
        self.applied_Nm = float(initial_Nm)
        #: commands sent, lost, and delivered with a delay other than the nominal
        self.sent = 0
        self.lost = 0
        self.jittered = 0

    def _delay(self) -> int:
        t = self.timing
        if t.jitter_cycles == 0 or t.jitter_probability == 0.0 or self._rng.random() >= t.jitter_probability:
            return self.delay_cycles
        step = int(self._rng.integers(1, t.jitter_cycles + 1)) * (1 if self._rng.random() < 0.5 else -1)
        return max(0, self.delay_cycles + step)

    def push(self, command_Nm: float) -> float:
        """Send this cycle's command; return the command the motor applies during this cycle [Nm]."""
        self.sent += 1
        lost = self.timing.loss_probability > 0.0 and self._rng.random() < self.timing.loss_probability
        if lost:
            self.lost += 1
        else:
            d = self._delay()
            if d != self.delay_cycles:
                self.jittered += 1
            arrival = max(self._cycle + d, self._last_arrival)     # in order, as CAN delivers one COB-ID
            self._last_arrival = arrival
            self._queue.append((arrival, float(command_Nm)))
        while self._queue and self._queue[0][0] <= self._cycle:
            self.applied_Nm = self._queue.popleft()[1]
        self._cycle += 1
        return self.applied_Nm

    def describe(self) -> dict[str, Any]:
        """Settings and counts, for run statistics."""
        t = self.timing
        return {"delay_cycles": self.delay_cycles, "jitter_cycles": t.jitter_cycles,
                "jitter_probability": t.jitter_probability, "loss_probability": t.loss_probability,
                "sent": self.sent, "lost": self.lost, "jittered": self.jittered,
                "lost_fraction": self.lost / self.sent if self.sent else math.nan}
