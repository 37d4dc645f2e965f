"""The PID loop's integral trim is clamped at ``feedback.integral_limit_Nm`` (anti-windup): a tracking
error the loop cannot remove (the input torque held 1 Nm below its reference, open loop) winds the
integral up at ``ki e`` per second to the limit and no further, in both directions, and it unwinds from
the limit at once when the error reverses (the input torque's low-pass delays the reversal a few cycles)."""

from __future__ import annotations

import numpy as np
import pytest

from capstan.controller.law.config import ControllerConfig
from test_torque_loop import _quiet, _run_step

KI, LIMIT = 10.0, 0.5


def _pid(limit: float = LIMIT) -> ControllerConfig:
    return ControllerConfig.from_mapping(_quiet({"torque_loop": "pid", "feedback": {
        "kp": 0.0, "kd_s": 0.0, "ki_1_s": KI, "integral_limit_Nm": limit, "inertia_comp_kg_m2": 0.0}}))


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_the_integral_winds_up_to_its_limit_and_no_further(sign: float) -> None:
    n = 1000
    u = _run_step(_pid(), None, 0, n, tau_in_in=np.full(n, -sign))     # error +sign Nm, held
    # ki e dt = 0.01 Nm per cycle: the limit is reached after 50 cycles and held (1 s would wind up 10 Nm)
    assert u[20] == pytest.approx(sign * 21 * KI * 1e-3, rel=1e-9)
    assert np.all(np.abs(u) <= LIMIT + 1e-12)
    assert np.all(u[60:] == sign * LIMIT)


def test_the_integral_unwinds_from_its_limit_at_once() -> None:
    tau = np.concatenate([np.full(1000, -1.0), np.full(100, 1.0)])      # the error reverses at cycle 1000
    u = _run_step(_pid(), None, 0, tau.size, tau_in_in=tau)
    assert u[999] == LIMIT
    # 50 cycles of the reversed error take ki e dt x 50 = 0.5 Nm off (less the tau_in filter's few cycles of
    # lag, 0.013 Nm measured): back near zero, where a wound-up integral (10 Nm) would still be at 9.5 Nm
    assert -LIMIT < u[1049] < 0.05
