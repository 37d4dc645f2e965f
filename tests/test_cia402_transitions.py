"""The commanded DS402 transitions against CiA 402-2's state machine, written out here from the
standard's table (transition number -> source, target, controlword bits 0-3 and 7), not from the
driver's own table: the controlwords the master sends on the way to OPERATION ENABLED and back."""

from __future__ import annotations

import pytest

from capstan.drivers.canopen.cia402 import CONTROLWORD, TRANSITIONS, State402, drive_transition, path_to

S = State402
#: CiA 402-2, device control: transition -> (source, target, the controlwords that command it)
STANDARD = {
    2: (S.SWITCH_ON_DISABLED, S.READY_TO_SWITCH_ON, {0x06}),          # shutdown
    3: (S.READY_TO_SWITCH_ON, S.SWITCHED_ON, {0x07}),                  # switch on
    4: (S.SWITCHED_ON, S.OPERATION_ENABLED, {0x0F}),                   # enable operation
    5: (S.OPERATION_ENABLED, S.SWITCHED_ON, {0x07}),                   # disable operation
    6: (S.SWITCHED_ON, S.READY_TO_SWITCH_ON, {0x06}),                  # shutdown
    7: (S.READY_TO_SWITCH_ON, S.SWITCH_ON_DISABLED, {0x00, 0x02}),     # disable voltage / quick stop
    8: (S.OPERATION_ENABLED, S.READY_TO_SWITCH_ON, {0x06}),            # shutdown
    9: (S.OPERATION_ENABLED, S.SWITCH_ON_DISABLED, {0x00}),            # disable voltage
    10: (S.SWITCHED_ON, S.SWITCH_ON_DISABLED, {0x00, 0x02}),           # disable voltage / quick stop
    11: (S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE, {0x02}),            # quick stop
    12: (S.QUICK_STOP_ACTIVE, S.SWITCH_ON_DISABLED, {0x00}),           # disable voltage
    15: (S.FAULT, S.SWITCH_ON_DISABLED, {0x80}),                       # fault reset (rising edge of bit 7)
    16: (S.QUICK_STOP_ACTIVE, S.OPERATION_ENABLED, {0x0F}),            # enable operation
}


@pytest.mark.parametrize("t", TRANSITIONS, ids=lambda t: f"transition-{t.number}")
def test_every_commanded_transition_is_the_standards(t) -> None:
    source, target, words = STANDARD[t.number]
    assert (t.source, t.target) == (source, target)
    assert CONTROLWORD[t.command] in words
    assert drive_transition(t.source, t.command) == t


def test_bring_up_and_back_send_the_standards_controlwords() -> None:
    up = path_to(S.SWITCH_ON_DISABLED, S.OPERATION_ENABLED)
    assert [t.number for t in up] == [2, 3, 4]
    assert [CONTROLWORD[t.command] for t in up] == [0x06, 0x07, 0x0F]
    down = path_to(S.OPERATION_ENABLED, S.SWITCH_ON_DISABLED)
    assert [t.number for t in down] == [9] and CONTROLWORD[down[0].command] == 0x00
    assert [t.number for t in path_to(S.FAULT, S.OPERATION_ENABLED)] == [15, 2, 3, 4]
