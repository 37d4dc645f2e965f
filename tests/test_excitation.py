import numpy as np
import pytest

from capstan.models.common.errors import ConfigError
from capstan.models.plant.excitation import Hold, Multisine, SineComponent, excitation_from_mapping


def test_multisine_matches_closed_form_after_fade_in():
    ex = Multisine((SineComponent(5.0, 0.2), SineComponent(3.0, 0.5, 0.7)), fade_in_s=1.0)
    t = np.linspace(1.0, 10.0, 1001)
    expect = 5.0 * np.sin(2 * np.pi * 0.2 * t) + 3.0 * np.sin(2 * np.pi * 0.5 * t + 0.7)
    np.testing.assert_allclose(ex.torque_Nm(t), expect, atol=1e-12)
    assert ex.torque_Nm(np.array([0.0]))[0] == 0.0  # faded in from zero
    assert ex.peak_Nm == 8.0


def test_hold_freezes_value_and_resumes_continuously():
    ex = Multisine((SineComponent(5.0, 0.2),), fade_in_s=0.0, holds=(Hold(2.0, 3.0),))
    t = np.array([2.0, 3.0, 4.999, 5.0, 6.0])
    y = ex.torque_Nm(t)
    frozen = 5.0 * np.sin(2 * np.pi * 0.2 * 2.0)
    np.testing.assert_allclose(y[:4], frozen, atol=1e-12)
    # after the hold the sine continues from where it stopped (clock shifted by 3 s)
    assert y[4] == pytest.approx(5.0 * np.sin(2 * np.pi * 0.2 * 3.0))


def test_table_excitation_interpolates_and_validates():
    ex = excitation_from_mapping({"type": "table", "samples": [[0, 0], [1, 2], [2, -2]]})
    np.testing.assert_allclose(ex.torque_Nm(np.array([0.5, 1.5, 3.0])), [1.0, 0.0, -2.0])
    with pytest.raises(ConfigError, match="strictly increasing"):
        excitation_from_mapping({"type": "table", "samples": [[0, 0], [0, 2]]})


def test_bad_excitation_config_names_the_key():
    with pytest.raises(ConfigError, match=r"excitation.components\[0\].frequency_hz"):
        excitation_from_mapping({"components": [{"amplitude_Nm": 1.0, "frequency_hz": -1}]})
    with pytest.raises(ConfigError, match=r"excitation.components\[0\].amplitud"):
        excitation_from_mapping({"components": [{"amplitud": 1.0, "frequency_hz": 1}]})
    with pytest.raises(ConfigError, match="excitation.type"):
        excitation_from_mapping({"type": "chirp"})
