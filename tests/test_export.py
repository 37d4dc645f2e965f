"""``capstan export``: a log becomes a measurement table with the documented mapping."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from capstan.controller.log.mcap_log import McapLog
from capstan.models.common.errors import DataFormatError
from capstan.tools.cli import main
from capstan.tools.offline.log_table import records_to_table
from capstan.models.common.measurement_table import read_table

from test_replay import simulate_run, write_log

CFG = {"controller": {"plant": {"r_in_m": 0.05, "r_out_m": 0.045},
                      "feedforward": {"mu": 0.06, "routing": {"length_m": 1.2, "theta_rad": 2.0}}}}


@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> tuple[Path, np.ndarray]:
    d = tmp_path_factory.mktemp("export")
    recs = simulate_run(1500, CFG)
    log = write_log(d / "run.mcap", recs, CFG)
    assert main(["export", str(log), "--out", str(d / "run.csv"), "--precision", "17"]) == 0
    return d / "run.csv", recs


def test_standard_columns_follow_the_mapping(exported) -> None:
    csv, r = exported
    tab = read_table(csv)
    assert len(tab) == 1500
    np.testing.assert_array_equal(tab["t"], r["t_s"])
    # r_in comes from the logged config (0.05, not the 0.04 default)
    np.testing.assert_array_equal(tab["tau_in"], 0.05 * (r["T_up_in_N"] - r["T_lo_in_N"]))
    np.testing.assert_array_equal(tab["T_lc_in"], 0.5 * (r["T_up_in_N"] + r["T_lo_in_N"]))
    np.testing.assert_array_equal(tab["T_lc_out"], 0.5 * (r["T_up_out_N"] + r["T_lo_out_N"]))
    np.testing.assert_array_equal(tab["q_in"], r["q_m_rad"])
    np.testing.assert_array_equal(tab["q_out"], r["q_out_rad"])
    np.testing.assert_array_equal(tab["dq_out"], r["dq_out_rad_s"])
    # pretension ~150 N, sine of 3 Nm amplitude at the input
    assert abs(tab["T_lc_in"].mean() - 150.0) < 0.5
    assert 2.5 < np.abs(tab["tau_in"]).max() * 0.04 / 0.05 < 3.5


def test_every_record_field_is_an_extra_column(exported) -> None:
    csv, r = exported
    tab = read_table(csv)
    for name in r.dtype.names:
        np.testing.assert_array_equal(tab[name], r[name].astype(np.float64))
    assert "tau_out" not in tab.columns          # no output torque sensor in the record


def test_sidecar_holds_geometry_and_units(exported) -> None:
    csv, _ = exported
    meta = yaml.safe_load(csv.with_suffix(".yaml").read_text())
    assert meta["r_in"] == 0.05 and meta["r_out"] == 0.045 and meta["mu"] == 0.06
    assert meta["length"] == pytest.approx(1.2)
    assert meta["units"]["tau_in"] == "Nm" and "[N]" in meta["units"]["T_up_in_N"]
    assert meta["curvature_profile"]


def test_generic_dtype_without_tensions_has_no_torque(tmp_path: Path) -> None:
    dt = np.dtype([("t_s", "<f8"), ("q_out_rad", "<f8")])
    r = np.zeros(3, dt)
    r["t_s"] = [1, 2, 3]
    with pytest.raises(DataFormatError, match="torque column"):
        records_to_table(r, {})
    dt2 = np.dtype([("x", "<f8")])
    with pytest.raises(DataFormatError, match="t_s"):
        records_to_table(np.zeros(2, dt2), {})


def test_non_increasing_time_is_refused(tmp_path: Path) -> None:
    r = simulate_run(20, CFG)
    r["t_s"][10] = r["t_s"][9]
    log = McapLog(tmp_path, "bad", r.dtype, yaml.safe_dump(CFG), first_path=tmp_path / "bad.mcap")
    log.write_records(r)
    log.close()
    assert main(["export", str(tmp_path / "bad.mcap"), "--out", str(tmp_path / "bad.csv")]) == 2
