"""The configuration reference (docs/configuration.md) is generated from the parsers: every key
the daemon's parsers read has a line of meaning, no meaning is left for a key the code no
longer reads, and the committed file is what ``capstan config reference`` prints now."""

from __future__ import annotations

from pathlib import Path

import pytest

from capstan.models.common.config_tools import get_float, recording_keys, reject_unknown
from capstan.models.common.errors import ConfigError
from capstan.tools.commands.config_reference import (collect_keys, missing_meanings, reference,
                                                     stale_meanings, unit_of)

DOC = Path(__file__).resolve().parent.parent / "docs" / "configuration.md"


@pytest.fixture(scope="module")
def keys():
    return collect_keys()


def test_every_key_has_a_meaning(keys):
    missing = missing_meanings(keys)
    assert not missing, ("keys without a line in capstan/tools/offline/config_meanings.py MEANINGS: "
                         + ", ".join(missing))


def test_no_meaning_for_a_key_the_code_does_not_read(keys):
    stale = stale_meanings(keys)
    assert not stale, "MEANINGS names keys no parser reads: " + ", ".join(stale)


def test_committed_reference_is_current():
    assert DOC.read_text() == reference(), (
        "docs/configuration.md is out of date: run `capstan config reference > docs/configuration.md`")


def test_reference_carries_the_code_defaults(keys):
    """The defaults come from the parsers, not from a shipped file: a key the shipped configs
    set to another value still shows the code's default."""
    from capstan.controller.law.config import ControllerConfig
    d = ControllerConfig()
    assert keys["controller.feedback.kp"].default == d.feedback.kp
    assert keys["controller.feedforward.eq25_reading"].default == d.feedforward.eq25_reading.name.lower()
    assert set(keys["controller.feedforward.eq25_reading"].choices) == {"friction_preserving", "field_minimum"}
    assert "controller.feedforward.effects" in keys
    assert {"alpha_s_rad", "eta_s_rad_s", "zeta_s", "v_rest_rad_s"} <= {
        k.rsplit(".", 1)[1] for k in keys if k.startswith("controller.feedforward.effects_shape.")}


def test_recorder_notes_bounds_and_allowed_keys():
    with recording_keys() as uses:
        reject_unknown({"a_hz": 1.0}, {"a_hz", "b"}, "x")
        assert get_float({"a_hz": 1.0}, "a_hz", "x", 2.0, min_value=0.0, min_exclusive=True, max_value=5.0) == 1.0
    by = {(u.path, u.kind): u for u in uses}
    assert ("x.b", "key") in by
    f = by[("x.a_hz", "float")]
    assert (f.default, f.min_value, f.max_value, f.min_exclusive) == (2.0, 0.0, 5.0, True)
    with pytest.raises(ConfigError):              # recording does not change validation
        with recording_keys():
            get_float({"a_hz": -1.0}, "a_hz", "x", min_value=0.0)


def test_units_from_key_names():
    assert unit_of("controller.feedback.deflection_damping_Nms_rad") == "N m s/rad"
    assert unit_of("controller.safety.dtau_max_Nm_s") == "N m/s"
    assert unit_of("controller.feedforward.zeta_s") == ""          # a factor, not seconds
    assert unit_of("loop.period_s") == "s"


def test_committed_controller_example_is_the_defaults():
    """config/controller.yaml is generated from the code's defaults, so its values and the
    meanings beside them cannot drift from the code."""
    committed = (DOC.parent.parent / "config" / "controller.yaml").read_text()
    from capstan.tools.commands.config_reference import controller_example
    assert committed == controller_example(), (
        "config/controller.yaml is out of date: run "
        "`capstan config reference --controller-example > config/controller.yaml`")
