"""`capstan simulate`: scenario file -> measurement table + sidecar + plots."""

import math

import numpy as np
import yaml

from capstan.tools.cli import main
from capstan.models.common.measurement_table import read_table

SCENARIO = {
    "name": "unit",
    "duration_s": 4.0,
    "seed": 2,
    "transmission": {"n_nodes": 6},
    "routing": {"length_m": 1.379, "theta_rad": 3.0},
    "pretension": {"T0_N": 150.0},
    "output": {"mode": "testbed", "k_out_Nm_rad": 20.0, "b_out_Nms_rad": 2.0},
    "excitation": {"components": [{"amplitude_Nm": 8.0, "frequency_hz": 0.5}], "fade_in_s": 0.5},
}


def _write(tmp_path, sc):
    p = tmp_path / "sc.yaml"
    p.write_text(yaml.safe_dump(sc))
    return p


def test_simulate_writes_table_sidecar_and_plots(tmp_path, capsys):
    sc = _write(tmp_path, SCENARIO)
    out = tmp_path / "run.csv"
    assert main(["simulate", str(sc), "--out", str(out), "--plot"]) == 0
    tab = read_table(out)
    assert len(tab) == 4001
    for col in ("t", "tau_in", "tau_out", "q_in", "q_out", "dq_out", "T_lc_in", "T_lc_out"):
        assert tab.has(col)
    meta = tab.meta
    assert meta["r_in"] == 0.04 and meta["mu"] == 0.052
    assert meta["environment"] == {"k_out": 20.0, "b_out": 2.0}
    # the curvature profile in the sidecar integrates to the routing's bending angle
    prof = np.asarray(meta["curvature_profile"])
    assert np.trapezoid(prof[:, 1], prof[:, 0]) == np.float64(3.0) or abs(np.trapezoid(prof[:, 1], prof[:, 0]) - 3.0) < 1e-6
    # T0_eq of uniform curvature: 2 T0 exp(-mu theta / 2)  (eq 25)
    assert meta["T0_eq_N"] == __import__("pytest").approx(2 * 150.0 * math.exp(-0.052 * 3.0 / 2), rel=1e-6)
    # environment law (eq 22) holds on the output: tau_out = k q + b dq (up to sensor noise)
    resid = tab["tau_out"] - (20.0 * tab["q_out"] + 2.0 * tab["dq_out"])
    assert np.sqrt(np.mean(resid[500:] ** 2)) < 0.05
    # friction loses torque: |tau_out| peaks below |tau_in| peaks
    assert np.max(np.abs(tab["tau_out"])) < np.max(np.abs(tab["tau_in"])) - 0.5
    for suffix in ("_torque.png", "_deflection.png", "_time.png"):
        assert (tmp_path / f"run{suffix}").stat().st_size > 1000


def test_slack_scenario_is_a_clear_error_not_nan(tmp_path, capsys):
    sc = dict(SCENARIO, pretension={"T0_N": 20.0},
              excitation={"components": [{"amplitude_Nm": 10.0, "frequency_hz": 0.5}], "fade_in_s": 0.1})
    out = tmp_path / "slack.csv"
    assert main(["simulate", str(_write(tmp_path, sc)), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("capstan simulate: ") and "slack" in err.lower() and len(err.splitlines()) == 1
    assert not out.exists()


def test_bad_scenario_key_is_refused(tmp_path, capsys):
    sc = dict(SCENARIO, routing={"length_m": 1.379, "theta": 3.0})
    assert main(["simulate", str(_write(tmp_path, sc)), "--out", str(tmp_path / "x.csv")]) == 2
    assert "routing.theta" in capsys.readouterr().err
