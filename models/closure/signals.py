"""Candidate signals of a run, derived once from the measured channels.

The closure attributes a residual to these signals (names as in ``depends_on``):
``velocity`` (dq_out, or the Savitzky-Golay derivative of q_out), ``acceleration``,
``position`` (q_out), ``dwell`` (how long the joint rested before its current motion;
grows while it rests), ``time`` (session time since the run started), ``load``
(transmitted torque tau_in), ``deflection`` (q_in - rho q_out), ``tension``
(mean measured cable tension) and every extra data channel by its own name. ``q_in`` (the
input pulley's angle) can be asked for by name but is not in :meth:`Signals.available`
(the dynamic closure offers it as a drive-gain curve only).

Several runs are concatenated into one :class:`Signals`; ``run_id`` tells them apart so
that time shifts and derivatives never cross a run boundary.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit
from scipy.signal import savgol_filter

from capstan.models.common.errors import DataFormatError
from capstan.models.common.measurement_table import STANDARD_COLUMNS, MeasurementTable

#: fraction of the 95th percentile of |velocity| below which the joint counts as resting
REST_FRACTION = 0.03
#: absolute floor of the rest threshold [rad/s]
REST_FLOOR_RAD_S = 0.005
#: smoothing time of the speed used for the rest/motion decision [s]
SMOOTH_S = 0.02
#: the joint counts as moving again above this multiple of the rest threshold
HYSTERESIS = 2.0


@njit(cache=True)
def dwell_states(dq_rad_s: np.ndarray, dt_s: np.ndarray, v_rest_rad_s: float,
                 out_dwell_s: np.ndarray, out_rest_s: np.ndarray, out_slide_rad: np.ndarray) -> None:
    """Dwell bookkeeping along one run (njit, allocation-free).

    ``out_dwell_s``: time since the joint last moved (0 while moving) [s];
    ``out_rest_s``: duration of the rest that preceded the current motion (while
    resting: the rest so far) [s]; ``out_slide_rad``: angle slid since motion onset [rad].
    The speed is smoothed over ``SMOOTH_S`` and compared with a hysteresis: the joint
    rests below ``v_rest`` and moves again above ``HYSTERESIS * v_rest``, so sensor
    noise does not chop a rest into pieces.
    """
    dwell = 10.0          # assume a long rest before the run
    rest = 10.0
    slide = 0.0
    moving = False
    speed = abs(dq_rad_s[0]) if dq_rad_s.shape[0] > 0 else 0.0
    for i in range(dq_rad_s.shape[0]):
        a = min(1.0, dt_s[i] / SMOOTH_S)
        speed += a * (abs(dq_rad_s[i]) - speed)
        if moving and speed < v_rest_rad_s:
            moving = False
        elif not moving and speed > HYSTERESIS * v_rest_rad_s:
            moving = True
        if not moving:
            dwell += dt_s[i]
            rest = dwell
            slide = 0.0
        else:
            if dwell > 0.0:
                rest = dwell
            dwell = 0.0
            slide += abs(dq_rad_s[i]) * dt_s[i]
        out_dwell_s[i] = dwell
        out_rest_s[i] = rest
        out_slide_rad[i] = slide


def derivative(x: np.ndarray, dt_s: float, window_s: float) -> np.ndarray:
    """d x / dt by a quadratic Savitzky-Golay filter over ``window_s`` [s] (np.gradient on short runs)."""
    n = x.shape[0]
    w = max(5, int(round(window_s / dt_s)) | 1)
    if n <= w:
        return np.gradient(x, dt_s)
    return savgol_filter(x, w, 2, deriv=1, delta=dt_s)


@dataclass
class Signals:
    """Measured and derived signals of one or more runs, concatenated.

    Arrays are float64 of equal length. ``deflection_rad`` / ``tension_N`` are None
    when the run lacks q_in / tension columns. ``extras`` maps extra channel names to
    arrays. ``v_rest_rad_s`` is the rest threshold used for ``dwell``.
    """

    t_s: np.ndarray
    run_id: np.ndarray
    tau_in_Nm: np.ndarray
    tau_out_Nm: np.ndarray
    q_out_rad: np.ndarray
    dq_out_rad_s: np.ndarray
    ddq_out_rad_s2: np.ndarray
    dwell_s: np.ndarray
    rest_s: np.ndarray
    slide_rad: np.ndarray
    q_in_rad: np.ndarray | None = None
    tension_N: np.ndarray | None = None
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    names: list[str] = field(default_factory=list)
    v_rest_rad_s: float = REST_FLOOR_RAD_S
    ratio_q: float = 1.0
    #: declared output environment per sample, columns [k_out Nm/rad, b_out Nm s/rad]
    #: (eq 22), or None when not every run declares one
    environment: np.ndarray | None = None
    #: extra channels declared (import description ``tied_to``) as measuring a torque channel
    tied_to: dict[str, str] = field(default_factory=dict)
    #: every run declares a link output (meta ``output: link``): moved by forces not measured
    output_link: bool = False
    #: fixture sides whose load cells ``tension_N`` averages ("in": T_lc_in, "out": T_lc_out)
    tension_sides: tuple[str, ...] = ()

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def take(self, mask: np.ndarray) -> "Signals":
        """Rows where ``mask`` is true (or at integer indices) as a new Signals."""
        def tk(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[mask]
        return Signals(self.t_s[mask], self.run_id[mask], self.tau_in_Nm[mask], self.tau_out_Nm[mask],
                       self.q_out_rad[mask], self.dq_out_rad_s[mask], self.ddq_out_rad_s2[mask],
                       self.dwell_s[mask], self.rest_s[mask], self.slide_rad[mask], tk(self.q_in_rad),
                       tk(self.tension_N), {k: v[mask] for k, v in self.extras.items()}, list(self.names),
                       self.v_rest_rad_s, self.ratio_q, tk(self.environment), dict(self.tied_to), self.output_link,
                       self.tension_sides)

    @property
    def deflection_rad(self) -> np.ndarray | None:
        """q_in - ratio_q * q_out [rad], or None without q_in."""
        if self.q_in_rad is None:
            return None
        return self.q_in_rad - self.ratio_q * self.q_out_rad

    def signal(self, name: str) -> np.ndarray | None:
        """The candidate signal called ``name`` (see module docstring), or None if absent."""
        table = {"velocity": self.dq_out_rad_s, "acceleration": self.ddq_out_rad_s2,
                 "position": self.q_out_rad, "dwell": self.rest_s, "time": self.t_s,
                 "load": self.tau_in_Nm, "deflection": self.deflection_rad, "tension": self.tension_N,
                 "q_in": self.q_in_rad}
        if name in table:
            return table[name]
        return self.extras.get(name)

    def available(self) -> list[str]:
        """Names of the candidate signals this data carries."""
        base = ["velocity", "acceleration", "position", "dwell", "time", "load"]
        if self.q_in_rad is not None:
            base.append("deflection")
        if self.tension_N is not None:
            base.append("tension")
        return base + sorted(self.extras)

    def segments(self) -> list[tuple[int, int]]:
        """[start, stop) index ranges of contiguous rows of one run."""
        if len(self) == 0:
            return []
        cut = np.flatnonzero(np.diff(self.run_id) != 0) + 1
        edges = np.concatenate([[0], cut, [len(self)]])
        return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def signals_from_tables(tables: list[MeasurementTable], v_rest_rad_s: float | None = None,
                        velocity_window_s: float = 0.025) -> Signals:
    """Derive :class:`Signals` from measurement tables (concatenated in order).

    Needs ``tau_in``, ``tau_out`` and ``q_out`` (or ``dq_out``) in every table; extra
    channels present in all tables are kept.

    :raises DataFormatError: if a required column is missing in a table.
    """
    if not tables:
        raise DataFormatError("no runs given")
    for tb in tables:
        for c in ("tau_in", "tau_out"):
            if not tb.has(c):
                raise DataFormatError(f"{tb.source or '<table>'}: column '{c}' is required for the closure")
        if not tb.has("q_out") and not tb.has("dq_out"):
            raise DataFormatError(f"{tb.source or '<table>'}: needs 'q_out' or 'dq_out'")
    parts: dict[str, list[np.ndarray]] = {}
    extra_names = set.intersection(*[{c for c in tb.columns if c not in STANDARD_COLUMNS} for tb in tables])
    has_qin = all(tb.has("q_in") and tb.has("q_out") for tb in tables)
    tension_cols = [c for c in ("T_lc_in", "T_lc_out") if all(tb.has(c) for tb in tables)]
    for k, tb in enumerate(tables):
        t = np.asarray(tb.t, float)
        dt = float(np.median(np.diff(t))) if len(t) > 1 else 1e-3
        if tb.has("dq_out"):
            v = np.asarray(tb["dq_out"], float)
            q = np.asarray(tb["q_out"], float) if tb.has("q_out") else np.concatenate([[0.0], np.cumsum(v[1:] * np.diff(t))])
        else:
            q = np.asarray(tb["q_out"], float)
            v = derivative(q, dt, velocity_window_s)
        a = derivative(v, dt, 2.0 * velocity_window_s)
        cols = {"t": t, "run": np.full(len(t), float(k)), "tau_in": tb["tau_in"], "tau_out": tb["tau_out"],
                "q": q, "v": v, "a": a}
        if has_qin:
            cols["q_in"] = tb["q_in"]
        if tension_cols:
            cols["T"] = np.mean([tb[c] for c in tension_cols], axis=0)
        for e in extra_names:
            cols["x:" + e] = tb[e]
        if all(_declared_environment(t) is not None for t in tables):
            k_out, b_out = _declared_environment(tb)  # type: ignore[misc]
            cols["env_k"], cols["env_b"] = np.full(len(t), k_out), np.full(len(t), b_out)
        for key, val in cols.items():
            parts.setdefault(key, []).append(np.asarray(val, dtype=np.float64))
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    v_all = cat["v"]
    if v_rest_rad_s is None:
        v_rest_rad_s = max(REST_FLOOR_RAD_S, REST_FRACTION * float(np.percentile(np.abs(v_all), 95)))
    n = v_all.shape[0]
    dwell, rest, slide = np.empty(n), np.empty(n), np.empty(n)
    run = cat["run"].astype(np.int64)
    edges = np.concatenate([[0], np.flatnonzero(np.diff(run) != 0) + 1, [n]])
    for a0, b0 in zip(edges[:-1], edges[1:]):
        tt = cat["t"][a0:b0]
        dt_arr = np.concatenate([[np.median(np.diff(tt)) if b0 - a0 > 1 else 1e-3], np.diff(tt)])
        d1, r1, s1 = np.empty(b0 - a0), np.empty(b0 - a0), np.empty(b0 - a0)
        dwell_states(np.ascontiguousarray(v_all[a0:b0]), dt_arr, float(v_rest_rad_s), d1, r1, s1)
        dwell[a0:b0], rest[a0:b0], slide[a0:b0] = d1, r1, s1
    ratio_q = 1.0
    if has_qin:
        r_in = tables[0].meta.get("r_in")
        r_out = tables[0].meta.get("r_out")
        if isinstance(r_in, (int, float)) and isinstance(r_out, (int, float)) and r_in > 0:
            ratio_q = float(r_out) / float(r_in)
        else:   # fit the angle ratio: the slope of q_in on q_out
            qo = cat["q"] - cat["q"].mean()
            ratio_q = float(np.dot(qo, cat["q_in"] - cat["q_in"].mean()) / max(np.dot(qo, qo), 1e-12))
    return Signals(cat["t"], run, cat["tau_in"], cat["tau_out"], cat["q"], v_all, cat["a"], dwell, rest, slide,
                   cat.get("q_in"), cat.get("T"), {e: cat["x:" + e] for e in sorted(extra_names)},
                   [tb.source for tb in tables], float(v_rest_rad_s), ratio_q,
                   np.column_stack([cat["env_k"], cat["env_b"]]) if "env_k" in cat else None,
                   {str(k): str(v) for tb in tables for k, v in (tb.meta.get("tied_to") or {}).items()},
                   all(_declared_output(tb) == "link" for tb in tables), tuple(c[5:] for c in tension_cols))


#: values of the table meta key ``output``: a link moved by forces the run does not measure
#: (the daemon's use case), or the testbed's environment
OUTPUT_KINDS = ("link", "testbed")


def _declared_output(tb: MeasurementTable) -> str | None:
    """The table's ``output`` meta ("link" / "testbed"), or None when not declared.

    :raises DataFormatError: if the value is not one of :data:`OUTPUT_KINDS` (naming the table).
    """
    out = tb.meta.get("output")
    if out is None:
        return None
    if out not in OUTPUT_KINDS:
        raise DataFormatError(f"{tb.source or '<table>'}: meta 'output' must be one of {', '.join(OUTPUT_KINDS)}, "
                              f"got {out!r}")
    return str(out)


def _declared_environment(tb: MeasurementTable) -> tuple[float, float] | None:
    """(k_out [Nm/rad], b_out [Nm s/rad]) from the table's ``environment`` meta, or None.

    :raises DataFormatError: if the declaration is malformed (naming the table and key).
    """
    env = tb.meta.get("environment")
    if env is None:
        return None
    if not isinstance(env, dict) or "k_out" not in env or "b_out" not in env:
        raise DataFormatError(f"{tb.source or '<table>'}: meta 'environment' must be a mapping with k_out and b_out, "
                              f"got {env!r}")
    try:
        k, b = float(env["k_out"]), float(env["b_out"])
    except (TypeError, ValueError):
        raise DataFormatError(f"{tb.source or '<table>'}: meta 'environment' k_out/b_out must be numbers, "
                              f"got {env!r}") from None
    if not (np.isfinite(k) and np.isfinite(b) and k >= 0.0 and b >= 0.0 and k + b > 0.0):
        raise DataFormatError(f"{tb.source or '<table>'}: meta 'environment' needs k_out >= 0, b_out >= 0 "
                              f"(not both 0), got k_out={k}, b_out={b}")
    return k, b
