"""The closure's selection rules on their own, without a fit (fast; the closures that use them are the
slow tests): catalogue first (:func:`capstan.models.closure.scoring.select_winner`), the materiality bar
as documented, and the block bootstrap's point improvement and lower bound against their definitions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capstan.models.closure import pipeline, scoring
from capstan.models.closure.effects import Target
from capstan.models.closure.scoring import Candidate, block_bootstrap, select_winner


def _cand(effect: str, improvement: float) -> Candidate:
    return Candidate(effect, ["x"], Target.TAU_OUT, 0, {}, {}, 0.1, 0.2, improvement, improvement / 2, True)


def _is_empirical(c: Candidate) -> bool:
    return c.effect.startswith("empirical:")


@pytest.mark.parametrize("cat, emp, winner", [
    (0.26, 0.28, "position_friction"),      # the README's eccentric-pulley case: 26 % >= 0.7 x 28 %
    (0.20, 0.28, "position_friction"),      # 0.20 >= 0.196
    (0.19, 0.28, "empirical:q_in"),         # 0.19 < 0.196
    (0.40, 0.10, "position_friction"),
])
def test_catalogue_first_takes_the_catalogued_form_at_70_percent_of_the_best_curve(cat: float, emp: float,
                                                                                      winner: str) -> None:
    """Of the significant candidates the best catalogued one wins if it reaches 0.7 x the best empirical
    improvement (scoring module docstring); the best of each kind is compared, not the first."""
    cands = [_cand("speed_viscous", cat / 2), _cand("position_friction", cat), _cand("empirical:velocity", emp / 3),
             _cand("empirical:q_in", emp)]
    assert select_winner(cands, _is_empirical).effect == winner
    assert select_winner(cands[::-1], _is_empirical).effect == winner


def test_a_single_kind_wins_alone_and_an_empty_round_is_refused() -> None:
    assert select_winner([_cand("empirical:time", 0.01)], _is_empirical).effect == "empirical:time"
    assert select_winner([_cand("dwell_stiction", 0.01)], _is_empirical).effect == "dwell_stiction"
    with pytest.raises(ValueError, match="at least one significant"):
        select_winner([], _is_empirical)


def test_the_materiality_bar_is_the_documented_5_percent() -> None:
    """The bar a significant candidate must clear is the one the closures' docstrings state (both
    import it from scoring): a change of the value must change the words."""
    assert f"least ``MATERIAL`` ({scoring.MATERIAL * 100:.0f} % lower held-out RMSE)" in " ".join(scoring.__doc__.split())
    assert f"({pipeline.MATERIAL * 100:.0f} % lower held-out RMSE)" in " ".join(pipeline.__doc__.split())
    assert pipeline.MATERIAL == scoring.MATERIAL


def test_block_bootstrap_point_and_bound_against_their_definitions() -> None:
    """Point: 1 - sqrt(SSE_after / SSE_before) over all samples; bound: the 5 % quantile of the same over
    resampled blocks, so below the point for a noisy gain and equal to it when every block gains alike."""
    rng = np.random.default_rng(0)
    n, nb = 4000, 20
    labels = np.repeat(np.arange(nb), n // nb)
    before = rng.normal(0.0, 1.0, n)
    after = 0.8 * before
    point, low = block_bootstrap(before, after, labels)
    assert point == pytest.approx(0.2, abs=1e-12) and low == pytest.approx(0.2, abs=1e-12)
    after = before * np.where(labels % 2 == 0, 0.6, 1.0)         # half the blocks gain, half do not
    point, low = block_bootstrap(before, after, labels)
    assert point == pytest.approx(1.0 - math.sqrt(np.sum(after ** 2) / np.sum(before ** 2)), abs=1e-12)
    assert 0.0 < low < point
