"""Candidates are mechanisms: signals that measure the predicted channel or are tied to it
algebraically are excluded with the reason (models/closure/exclusion.py), and import
descriptions can mark such channels (tools/offline/importer.py ``tied_to``)."""

from __future__ import annotations

import numpy as np
import pytest

from capstan.models.closure.exclusion import excluded_signals
from capstan.models.closure.signals import signals_from_tables
from capstan.models.common.errors import ConfigError
from capstan.models.common.measurement_table import MeasurementTable
from capstan.tools.offline.importer import ImportDescription


def _table(meta=None) -> MeasurementTable:
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 20.0, 1e-3)
    q = 0.3 * np.sin(2 * np.pi * 0.3 * t) + 0.1 * np.sin(2 * np.pi * 1.1 * t)
    tau_out = 20.0 * q + 0.3 * np.tanh(50 * np.gradient(q, t))
    T0 = 150.0 + 60.0 * np.sin(2 * np.pi * 0.07 * t + 1.0)     # pretension change, shared by both
    cols = {"t": t, "q_out": q, "tau_in": tau_out + 0.4 * np.sign(np.gradient(q, t)),
            "tau_out": tau_out + 0.02 * rng.standard_normal(t.size),
            # tau_out = r (T_up,out - T_lo,out): each tension alone carries half of it plus the
            # pretension change; only the pair gives tau_out
            "T_up_out": T0 + tau_out / 0.08 + 0.5 * rng.standard_normal(t.size),
            "T_lo_out": T0 - tau_out / 0.08 + 0.5 * rng.standard_normal(t.size),
            "temperature": 25.0 + 0.5 * t / 20.0 + 0.01 * rng.standard_normal(t.size),
            "motor_current": 0.1 * tau_out + 0.001 * rng.standard_normal(t.size)}
    return MeasurementTable(cols, meta or {}, "excl")


def test_output_tensions_and_a_current_are_excluded_with_reasons_mechanisms_stay() -> None:
    sig = signals_from_tables([_table()])
    out = excluded_signals(sig, "tau_out", ("tau_in", "environment"))
    assert "motor_current" in out and "tied to tau_out" in out["motor_current"]
    # neither tension alone is tied (the pretension change), the pair is
    assert "together with T_up_out" in out["T_lo_out"] and "together with T_lo_out" in out["T_up_out"]
    # mechanisms and the driving signal are never tested
    for keep in ("temperature", "velocity", "position", "time", "dwell", "load"):
        assert keep not in out


def test_declared_ties_and_the_target_under_another_name() -> None:
    sig = signals_from_tables([_table({"tied_to": {"temperature": "tau_in"}})])
    out = excluded_signals(sig, "tau_in", ("q_in", "tau_out"))
    assert out["temperature"] == "declared in the import description as tied to tau_in"
    assert out["load"] == "load is tau_in, the predicted channel"


def test_import_description_tied_to_is_validated_and_recorded(tmp_path) -> None:
    base = {"channels": {"t": {"column": 1}, "tau_in": {"column": 2, "unit": "Nm"},
                         "current": {"column": 3, "unit": "A", "tied_to": "tau_in"}}}
    desc = ImportDescription(base)
    f = tmp_path / "run.txt"
    f.write_text("0,1,2\n0.001,1.5,2.5\n")
    tab = desc.read(f)
    assert tab.meta["tied_to"] == {"current": "tau_in"}
    bad = {"channels": {**base["channels"], "current": {"column": 3, "unit": "A", "tied_to": "velocity"}}}
    with pytest.raises(ConfigError, match=r"channels\.current\.tied_to"):
        ImportDescription(bad)
    std = {"channels": {**base["channels"], "tau_out": {"column": 3, "unit": "Nm", "tied_to": "tau_in"}}}
    with pytest.raises(ConfigError, match="only extra channels"):
        ImportDescription(std)
