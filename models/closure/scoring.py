"""What a closure round produces and how it is scored: the candidates and the target's
result (:class:`Candidate`, :class:`TargetResult`), and the held-out significance test.

Significance: the held-out data are cut into contiguous blocks (``BLOCK_S`` seconds,
never crossing a run); a block bootstrap (``N_BOOT`` resamples of blocks) of
``1 - sqrt(sum SSE_after / sum SSE_before)`` gives a one-sided 95 % lower bound. A
candidate is *significant* when that bound is > 0 and the point improvement is at
least ``MATERIAL`` (5 % lower held-out RMSE).

Catalogue first (:func:`select_winner`, both closures): of the significant candidates the best catalogue effect
is taken if it achieves at least ``PREFER_CATALOGUE`` of the best empirical improvement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from capstan.models.closure.effects import EffectSpec, Target
from capstan.models.closure.signals import Signals

MATERIAL = 0.05
BLOCK_S = 2.0
N_BOOT = 400


@dataclass
class Candidate:
    """One candidate tried in one round (see the module docstring for the scores)."""

    effect: str
    depends_on: list[str]
    target: Target
    round: int
    shape: dict
    params: dict[str, float]
    rmse_Nm: float
    max_err_Nm: float
    improvement: float
    ci_low: float
    significant: bool
    spec: EffectSpec | None = None
    F_train: np.ndarray | None = None
    F_test: np.ndarray | None = None
    description: dict | None = None
    #: the augmented model's baseline parameters refitted with this candidate (friction path)
    baseline_params: dict[str, float] | None = None
    #: held-out samples the scores are computed on (0: not recorded or not scored)
    held_out_samples: int = 0
    #: why the candidate was not scored on the held-out runs (long runs), else ""
    screened_out: str = ""
    #: why its fitted coefficients are outside the mechanism's physical range (then not
    #: significant), else ""
    implausible: str = ""
    #: standard errors and 95 % intervals of the selected effect's parameters (the keys of
    #: ``params`` and ``shape`` that were fitted; :mod:`capstan.models.closure.dynamic.uncertainty`)
    params_stderr: dict[str, float] | None = None
    params_interval: dict[str, list[float]] | None = None
    #: level at which "no effect" is rejected (NaN: not tested); why it was not selected, else ""
    no_effect_p: float = math.nan
    no_effect: str = ""
    #: the shape and size of a catalogued slow form in words (:mod:`capstan.models.closure.shape_words`), else ""
    words: str = ""

    def summary(self) -> dict:
        """JSON-able summary."""
        d = {"effect": self.effect, "depends_on": list(self.depends_on), "target": self.target.name.lower(),
             "round": self.round, "rmse_Nm": self.rmse_Nm, "max_err_Nm": self.max_err_Nm,
             "improvement": self.improvement, "improvement_ci_low": self.ci_low, "significant": self.significant}
        if self.held_out_samples:
            d["held_out_samples"] = self.held_out_samples
        if self.screened_out:
            d["screened_out"] = self.screened_out
        if self.implausible:
            d["implausible"] = self.implausible
        if self.params_stderr is not None:
            d["params"] = {**self.params, **{k: v for k, v in self.shape.items() if k in self.params_stderr}}
            d["params_stderr"] = self.params_stderr
            d["params_interval"] = self.params_interval
            d["no_effect_p"] = self.no_effect_p
        if self.no_effect:
            d["no_effect"] = self.no_effect
        if self.description:
            d["description"] = self.description["text"]
        elif self.words:
            d["description"] = self.words
        return d


@dataclass
class TargetResult:
    """Closure of one target (the friction path tau_out, or the elastic path)."""

    target: Target
    y_test: np.ndarray
    pred_before: np.ndarray
    pred_after: np.ndarray
    rmse_before_Nm: float
    max_before_Nm: float
    rmse_after_Nm: float
    max_after_Nm: float
    candidates: list[Candidate] = field(default_factory=list)
    selected: list[Candidate] = field(default_factory=list)
    theta: np.ndarray | None = None
    #: the residual trace of the dynamic closure (signal, explained, improvement), best first
    trace: list[dict] = field(default_factory=list)
    #: friction path: the baseline's parameters as refitted in the final augmented model
    #: (linear ones, alpha_s_rad, eta_s_rad_s, zeta_s); the selected effects' coefficients
    #: belong with these, not with the baseline fitted alone
    params_after: dict[str, float] = field(default_factory=dict)


def _rmse(r: np.ndarray) -> float:
    return float(np.sqrt(np.mean(r ** 2))) if r.size else math.nan


def test_blocks(sig: Signals, block_s: float = BLOCK_S) -> np.ndarray:
    """Block label per held-out sample: contiguous ~block_s pieces inside each run (>= 8 blocks)."""
    labels = np.empty(len(sig), dtype=np.int64)
    dt = float(np.median(np.diff(sig.t_s))) if len(sig) > 1 else 1e-3
    per = max(50, int(block_s / max(dt, 1e-6)))
    per = min(per, max(50, len(sig) // 8))
    k = 0
    for a, b in sig.segments():
        m = b - a
        nb = max(1, int(round(m / per)))
        labels[a:b] = k + np.minimum((np.arange(m) * nb) // m, nb - 1)
        k += nb
    return labels


def block_bootstrap(r_before: np.ndarray, r_after: np.ndarray, labels: np.ndarray,
                    n_boot: int = N_BOOT, seed: int = 12345, alpha: float = 0.05) -> tuple[float, float]:
    """(point improvement, one-sided ``1 - alpha`` lower bound) of the relative RMSE reduction."""
    nb = int(labels.max()) + 1
    sb = np.bincount(labels, r_before ** 2, nb)
    sa = np.bincount(labels, r_after ** 2, nb)
    point = 1.0 - math.sqrt(sa.sum() / max(sb.sum(), 1e-300))
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, nb, size=(n_boot, nb))
    boots = 1.0 - np.sqrt(sa[idx].sum(axis=1) / np.maximum(sb[idx].sum(axis=1), 1e-300))
    return point, float(np.quantile(boots, alpha))


#: a catalogue candidate is preferred when it achieves this share of the best empirical one
PREFER_CATALOGUE = 0.7


def select_winner(significant: list[Candidate], empirical: Callable[[Candidate], bool]) -> Candidate:
    """The round's winner among ``significant`` (not empty): the best catalogue candidate if its improvement is
    at least ``PREFER_CATALOGUE`` x the best empirical one's (``empirical`` tells which is which), else that
    empirical one.

    :raises ValueError: if ``significant`` is empty."""
    if not significant:
        raise ValueError("select_winner needs at least one significant candidate")
    cat = [c for c in significant if not empirical(c)]
    emp = [c for c in significant if empirical(c)]
    best_cat = max(cat, key=lambda c: c.improvement) if cat else None
    best_emp = max(emp, key=lambda c: c.improvement) if emp else None
    if best_cat is not None and (best_emp is None or best_cat.improvement >= PREFER_CATALOGUE * best_emp.improvement):
        return best_cat
    assert best_emp is not None
    return best_emp
