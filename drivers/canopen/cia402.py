"""The CiA 402 (DS402) drive state machine as a transition table.

Shared by the master side (:mod:`capstan.drivers.canopen.motor`: which controlword moves the
drive one step towards a target state) and the drive side (:mod:`capstan.drivers.sim.drive`:
which state a received controlword leads to). Transition numbers are those of
CiA 402-2 figure "state machine"::

    NOT READY --1--> SWITCH ON DISABLED --2--> READY TO SWITCH ON --3--> SWITCHED ON
                         ^  ^  ^   <-7-- (READY)   <-6-- (SWITCHED ON)     |4 ^5
                         |  |  +--10-- (SWITCHED ON)                       v  |
                         |  +-----9-- (OPERATION ENABLED) <---------- OPERATION ENABLED
                         +--12-- QUICK STOP ACTIVE <--11-- (OP. ENABLED); 16: back
    any --13--> FAULT REACTION ACTIVE --14--> FAULT --15 (fault reset edge)--> SWITCH ON DISABLED
    (8: OPERATION ENABLED --> READY TO SWITCH ON)

Statusword bits used: 0 ready to switch on, 1 switched on, 2 operation enabled,
3 fault, 4 voltage enabled, 5 quick stop (active low), 6 switch on disabled,
7 warning, 9 remote, 10 target reached, 11 internal limit active.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from enum import IntEnum


class State402(IntEnum):
    """Drive states decoded from the statusword (0x6041)."""

    UNKNOWN = 0
    NOT_READY_TO_SWITCH_ON = 1
    SWITCH_ON_DISABLED = 2
    READY_TO_SWITCH_ON = 3
    SWITCHED_ON = 4
    OPERATION_ENABLED = 5
    QUICK_STOP_ACTIVE = 6
    FAULT_REACTION_ACTIVE = 7
    FAULT = 8


class Command402(IntEnum):
    """Device-control commands encoded in the controlword (0x6040) bits 0-3 and 7."""

    NONE = 0
    SHUTDOWN = 1
    SWITCH_ON = 2              # also "disable operation" (same bits)
    ENABLE_OPERATION = 3       # "switch on + enable operation"
    DISABLE_VOLTAGE = 4
    QUICK_STOP = 5
    FAULT_RESET = 6


class OpMode(IntEnum):
    """Modes of operation (0x6060 / 0x6061) used by capstan."""

    NO_MODE = 0
    PROFILE_POSITION = 1
    PROFILE_VELOCITY = 3
    PROFILE_TORQUE = 4
    HOMING = 6
    CYCLIC_SYNC_POSITION = 8
    CYCLIC_SYNC_VELOCITY = 9
    CYCLIC_SYNC_TORQUE = 10


#: bit of 0x6502 (supported drive modes) for each mode of operation
SUPPORTED_MODE_BIT: dict[OpMode, int] = {
    OpMode.PROFILE_POSITION: 0,
    OpMode.PROFILE_VELOCITY: 2,
    OpMode.PROFILE_TORQUE: 3,
    OpMode.HOMING: 5,
    OpMode.CYCLIC_SYNC_POSITION: 7,
    OpMode.CYCLIC_SYNC_VELOCITY: 8,
    OpMode.CYCLIC_SYNC_TORQUE: 9,
}

#: controlword values the master sends for each command (bits 4-6, 8 zero)
CONTROLWORD: dict[Command402, int] = {
    Command402.NONE: 0x0000,
    Command402.SHUTDOWN: 0x0006,
    Command402.SWITCH_ON: 0x0007,
    Command402.ENABLE_OPERATION: 0x000F,
    Command402.DISABLE_VOLTAGE: 0x0000,
    Command402.QUICK_STOP: 0x0002,
    Command402.FAULT_RESET: 0x0080,
}

#: (mask, value, state) — statusword decode table, CiA 402-2 table "statusword"
_STATUS_TABLE: tuple[tuple[int, int, State402], ...] = (
    (0x4F, 0x00, State402.NOT_READY_TO_SWITCH_ON),
    (0x4F, 0x40, State402.SWITCH_ON_DISABLED),
    (0x6F, 0x21, State402.READY_TO_SWITCH_ON),
    (0x6F, 0x23, State402.SWITCHED_ON),
    (0x6F, 0x27, State402.OPERATION_ENABLED),
    (0x6F, 0x07, State402.QUICK_STOP_ACTIVE),
    (0x4F, 0x0F, State402.FAULT_REACTION_ACTIVE),
    (0x4F, 0x08, State402.FAULT),
)

#: statusword bits 0-6 a drive reports in each state (bit 4 voltage enabled set where powered)
STATUSWORD_BITS: dict[State402, int] = {
    State402.NOT_READY_TO_SWITCH_ON: 0x00,
    State402.SWITCH_ON_DISABLED: 0x40,
    State402.READY_TO_SWITCH_ON: 0x21,
    State402.SWITCHED_ON: 0x33,
    State402.OPERATION_ENABLED: 0x37,
    State402.QUICK_STOP_ACTIVE: 0x17,
    State402.FAULT_REACTION_ACTIVE: 0x1F,
    State402.FAULT: 0x08,
}


@dataclass(frozen=True)
class Transition:
    """One commanded DS402 transition.

    :ivar number: transition number in CiA 402-2.
    :ivar source: state before.
    :ivar target: state after.
    :ivar command: controlword command that triggers it.
    :ivar timeout_s: default time the drive is given to report the new state [s].
    """

    number: int
    source: State402
    target: State402
    command: Command402
    timeout_s: float


_S = State402
_C = Command402

#: every transition a controlword can trigger (13/14 are automatic on a fault, 0/1 on power-up)
TRANSITIONS: tuple[Transition, ...] = (
    Transition(2, _S.SWITCH_ON_DISABLED, _S.READY_TO_SWITCH_ON, _C.SHUTDOWN, 0.5),
    Transition(3, _S.READY_TO_SWITCH_ON, _S.SWITCHED_ON, _C.SWITCH_ON, 0.5),
    Transition(4, _S.SWITCHED_ON, _S.OPERATION_ENABLED, _C.ENABLE_OPERATION, 1.0),
    Transition(5, _S.OPERATION_ENABLED, _S.SWITCHED_ON, _C.SWITCH_ON, 0.5),
    Transition(6, _S.SWITCHED_ON, _S.READY_TO_SWITCH_ON, _C.SHUTDOWN, 0.5),
    Transition(7, _S.READY_TO_SWITCH_ON, _S.SWITCH_ON_DISABLED, _C.DISABLE_VOLTAGE, 0.5),
    Transition(7, _S.READY_TO_SWITCH_ON, _S.SWITCH_ON_DISABLED, _C.QUICK_STOP, 0.5),
    Transition(8, _S.OPERATION_ENABLED, _S.READY_TO_SWITCH_ON, _C.SHUTDOWN, 0.5),
    Transition(9, _S.OPERATION_ENABLED, _S.SWITCH_ON_DISABLED, _C.DISABLE_VOLTAGE, 0.5),
    Transition(10, _S.SWITCHED_ON, _S.SWITCH_ON_DISABLED, _C.DISABLE_VOLTAGE, 0.5),
    Transition(10, _S.SWITCHED_ON, _S.SWITCH_ON_DISABLED, _C.QUICK_STOP, 0.5),
    Transition(11, _S.OPERATION_ENABLED, _S.QUICK_STOP_ACTIVE, _C.QUICK_STOP, 0.5),
    Transition(12, _S.QUICK_STOP_ACTIVE, _S.SWITCH_ON_DISABLED, _C.DISABLE_VOLTAGE, 2.0),
    Transition(15, _S.FAULT, _S.SWITCH_ON_DISABLED, _C.FAULT_RESET, 1.0),
    Transition(16, _S.QUICK_STOP_ACTIVE, _S.OPERATION_ENABLED, _C.ENABLE_OPERATION, 0.5),
)

#: (state, command) -> transition, for the drive side
_BY_COMMAND: dict[tuple[State402, Command402], Transition] = {
    (t.source, t.command): t for t in TRANSITIONS
}


def decode_statusword(statusword: int) -> State402:
    """State encoded in a statusword (0x6041); UNKNOWN for an invalid bit pattern."""
    for mask, value, state in _STATUS_TABLE:
        if statusword & mask == value:
            return state
    return State402.UNKNOWN


def decode_controlword(controlword: int, previous_controlword: int) -> Command402:
    """Command encoded in a controlword, as a drive interprets it.

    Fault reset is the rising edge of bit 7 only (bit 7 held high is no command).
    Table CiA 402-2 "command coding" (bits 7, 3, 2, 1, 0).
    """
    if controlword & 0x80:
        return Command402.FAULT_RESET if not previous_controlword & 0x80 else Command402.NONE
    if controlword & 0x02 == 0:
        return Command402.DISABLE_VOLTAGE
    if controlword & 0x04 == 0:
        return Command402.QUICK_STOP
    if controlword & 0x01 == 0:
        return Command402.SHUTDOWN
    if controlword & 0x08 == 0:
        return Command402.SWITCH_ON
    return Command402.ENABLE_OPERATION


def drive_transition(state: State402, command: Command402) -> Transition | None:
    """The transition a drive in ``state`` takes on ``command`` (None: stays put)."""
    return _BY_COMMAND.get((state, command))


def path_to(state: State402, target: State402) -> list[Transition]:
    """Shortest list of commanded transitions from ``state`` to ``target``.

    Empty if already there or if no commanded path exists (e.g. from
    NOT_READY_TO_SWITCH_ON or FAULT_REACTION_ACTIVE, which the drive leaves by itself).
    """
    if state == target:
        return []
    prev: dict[State402, Transition] = {}
    queue = deque([state])
    seen = {state}
    while queue:
        s = queue.popleft()
        for t in TRANSITIONS:
            if t.source == s and t.target not in seen:
                seen.add(t.target)
                prev[t.target] = t
                if t.target == target:
                    out = [t]
                    while out[0].source != state:
                        out.insert(0, prev[out[0].source])
                    return out
                queue.append(t.target)
    return []


def describe_statusword(statusword: int) -> str:
    """Readable one-line summary of a statusword."""
    flags = [name for bit, name in ((7, "warning"), (9, "remote"), (10, "target reached"),
                                    (11, "internal limit")) if statusword & (1 << bit)]
    extra = f" ({', '.join(flags)})" if flags else ""
    return f"0x{statusword:04X} {decode_statusword(statusword).name}{extra}"
