"""The first-order low-pass the law's filters use (``ldo.lowpass_alpha``, ``y += (1 - alpha)(x - y)``) has
its corner where it is configured: |H| = 1/sqrt(2) (-3 dB) at the cutoff, for cutoffs far below the
1 kHz rate (the discrete filter against the analogue one, within 1 %), and unit gain at DC."""

from __future__ import annotations

import numpy as np
import pytest

from capstan.controller.law.ldo import lowpass_alpha

DT = 1e-3


@pytest.mark.parametrize("cutoff_hz", [1.0, 5.0, 20.0])
def test_the_low_pass_is_3_db_down_at_its_cutoff(cutoff_hz: float) -> None:
    a = lowpass_alpha(cutoff_hz, DT)
    z = np.exp(1j * 2 * np.pi * cutoff_hz * DT)
    h = (1.0 - a) / (1.0 - a / z)
    assert abs(h) == pytest.approx(1.0 / np.sqrt(2.0), rel=0.01)
    assert (1.0 - a) / (1.0 - a) == 1.0 and 0.0 < a < 1.0


def test_off_is_zero() -> None:
    assert lowpass_alpha(0.0, DT) == 0.0
