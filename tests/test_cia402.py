"""DS402 state machine table, controlword/statusword coding (CiA 402-2) and EMCY decoding."""

from __future__ import annotations

import pytest

from capstan.drivers.canopen.cia402 import (CONTROLWORD, Command402, State402, STATUSWORD_BITS, TRANSITIONS,
                            decode_controlword, decode_statusword, drive_transition, path_to)
from capstan.drivers.canopen.emcy import decode_emcy, describe_code, encode_emcy
from capstan.models.common.errors import ProtocolError

S = State402


@pytest.mark.parametrize("sw, state", [
    (0x0000, S.NOT_READY_TO_SWITCH_ON),
    (0x0250, S.SWITCH_ON_DISABLED),       # typical: remote + voltage + switch on disabled
    (0x0040, S.SWITCH_ON_DISABLED),
    (0x0231, S.READY_TO_SWITCH_ON),
    (0x0233, S.SWITCHED_ON),
    (0x1237, S.OPERATION_ENABLED),        # + bit 12 "drive follows the command value"
    (0x02B7, S.OPERATION_ENABLED),        # + warning bit 7
    (0x0217, S.QUICK_STOP_ACTIVE),        # bit 5 (quick stop) low
    (0x021F, S.FAULT_REACTION_ACTIVE),
    (0x0218, S.FAULT),
    (0x0208, S.FAULT),
])
def test_statusword_decoding_follows_the_spec_table(sw, state):
    assert decode_statusword(sw) == state


def test_invalid_statusword_pattern_is_unknown():
    assert decode_statusword(0x0001) == S.UNKNOWN  # ready bit without quick-stop bit


def test_status_bits_a_drive_reports_decode_back_to_the_same_state():
    for state, bits in STATUSWORD_BITS.items():
        assert decode_statusword(bits | 0x0200) == state


@pytest.mark.parametrize("cw, command", [
    (0x0006, Command402.SHUTDOWN),
    (0x000E, Command402.SHUTDOWN),         # bit 3 is "don't care" for shutdown
    (0x0007, Command402.SWITCH_ON),
    (0x000F, Command402.ENABLE_OPERATION),
    (0x0000, Command402.DISABLE_VOLTAGE),
    (0x000D, Command402.DISABLE_VOLTAGE),  # bit 1 low wins
    (0x0002, Command402.QUICK_STOP),
    (0x000B, Command402.QUICK_STOP),
])
def test_controlword_command_coding(cw, command):
    assert decode_controlword(cw, 0x0000) == command


def test_fault_reset_needs_a_rising_edge_of_bit_7():
    assert decode_controlword(0x0080, 0x0000) == Command402.FAULT_RESET
    assert decode_controlword(0x0080, 0x0080) == Command402.NONE  # held high: no second reset
    assert decode_controlword(0x008F, 0x000F) == Command402.FAULT_RESET


def test_master_controlwords_are_decoded_as_their_command():
    for command, cw in CONTROLWORD.items():
        if command in (Command402.NONE, Command402.FAULT_RESET):
            continue
        assert decode_controlword(cw, 0) == command


def test_transition_numbers_match_cia402():
    by_number = {(t.number, t.source, t.target) for t in TRANSITIONS}
    expected = {
        (2, S.SWITCH_ON_DISABLED, S.READY_TO_SWITCH_ON), (3, S.READY_TO_SWITCH_ON, S.SWITCHED_ON),
        (4, S.SWITCHED_ON, S.OPERATION_ENABLED), (5, S.OPERATION_ENABLED, S.SWITCHED_ON),
        (6, S.SWITCHED_ON, S.READY_TO_SWITCH_ON), (7, S.READY_TO_SWITCH_ON, S.SWITCH_ON_DISABLED),
        (8, S.OPERATION_ENABLED, S.READY_TO_SWITCH_ON), (9, S.OPERATION_ENABLED, S.SWITCH_ON_DISABLED),
        (10, S.SWITCHED_ON, S.SWITCH_ON_DISABLED), (11, S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE),
        (12, S.QUICK_STOP_ACTIVE, S.SWITCH_ON_DISABLED), (15, S.FAULT, S.SWITCH_ON_DISABLED),
        (16, S.QUICK_STOP_ACTIVE, S.OPERATION_ENABLED),
    }
    assert by_number == expected
    assert all(t.timeout_s > 0 for t in TRANSITIONS)


def test_paths_take_the_spec_transitions():
    assert [t.number for t in path_to(S.SWITCH_ON_DISABLED, S.OPERATION_ENABLED)] == [2, 3, 4]
    assert [t.number for t in path_to(S.FAULT, S.OPERATION_ENABLED)] == [15, 2, 3, 4]
    assert [t.number for t in path_to(S.OPERATION_ENABLED, S.READY_TO_SWITCH_ON)] == [8]
    assert [t.number for t in path_to(S.QUICK_STOP_ACTIVE, S.OPERATION_ENABLED)] == [16]
    assert path_to(S.OPERATION_ENABLED, S.OPERATION_ENABLED) == []
    assert path_to(S.NOT_READY_TO_SWITCH_ON, S.OPERATION_ENABLED) == []  # drive leaves it by itself


def test_drive_side_transitions():
    assert drive_transition(S.SWITCH_ON_DISABLED, Command402.SHUTDOWN).number == 2
    assert drive_transition(S.SWITCH_ON_DISABLED, Command402.SWITCH_ON) is None
    assert drive_transition(S.OPERATION_ENABLED, Command402.QUICK_STOP).number == 11
    assert drive_transition(S.FAULT, Command402.ENABLE_OPERATION) is None
    assert drive_transition(S.FAULT, Command402.FAULT_RESET).number == 15


def test_emcy_decoding_of_exact_bytes():
    fault = decode_emcy(bytes([0x10, 0x42, 0x09, 0x01, 0x02, 0x03, 0x04, 0x05]), t_s=1.5)
    assert fault.code == 0x4210 and fault.register == 0x09
    assert fault.vendor_data == b"\x01\x02\x03\x04\x05" and fault.t_s == 1.5
    assert fault.description == "excess temperature, device"
    assert "generic" in str(fault) and "temperature" in str(fault) and "0x4210" in str(fault)
    assert not fault.is_reset
    assert decode_emcy(bytes(8)).is_reset


def test_emcy_code_falls_back_to_its_group():
    assert describe_code(0x8130) == "life guard or heartbeat error"
    assert describe_code(0x2311) == "continuous over-current"   # 0x231x group
    assert describe_code(0x4399) == "drive temperature"          # 0x43xx group
    assert describe_code(0xFF42) == "device specific"
    assert describe_code(0x3456) == "voltage"


def test_emcy_roundtrip_and_short_frame():
    assert encode_emcy(0x8130, 0x11) == bytes([0x30, 0x81, 0x11, 0, 0, 0, 0, 0])
    with pytest.raises(ProtocolError):
        decode_emcy(b"\x00\x10")
