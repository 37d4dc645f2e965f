"""The paper reproduction's plants and pretension models (tools/experiments/paper/common.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capstan.models.common.errors import ModelError
from capstan.models.transmission.pretension import pretension_field, segment_tensions_N
from capstan.tools.experiments.paper.common import (MU, OUTPUTS, Settings, effective_mu, group_routing, simulate_plant,
                                                    sine, transmission)


def test_imbalanced_plant_is_a_static_field_with_the_same_load_cell_mean() -> None:
    s = Settings.quick_settings()
    r = group_routing(0)                                   # theta = 6 rad: the largest imbalance
    run = simulate_plant(r, sine(1e-6), s, OUTPUTS["stiff"], imbalanced=True, n_nodes=8, duration_s=0.02,
                         record_tensions=True)
    up, lo = run.tensions_upper_N[0], run.tensions_lower_N[0]
    # upper cable tighter at its input fixture, lower cable at its output fixture, by 1 +/- tanh(0.8 mu theta / 2)
    x = math.tanh(0.8 * MU * r.theta_total_rad / 2.0)
    assert up[0] == pytest.approx(150.0 * (1 + x), rel=1e-6) and up[-1] == pytest.approx(150.0 * (1 - x), rel=1e-6)
    assert lo[0] == pytest.approx(150.0 * (1 - x), rel=1e-6) and lo[-1] == pytest.approx(150.0 * (1 + x), rel=1e-6)
    # the four fixture tensions average to the nominal pretension: what the models see is unchanged
    assert np.mean([up[0], up[-1], lo[0], lo[-1]]) == pytest.approx(150.0, rel=1e-9)
    # inside the capstan ratio: a field friction can hold at rest (not clipped)
    assert abs(math.log(up[0] / up[-1])) < MU * r.theta_total_rad
    assert not pretension_field(r, MU, up[0], up[-1]).clipped
    # each cable is the eq 23 field of its own (unequal) ends, not the symmetric field the models assume
    assert np.allclose(up, segment_tensions_N(r, MU, up[0], up[-1], 8), rtol=1e-9)
    assert np.allclose(lo, segment_tensions_N(r, MU, lo[0], lo[-1], 8), rtol=1e-9)
    sym = segment_tensions_N(r, MU, 150.0, 150.0, 8)
    assert np.max(np.abs(up - sym)) > 10.0 and np.max(np.abs(lo - sym)) > 10.0


def test_effective_mu_is_the_normal_force_weighted_node_friction() -> None:
    r = group_routing(4)
    trans = transmission(r, 6, 150.0, 150.0)
    assert effective_mu(trans, np.ones(12)) == pytest.approx(MU, rel=1e-12)
    scale = np.ones(12)
    scale[2] = 3.0
    w_up = trans.theta_upper_rad * 0.5 * (trans.tension_upper_N[1:] + trans.tension_upper_N[:-1])
    w_lo = trans.theta_lower_rad * 0.5 * (trans.tension_lower_N[1:] + trans.tension_lower_N[:-1])
    expected = MU * (w_up.sum() + w_lo.sum() + 2.0 * w_up[2]) / (w_up.sum() + w_lo.sum())
    assert effective_mu(trans, scale) == pytest.approx(expected, rel=1e-12)


def test_pretension_models_of_the_predictions() -> None:
    r = group_routing(0)
    f = pretension_field(r, MU, 150.0, 150.0)
    fric = transmission(r, 4, 150.0, 150.0, pretension="friction_preserving")
    mini = transmission(r, 4, 150.0, 150.0, pretension="field_minimum")
    dist = transmission(r, 4, 150.0, 150.0)
    assert np.allclose(fric.tension_upper_N, f.T0_eq_friction_N / 2.0) and np.allclose(mini.tension_lower_N, f.T_min_N)
    # the eq 23 field lies between its minimum and its ends; the friction-preserving springs in between
    assert mini.tension_upper_N[0] < fric.tension_upper_N[0] < dist.tension_upper_N[0] == pytest.approx(150.0)
    with pytest.raises(ModelError, match="eq 25 reading"):
        transmission(r, 4, 150.0, 150.0, pretension="averaged")
