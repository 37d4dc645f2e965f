"""Uncertainty of a selected in-model effect (models/closure/dynamic/uncertainty.py): standard
errors from the linearised fit (block sandwich over 0.5 s windows), intervals from the
linearised block bootstrap, and the "no effect" test that keeps a marginal finding out of the
selection.

* with the input load cell reading 6 % high (the closure's torsional unit, tests/test_closure_inmodel.py),
  the drive gain's 95 % interval covers the injected eps = 1 / 1.06 - 1 and excludes 0, and
  "no effect" is rejected;
* on clean runs the same candidate's interval includes 0 and "no effect" is not rejected (it
  would not be selected);
* the block sandwich of a linear model with independent noise is the textbook covariance
  (within the scatter of its 16 windows);
* ``close`` writes them into the JSON summary (``selected[].params_stderr`` /
  ``params_interval``) and the report (``value +- stderr``, the intervals).

The runs here are the closure's own unit; the independent evidence of the words and the
empirical curve's interval is in tests/test_closure_families_independent.py.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from capstan.models.closure.dynamic.closure import setup
from capstan.models.closure.dynamic.in_model import InModelCloser, JointFit
from capstan.models.closure.dynamic.uncertainty import effect_uncertainty, named_uncertainty, sandwich
from capstan.models.closure.pipeline import close
from capstan.tools.offline.closure_report import summary, write_report

from test_closure_drive_gain import EPS_TRUE, REFS, _gain, _pair

pytestmark = pytest.mark.slow


def _fitted(runs):
    train, test = runs
    ds = setup(train, test)
    closer = InModelCloser(ds.fit, train, test)
    jf, _, _ = closer.joint_pair(JointFit(np.array(list(ds.fit.params.values()))), _gain(train))
    return closer, jf, list(ds.fit.params)


@pytest.fixture(scope="module")
def gain_fit():
    return _fitted(_pair(1.06))


@pytest.fixture(scope="module")
def clean_fit():
    return _fitted(_pair(1.0))


def test_the_injected_gain_lies_inside_its_interval_and_no_effect_is_rejected(gain_fit) -> None:
    closer, jf, names = gain_fit
    unc = effect_uncertainty(closer, jf)
    se, ci = named_uncertainty(jf, unc, names, REFS)
    eps = float(jf.effects[-1][2][0])
    lo, hi = ci["eps"]
    assert lo <= EPS_TRUE <= hi, (eps, ci["eps"])
    assert 0.0 < se["eps"] < 0.25 * abs(EPS_TRUE)           # a finding, not a marginal one
    assert hi < 0.0 and not unc.no_effect and unc.p_value < 1e-3, (unc.wald, unc.p_value)
    # the feedforward's named parameter carries its own error (1 / (1 + eps) - 1 ~ -eps)
    assert se["load_cell_gain_error"] == pytest.approx(se["eps"], rel=0.2)


def test_on_clean_runs_the_interval_includes_zero_and_it_is_not_an_effect(clean_fit) -> None:
    closer, jf, names = clean_fit
    unc = effect_uncertainty(closer, jf)
    _, ci = named_uncertainty(jf, unc, names, REFS)
    lo, hi = ci["eps"]
    assert lo <= 0.0 <= hi, ci["eps"]
    assert unc.no_effect, (unc.wald, unc.p_value)


def test_the_block_sandwich_of_a_linear_fit_is_the_textbook_covariance() -> None:
    rng = np.random.default_rng(3)
    n, sigma = 16_000, 0.2
    J = np.column_stack([np.ones(n), np.linspace(-1.0, 1.0, n)])
    r = sigma * rng.standard_normal(n)
    labels = np.repeat(np.arange(16), n // 16)
    _, G, cov = sandwich(J, r, labels)
    textbook = sigma ** 2 * np.linalg.inv(J.T @ J)
    # 16 windows: the variance estimate scatters by sqrt(2 / 16) = 35 %; 2 x that
    np.testing.assert_allclose(np.diag(cov), np.diag(textbook), rtol=0.7)
    assert G.shape == (16, 2)



def test_close_writes_the_errors_into_the_json_and_the_report(tmp_path) -> None:
    res = close(*_pair(1.06))
    summ = summary(res, ["train"], ["test"], "reduced")
    sel = summ["selected"][0]
    assert sel["effect"] == "drive_gain"
    lo, hi = sel["params_interval"]["load_cell_gain_error"]
    assert lo <= 0.06 <= hi and sel["params_stderr"]["load_cell_gain_error"] > 0.0
    json.dumps(summ)                                           # JSON-able
    text = write_report(res, summ, tmp_path, []).read_text()
    assert f"load_cell_gain_error={sel['params']['load_cell_gain_error']:.4g} +- " in text
    assert "95 % intervals" in text
