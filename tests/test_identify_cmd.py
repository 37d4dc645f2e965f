"""``capstan identify`` (tools/commands/identify.py over models/closure/identification.py)
on runs of the independent plant (tests/independent_runs.py: written from the paper, no
package code; motor-driven rig, testbed output, load cells / torque sensor / encoder / gyro
with noise and quantisation).

What the fit claims (its docstring) and what is checked here:

* the elastic path gives K_c exactly for N = 1 -- on five independent 1-node runs K_c (truth
  240 Nm/rad), and the testbed environment k_out, b_out (eq 22, exact for the massless
  testbed: truth 20 Nm/rad, 2 N m s/rad) lie within 2 stated standard errors of the truth on
  >= 4 of 5 seeds (measured: 5 of 5, |error| / se <= 1.6);
* the stated 1-sigma is honest: the seed-to-seed spread of those three over five seeds is
  within a factor 3 of the mean stated error (five seeds put the sample deviation alone at
  0.4-1.5 x sigma; measured ratios 0.7-1.1);
* the friction map's parameters (ratio g, offset c, tau_fc): their stated error does *not*
  cover the spread over excitations (measured spread / se: ratio 3.4, offset 4.2, tau_fc 1.4) -- the
  static friction-on-velocity form is misspecified on a dynamic run, and the block sandwich
  sees only one excitation. Recorded as a strict xfail with the figures.
* the CLI's JSON carries the fit of :func:`fit_baseline` on the same file exactly, the text
  mode prints every parameter, and bad input exits 2 naming what is wrong.

Measured on 12-node runs (not asserted: the elastic sum is exact for N = 1 only): K_c
247-253 Nm/rad (se 1.4-3.1), +3 to +5 % from the end tensions not averaging the cable.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

from capstan.models.closure.identification import BaselineFit, ModelKind, fit_baseline
from capstan.models.closure.signals import signals_from_tables
from capstan.models.common.measurement_table import MeasurementTable, read_table, write_table
from capstan.tools.cli import main
from tests.independent_runs import rig_run

SEEDS = (0, 1, 2, 3, 4)
TRUTH = {"K_c_Nm_rad": ("elastic", 240.0), "k_out_Nm_rad": ("environment", 20.0),
         "b_out_Nms_rad": ("environment", 2.0)}


@lru_cache(maxsize=None)
def _fit(seed: int) -> BaselineFit:
    table, _ = rig_run("none", 100 + seed, 20.0, 2.0, 10.0, n_nodes=1)
    return fit_baseline(signals_from_tables([table]))


def _value(fit: BaselineFit, name: str) -> tuple[float, float]:
    if name in fit.params:
        return fit.params[name], fit.stderr[name]
    group = fit.extra[TRUTH[name][0]]
    return group[name], group[f"{name}_se"]


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(TRUTH))
def test_stiffness_and_environment_are_recovered_within_their_stated_error(name: str) -> None:
    truth = TRUTH[name][1]
    got = [_value(_fit(s), name) for s in SEEDS]
    z = [abs(v - truth) / se for v, se in got]
    assert sum(x <= 2.0 for x in z) >= 4, got
    spread = float(np.std([v for v, _ in got], ddof=1))
    stated = float(np.mean([se for _, se in got]))
    assert 1 / 3 <= spread / stated <= 3.0, (spread, stated)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="friction-map parameters vary over excitations 3-4x their stated 1-sigma "
                                       "(5 seeds, 1-node runs: ratio spread 0.056 vs se 0.017, offset 0.28 vs 0.067)")
def test_the_friction_map_error_covers_the_spread_over_excitations() -> None:
    for name in ("ratio", "offset_Nm", "tau_fc_Nm"):
        got = [_value(_fit(s), name) for s in SEEDS]
        spread = float(np.std([v for v, _ in got], ddof=1))
        stated = float(np.mean([se for _, se in got]))
        assert spread / stated <= 3.0, (name, spread, stated)


@pytest.fixture(scope="module")
def run_csv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    table, _ = rig_run("none", 7, 20.0, 2.0, 3.0, n_nodes=1)
    return write_table(table, tmp_path_factory.mktemp("identify") / "run.csv")


def test_json_output_is_the_fit_of_the_file(run_csv: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["identify", str(run_csv), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    table = read_table(run_csv)
    fit = fit_baseline(signals_from_tables([table]))
    assert out["model"] == "reduced" and out["data"] == [str(run_csv)]
    assert out["n_samples"] == len(table) == 3000
    assert out["params"] == fit.params and out["stderr"] == fit.stderr      # identical data: exact
    assert out["rmse_Nm"] == fit.rmse_Nm and out["max_err_Nm"] == fit.max_err_Nm
    assert out["elastic"] == fit.extra["elastic"] and out["environment"] == fit.extra["environment"]
    assert set(out["params"]) == {"ratio", "tau_fc_Nm", "stiction_excess_Nm", "b_vis_Nms_rad", "offset_Nm",
                                  "alpha_s_rad", "eta_s_rad_s", "zeta_s"}
    assert all(np.isfinite(v) and v >= 0 for v in out["stderr"].values())
    assert out["elastic"]["K_c_Nm_rad"] == pytest.approx(240.0, rel=0.01)  # 3 s of data: se ~0.1 Nm/rad


def test_text_output_lists_every_parameter(run_csv: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["identify", str(run_csv), "--model", "wu"]) == 0
    text = capsys.readouterr().out
    fit = fit_baseline(signals_from_tables([read_table(run_csv)]), ModelKind.WU)
    assert text.startswith("model: wu   runs: 1   samples: 3000")
    for name in fit.params:
        assert f"  {name} " in text
    assert "[elastic] K_c_Nm_rad=" in text and "fit error: RMSE" in text


def test_bad_input_exits_2_naming_the_problem(run_csv: Path, tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["identify", str(run_csv), "--model", "distributed"]) == 2
    err = capsys.readouterr().err                  # one line on stderr, no traceback
    assert "unobservable" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    table = read_table(run_csv)
    cols = {k: v for k, v in table.columns.items() if k != "tau_out"}
    bad = write_table(MeasurementTable(cols, dict(table.meta), "bad"), tmp_path / "bad.csv")
    assert main(["identify", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "tau_out" in err and "Traceback" not in err
