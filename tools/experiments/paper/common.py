"""Shared pieces of the paper reproduction (:mod:`capstan.tools.experiments.paper.experiment`): settings, the ten
routing groups, "measured" runs of the full distributed plant and model predictions.

**Measured runs.** The ground truth is the distributed model with ``n_true`` nodes (50 in the
full run) on the routing's curvature profile with the capstan pretension field of eq (23),
driven by the commanded input torque on the testbed output ``tau_out = k_out q + b_out dq``.
Sensor noise of :class:`capstan.models.plant.rig.SensorNoise` is added to the recorded torques and angles.
With ``effects=True`` the plant also carries effects none of the predicting models contain:

* node friction varying along the sheath (``mu_scale`` log-normal, 20 % spread, fixed seed) -
  local wear / lubrication differences the specification-based models cannot see;
* a pretension asymmetry between the cables (+/- ``asym`` of the nominal boundary value,
  same mean, so the load-cell average the models use is unchanged).

With ``imbalanced=True`` (a plant of another structure, labelled "imbalanced" in the report)
each cable is also tensioned unevenly along its length: the upper cable holds more at its
input fixture, the lower cable at its output fixture, ``T_a,b = T (1 +/- tanh(x))`` with
``x = imbalance * mu theta / 2`` (inside the capstan ratio, so it is a static field; the
mean of the four fixture tensions, all the models see, is unchanged). The two fields are
skewed in opposite directions, which no symmetric-pretension model (distributed with the
load-cell mean, or reduced) can represent.

**Pretension models of the predictions** (:data:`PRETENSION_MODELS`): ``distributed`` is the
eq 23 field sampled at the N + 1 springs; ``field_minimum`` and ``friction_preserving`` put
every spring at ``T0_eq / 2`` of eq 25 in its two readings
(:class:`capstan.models.transmission.pretension.Eq25Reading`).

Predictions are driven by the *measured* (noisy) input torque.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from capstan.models.distributed.model import BoundaryParams, DistributedModel, TransmissionParams
from capstan.models.plant.excitation import Multisine, SineComponent
from capstan.models.transmission.pretension import (Eq25Reading, pretension_field, segment_tensions_N,
                                                   uniform_segment_tensions_N)
from capstan.models.plant.rig import SensorNoise
from capstan.models.transmission.routing import Routing

MU = 0.052             #: sheath friction coefficient of the reference rig [-]
LENGTH_M = 1.379       #: routing length [m]
R_M = 0.04             #: pulley radius (in and out) [m]
K_C_NM_RAD = 240.0     #: configured torsional stiffness [Nm/rad]

#: testbed outputs: stiffness-dominated and damping-dominated (k_out [Nm/rad], b_out [Nm s/rad])
OUTPUTS: dict[str, tuple[float, float]] = {"stiff": (30.0, 0.3), "damped": (2.0, 4.0)}

#: pretension models of the predictions: eq 23 field, and eq 25 in its two readings
PRETENSION_MODELS: tuple[str, ...] = ("distributed", "field_minimum", "friction_preserving")

#: accumulated bending of the ten routing groups theta_1 (strongly bent) ... theta_10 (near flat) [rad]
GROUP_THETA_RAD = (6.0, 5.2, 4.5, 3.8, 3.1, 2.5, 1.9, 1.3, 0.7, 0.3)


@dataclass(frozen=True)
class Settings:
    """Grid sizes and durations of one reproduction run.

    :ivar n_true: nodes of the ground-truth distributed plant.
    :ivar duration_s: simulated time of each prediction run [s].
    :ivar sample_rate_hz: rows per second of the measured runs.
    :ivar n_list: discretisations N evaluated in Fig. 9-10.
    :ivar groups: indices (0-based) of the routing groups evaluated.
    :ivar pretension_N: nominal boundary pretension of the prediction runs [N].
    :ivar asym: cable pretension asymmetry of the unmodelled-effects plant [-].
    :ivar interaction_s: simulated time per interaction run (Fig. 13) [s].
    :ivar seed: noise / effects seed of the first realisation.
    :ivar n_seeds: realisations (seed, seed + 1, ...) of noise and plant effects for the spreads.
    :ivar n_starts: starting points of each multi-start identification (Fig. 11).
    :ivar imbalance: along-cable pretension imbalance of the "imbalanced" plant, as a fraction
        of the capstan ratio's half-log ``mu theta / 2`` [-].
    """

    n_true: int = 50
    duration_s: float = 20.0
    sample_rate_hz: float = 500.0
    n_list: tuple[int, ...] = tuple(range(1, 21))
    groups: tuple[int, ...] = tuple(range(10))
    pretension_N: float = 150.0
    asym: float = 0.06
    interaction_s: float = 24.0
    seed: int = 0
    quick: bool = False
    n_seeds: int = 3
    imbalance: float = 0.8
    n_starts: int = 10

    @property
    def seeds(self) -> tuple[int, ...]:
        """The noise / effects seeds of the spread: ``seed .. seed + n_seeds - 1``."""
        return tuple(self.seed + k for k in range(max(1, self.n_seeds)))

    @staticmethod
    def quick_settings() -> "Settings":
        """Coarse grids for CI (a few minutes on 2 cores)."""
        return Settings(n_true=30, duration_s=10.0, sample_rate_hz=250.0, n_list=(1, 2, 4, 10, 20),
                        groups=(0, 1, 2, 4, 7, 9), interaction_s=6.5, quick=True)


def group_routing(j: int) -> Routing:
    """Routing group theta_{j+1} (j = 0..9): a curvature profile over L = 1.379 m.

    Even j: multi-bend profiles (two or three Gaussian bumps on a small base curvature,
    non-uniform, with localised high-curvature regions); odd j: one broad asymmetric bend.
    The profile is scaled so that ``int kappa ds`` equals :data:`GROUP_THETA_RAD` [j].

    :raises ValueError: if ``j`` is not in 0..9.
    """
    if not 0 <= j < len(GROUP_THETA_RAD):
        raise ValueError(f"routing group index must be 0..9, got {j}")
    s = np.linspace(0.0, LENGTH_M, 281)
    x = s / LENGTH_M

    def bump(c: float, w: float, a: float) -> np.ndarray:
        return a * np.exp(-0.5 * ((x - c) / w) ** 2)

    if j % 2 == 0:
        shape = 0.15 + bump(0.25, 0.06, 1.0) + bump(0.7, 0.08, 0.7) + (bump(0.5, 0.04, 0.5) if j % 4 == 0 else 0.0)
    else:
        shape = 0.2 + bump(0.4 + 0.03 * j, 0.18, 1.0)
    base = Routing.from_curvature_samples(s, shape)
    return Routing.from_curvature_samples(s, shape * (GROUP_THETA_RAD[j] / base.theta_total_rad))


def multisine(peak_Nm: float = 8.0) -> Multisine:
    """Three-term input torque (paper: 'superposition of sinusoids'), peak ``peak_Nm`` [Nm]."""
    a = peak_Nm / 1.9
    return Multisine((SineComponent(a, 0.15), SineComponent(0.6 * a, 0.37, 1.0), SineComponent(0.3 * a, 0.71, 2.0)),
                     fade_in_s=1.0)


def sine(peak_Nm: float = 8.0, frequency_hz: float = 0.2) -> Multisine:
    """Single sine input torque, faded in over 1 s."""
    return Multisine((SineComponent(peak_Nm, frequency_hz),), fade_in_s=1.0)


def transmission(routing: Routing, n: int, T_upper_N: float, T_lower_N: float,
                 pretension: str = "distributed", mu: float = MU,
                 ends_upper: tuple[float, float] = (1.0, 1.0),
                 ends_lower: tuple[float, float] = (1.0, 1.0)) -> TransmissionParams:
    """N-node transmission on ``routing`` with the named pretension model (:data:`PRETENSION_MODELS`):
    the eq (23) field, or every spring at ``T0_eq / 2`` of eq (25) in the named reading (one T0_eq
    per cable). ``ends_*`` scale the cable's (input, output) fixture tension (the imbalanced plant).

    :raises ConfigError: on invalid parameters. :raises ModelError: on invalid pretension or model name.
    """
    th = routing.segment_bending_rad(n)
    if pretension == "distributed":
        tu = segment_tensions_N(routing, mu, T_upper_N * ends_upper[0], T_upper_N * ends_upper[1], n)
        tl = segment_tensions_N(routing, mu, T_lower_N * ends_lower[0], T_lower_N * ends_lower[1], n)
    else:
        reading = Eq25Reading.parse(pretension)
        tu = uniform_segment_tensions_N(pretension_field(routing, mu, T_upper_N, T_upper_N).T0_eq(reading), n)
        tl = uniform_segment_tensions_N(pretension_field(routing, mu, T_lower_N, T_lower_N).T0_eq(reading), n)
    return TransmissionParams(th, th.copy(), tu, tl, stiffness_Nm_rad=K_C_NM_RAD, mu=mu, r_in_m=R_M, r_out_m=R_M)


@dataclass
class Run:
    """A measured (noisy) run; ``truth_*`` are the noise-free plant outputs."""

    t_s: np.ndarray
    tau_in_Nm: np.ndarray
    tau_out_Nm: np.ndarray
    q_in_rad: np.ndarray
    q_out_rad: np.ndarray
    dq_in_rad_s: np.ndarray
    dq_out_rad_s: np.ndarray
    fixture_N: np.ndarray                     #: (n, 4) noisy fixture tensions (up in, up out, lo out, lo in)
    truth_tau_out_Nm: np.ndarray
    tensions_upper_N: np.ndarray | None = None
    tensions_lower_N: np.ndarray | None = None
    wall_s: float = 0.0
    meta: dict[str, Any] = field(default_factory=dict)


def simulate_plant(routing: Routing, u: Multisine | Callable[[np.ndarray], np.ndarray], settings: Settings,
                   output: tuple[float, float] = OUTPUTS["stiff"], pretension_N: float | None = None,
                   effects: bool = False, n_nodes: int | None = None, duration_s: float | None = None,
                   record_tensions: bool = False, seed_offset: int = 0, imbalanced: bool = False,
                   seed: int | None = None) -> Run:
    """A measured run of the ground-truth distributed plant (see module doc).

    :param u: input torque [Nm]: an excitation or a function of time [s].
    :param imbalanced: the plant of another structure (opposite along-cable imbalance, module doc).
    :param seed: noise / effects seed (default ``settings.seed``); ``seed_offset`` varies it per run.
    :raises OperatingRangeError: on cable slack. :raises IntegrationError: on solver failure.
    """
    T0 = settings.pretension_N if pretension_N is None else pretension_N
    n = settings.n_true if n_nodes is None else n_nodes
    dur = settings.duration_s if duration_s is None else duration_s
    asym = settings.asym if effects else 0.0
    ends_u, ends_l = (1.0, 1.0), (1.0, 1.0)
    if imbalanced:
        x = math.tanh(settings.imbalance * MU * routing.theta_total_rad / 2.0)
        ends_u, ends_l = (1.0 + x, 1.0 - x), (1.0 - x, 1.0 + x)
    trans = transmission(routing, n, T0 * (1.0 + asym), T0 * (1.0 - asym), ends_upper=ends_u, ends_lower=ends_l)
    model = DistributedModel(trans, BoundaryParams(k_out_Nm_rad=output[0], b_out_Nms_rad=output[1]))
    rng = np.random.default_rng((settings.seed if seed is None else seed) + 1000 * seed_offset)
    mu_eff = MU
    if effects:
        model.mu_scale = np.exp(rng.normal(0.0, 0.2, 2 * n) - 0.02)
        mu_eff = effective_mu(trans, model.mu_scale)
    t = np.arange(int(round(dur * settings.sample_rate_hz)) + 1) / settings.sample_rate_hz
    ut = np.asarray(u.torque_Nm(t) if hasattr(u, "torque_Nm") else u(t), dtype=float)
    start = time.perf_counter()
    res = model.simulate(t, ut, adaptive=True, record_tensions=True)
    wall = time.perf_counter() - start
    nz = SensorNoise()
    fix = res.fixture_tensions_N + rng.normal(0.0, nz.tension_N, res.fixture_tensions_N.shape)
    return Run(t, res.tau_in_Nm + rng.normal(0.0, nz.torque_Nm, t.shape),
               res.tau_out_Nm + rng.normal(0.0, nz.torque_Nm, t.shape), res.q_in_rad.copy(),
               res.q_out_rad + rng.normal(0.0, nz.angle_rad, t.shape), res.dq_in_rad_s.copy(),
               res.dq_out_rad_s + rng.normal(0.0, nz.rate_rad_s, t.shape), fix, res.tau_out_Nm.copy(),
               res.tensions_upper_N if record_tensions else None,
               res.tensions_lower_N if record_tensions else None, wall,
               {"theta_rad": routing.theta_total_rad, "T0_N": T0, "n_nodes": n, "effects": effects,
                "imbalanced": imbalanced, "mu_effective": mu_eff, "k_out": output[0], "b_out": output[1]})


def effective_mu(trans: TransmissionParams, mu_scale: np.ndarray) -> float:
    """The single friction coefficient with the same total sliding friction as per-node ``mu_scale``.

    Node i's Coulomb friction is ``mu scale_i theta_i`` x its mean spring tension (eq 11/13), so the
    equivalent coefficient is ``mu`` times the normal-force-weighted mean of the scales (both cables,
    the initial field) - what an identification of mu on this plant should find.
    """
    w = np.concatenate([trans.theta_upper_rad * 0.5 * (trans.tension_upper_N[1:] + trans.tension_upper_N[:-1]),
                        trans.theta_lower_rad * 0.5 * (trans.tension_lower_N[1:] + trans.tension_lower_N[:-1])])
    return float(trans.mu * np.sum(w * mu_scale) / np.sum(w))


def predict_distributed(run: Run, routing: Routing, n: int, pretension: str, pretension_N: float,
                        output: tuple[float, float]) -> np.ndarray:
    """Output torque [Nm] the N-node distributed model predicts from the measured input torque,
    with the nominal symmetric pretension (the models know only the load-cell mean) in the named
    pretension model (:data:`PRETENSION_MODELS`).

    :raises OperatingRangeError: on cable slack. :raises IntegrationError: on solver failure.
    """
    model = DistributedModel(transmission(routing, n, pretension_N, pretension_N, pretension=pretension),
                             BoundaryParams(k_out_Nm_rad=output[0], b_out_Nms_rad=output[1]))
    return model.simulate(run.t_s, run.tau_in_Nm, adaptive=True, record_tensions=False).tau_out_Nm


def rmse(a: np.ndarray, b: np.ndarray, skip: int = 0) -> float:
    """Root-mean-square difference [same unit] after dropping the first ``skip`` samples."""
    d = np.asarray(a)[skip:] - np.asarray(b)[skip:]
    return float(np.sqrt(np.mean(d * d)))


def ratio(ours: float, paper: float) -> float:
    """ours / paper (NaN if the paper value is 0 or either is not finite)."""
    if not (math.isfinite(ours) and math.isfinite(paper)) or paper == 0.0:
        return math.nan
    return ours / paper


def row(quantity: str, paper: float | None, ours: float, unit: str, note: str = "", like_for_like: bool = True,
        spread: tuple[float, float, int] | None = None, rid: str = "") -> dict[str, Any]:
    """One report-table row: the paper's value, ours, their ratio and a note on disagreements.

    :param like_for_like: False when the paper's number is a different quantity or case than
        ours (the table then says so instead of a ratio).
    :param spread: ``(min, max, count)`` of ours over noise seeds / fit starts, if any.
    :param rid: short row id the report's agree/disagree sentences refer to.
    """
    comparable = paper is not None and like_for_like
    return {"quantity": quantity, "paper": paper, "ours": float(ours), "unit": unit,
            "ratio": ratio(float(ours), float(paper)) if comparable else None, "note": note,
            "like_for_like": comparable, "spread": list(spread) if spread is not None else None, "id": rid}


def spread_of(values: Any) -> tuple[float, float, int]:
    """``(min, max, count)`` of the finite values (NaN, NaN, 0 when none)."""
    v = np.asarray(values, dtype=float).ravel()
    v = v[np.isfinite(v)]
    return (float(v.min()), float(v.max()), int(v.size)) if v.size else (math.nan, math.nan, 0)


def save(fig: Any, out_dir: Path, name: str) -> str:
    """Save a matplotlib figure as ``out_dir/name`` (PNG, 110 dpi), close it, return the name."""
    out_dir.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(out_dir / name, dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return name


#: plants of the measured runs: name -> (unmodelled effects, along-cable imbalance) (module doc)
PLANTS: dict[str, tuple[bool, bool]] = {"effects": (True, False), "imbalanced": (True, True)}


def claim(paper_says: str, ours_holds: list[bool], rows: list[str], ours_says: str = "",
          plant: str = "effects") -> dict[str, Any]:
    """A paper statement checked on our runs: held in how many of the seeds, and the rows it rests on.

    :param ours_holds: per noise seed, whether the statement holds on our numbers.
    :param rows: ids of the table rows the check reads.
    :returns: ``{"paper", "ours", "plant", "held", "seeds", "verdict", "rows"}`` with verdict
        ``agrees`` (every seed), ``disagrees`` (none) or ``mixed``.
    """
    held = int(sum(bool(h) for h in ours_holds))
    n = len(ours_holds)
    verdict = "agrees" if n and held == n else ("disagrees" if held == 0 else "mixed")
    return {"paper": paper_says, "ours": ours_says, "plant": plant, "held": held, "seeds": n,
            "verdict": verdict, "rows": list(rows)}
