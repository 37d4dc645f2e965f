"""Cable routing: the arc-length curvature profile kappa(s) of the sheath centreline.

The routing is a prescribed geometric input (paper §3, §4.1). It is stored as a
piecewise-linear curvature-magnitude profile on knots ``0 = s_0 < s_1 < ... < s_K = L``
running from the input fixture (s = 0) to the output fixture (s = L). All bending
integrals are the exact integrals of that piecewise-linear profile, so the segment
bending angles of any discretisation sum to the total bending ``theta = int_0^L kappa ds``.

Three sources produce the same object:

* :meth:`Routing.uniform` - constant curvature (length and total bending angle);
* :meth:`Routing.from_curvature_samples` - a measured/designed profile ``[(s, kappa)]``;
* :meth:`Routing.from_points` - planar marker points (motion capture), fitted by a
  parametric smoothing spline, resampled at uniform arc length (paper §4.1).
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np
from numpy.typing import ArrayLike

from capstan.models.common.config_tools import get_float, get_int, reject_unknown
from capstan.models.common.errors import ConfigError


class Routing:
    """Piecewise-linear curvature profile along the sheath, input (s = 0) to output (s = L).

    Build it with one of the static constructors; the instance is immutable.

    :ivar length_m: routing length L [m].
    :ivar theta_total_rad: accumulated bending angle int_0^L kappa ds [rad].
    """

    __slots__ = ("_s", "_k", "_c", "length_m", "theta_total_rad")

    def __init__(self, s_knots_m: np.ndarray, kappa_knots_1_per_m: np.ndarray) -> None:
        """Internal: knots must start at 0, be strictly increasing, kappa >= 0 (validated by the constructors)."""
        s = np.array(s_knots_m, dtype=float)
        k = np.array(kappa_knots_1_per_m, dtype=float)
        h = np.diff(s)
        c = np.concatenate(([0.0], np.cumsum(0.5 * h * (k[:-1] + k[1:]))))
        for arr in (s, k, c):
            arr.setflags(write=False)
        self._s, self._k, self._c = s, k, c
        self.length_m = float(s[-1])
        self.theta_total_rad = float(c[-1])

    # ------------------------------------------------------------------ constructors
    @staticmethod
    def uniform(length_m: float, theta_rad: float) -> "Routing":
        """Constant curvature ``theta_rad / length_m`` over ``length_m``.

        :param length_m: routing length L [m], > 0.
        :param theta_rad: total bending angle [rad], >= 0.
        :raises ConfigError: on non-finite, non-positive length or negative angle.
        """
        length = float(length_m)
        theta = float(theta_rad)
        if not np.isfinite(length) or length <= 0.0:
            raise ConfigError("length_m", f"must be > 0, got {length_m!r}")
        if not np.isfinite(theta) or theta < 0.0:
            raise ConfigError("theta_rad", f"must be >= 0, got {theta_rad!r}")
        kappa = theta / length
        return Routing(np.array([0.0, length]), np.array([kappa, kappa]))

    @staticmethod
    def from_curvature_samples(s_m: ArrayLike, kappa_1_per_m: ArrayLike, length_m: float | None = None,
                               key: str = "curvature_profile") -> "Routing":
        """Profile from samples ``kappa(s)``, linearly interpolated between samples.

        If the first sample lies at s > 0 the first curvature value is held from s = 0;
        if ``length_m`` exceeds the last sample the last value is held up to ``length_m``.
        Without ``length_m`` the routing ends at the last sample.

        :param s_m: arc-length positions [m], strictly increasing, >= 0.
        :param kappa_1_per_m: curvature magnitudes [1/m], >= 0, same length as ``s_m``.
        :param length_m: routing length L [m]; default the last ``s_m``.
        :param key: config key named in errors.
        :raises ConfigError: on empty, mismatched, non-finite, unsorted or negative input.
        """
        s = np.asarray(s_m, dtype=float).ravel()
        k = np.asarray(kappa_1_per_m, dtype=float).ravel()
        if s.size == 0 or s.size != k.size:
            raise ConfigError(key, f"need matching non-empty s and kappa samples, got {s.size} and {k.size}")
        if not (np.all(np.isfinite(s)) and np.all(np.isfinite(k))):
            raise ConfigError(key, "samples must be finite numbers")
        if s[0] < 0.0:
            raise ConfigError(key, f"arc length must start at >= 0, got {s[0]}")
        if np.any(np.diff(s) <= 0.0):
            i = int(np.argmax(np.diff(s) <= 0.0))
            raise ConfigError(key, f"arc length must be strictly increasing (sample {i + 1}: {s[i + 1]} after {s[i]})")
        if np.any(k < 0.0):
            i = int(np.argmax(k < 0.0))
            raise ConfigError(key, f"curvature is a magnitude and must be >= 0 (sample {i}: {k[i]})")
        if length_m is not None:
            length = float(length_m)
            if not np.isfinite(length) or length < s[-1] or length <= 0.0:
                raise ConfigError("length_m", f"must be > 0 and >= the last sample s = {s[-1]}, got {length_m!r}")
        else:
            length = float(s[-1])
        if length <= 0.0:
            raise ConfigError(key, "routing length must be > 0 (give more than one sample or a length)")
        if s[0] > 0.0:
            s = np.concatenate(([0.0], s))
            k = np.concatenate(([k[0]], k))
        if length > s[-1]:
            s = np.concatenate((s, [length]))
            k = np.concatenate((k, [k[-1]]))
        return Routing(s, k)

    @staticmethod
    def from_points(xy_m: ArrayLike, smoothing: float | None = None, n_resample: int = 400,
                    key: str = "points_m") -> "Routing":
        """Profile from planar centreline points (e.g. motion-capture markers), paper §4.1.

        A parametric cubic smoothing spline (``scipy.interpolate.splprep``) is fitted through
        the points in the given order (first point = input fixture), its arc length is
        integrated on a fine grid, and the curvature magnitude
        ``|x'y'' - y'x''| / (x'^2 + y'^2)^1.5`` is evaluated at ``n_resample`` points of
        uniform arc length.

        :param xy_m: (M, 2) points [m], M >= 3, consecutive duplicates are dropped.
        :param smoothing: spline smoothing factor ``s`` of splprep [m^2] (upper bound on the
            sum of squared residuals); ``None`` or 0 interpolates the points.
        :param n_resample: number of uniform arc-length samples (>= 3).
        :param key: config key named in errors.
        :raises ConfigError: on malformed points, too few distinct points or a failed fit.
        """
        from scipy.interpolate import splev, splprep

        pts = np.asarray(xy_m, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 2:
            raise ConfigError(key, f"must be a list of [x, y] points, got shape {pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise ConfigError(key, "points must be finite numbers")
        keep = np.concatenate(([True], np.any(np.diff(pts, axis=0) != 0.0, axis=1)))
        pts = pts[keep]
        if pts.shape[0] < 3:
            raise ConfigError(key, f"need at least 3 distinct points, got {pts.shape[0]}")
        if n_resample < 3:
            raise ConfigError(f"{key}.n_resample", f"must be >= 3, got {n_resample}")
        s_fac = 0.0 if smoothing is None else float(smoothing)
        if not np.isfinite(s_fac) or s_fac < 0.0:
            raise ConfigError(f"{key}.smoothing", f"must be >= 0, got {smoothing!r}")
        # chord-length parameter so the spline parameter is close to arc length
        chord = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))))
        u_pts = chord / chord[-1]
        deg = min(3, pts.shape[0] - 1)
        try:
            tck, _ = splprep([pts[:, 0], pts[:, 1]], u=u_pts, k=deg, s=s_fac)
        except (ValueError, TypeError) as exc:  # scipy raises these for degenerate input
            raise ConfigError(key, f"spline fit failed: {exc}") from exc
        n_fine = max(20 * n_resample, 20 * pts.shape[0])
        u_fine = np.linspace(0.0, 1.0, n_fine)
        dx, dy = splev(u_fine, tck, der=1)
        speed = np.hypot(dx, dy)
        s_fine = np.concatenate(([0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(u_fine))))
        length = float(s_fine[-1])
        if not length > 0.0:
            raise ConfigError(key, "points span zero length")
        s_res = np.linspace(0.0, length, n_resample)
        u_res = np.interp(s_res, s_fine, u_fine)
        d1 = np.array(splev(u_res, tck, der=1))
        d2 = np.array(splev(u_res, tck, der=2))
        num = np.abs(d1[0] * d2[1] - d1[1] * d2[0])
        den = np.maximum((d1[0] ** 2 + d1[1] ** 2) ** 1.5, 1e-300)
        kappa = num / den
        return Routing.from_curvature_samples(s_res, kappa, key=key)

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any], prefix: str = "routing") -> "Routing":
        """Build from one of the YAML forms::

            {length_m: 1.379, theta_rad: 3.0}                           # constant curvature
            {curvature_profile: [[s_m, kappa_1_per_m], ...], length_m: 1.379}   # length optional
            {points_m: [[x, y], ...], smoothing: 0.0, n_resample: 400}  # planar marker points

        :raises ConfigError: naming the offending key on unknown keys, a mix of forms or bad values.
        """
        def key(k: str) -> str:
            return f"{prefix}.{k}" if prefix else k

        if not isinstance(cfg, Mapping):
            raise ConfigError(prefix or "routing", f"must be a mapping, got {type(cfg).__name__}")
        if "points_m" in cfg:
            reject_unknown(cfg, {"points_m", "smoothing", "n_resample"}, prefix)
            pts = _as_pairs(cfg["points_m"], key("points_m"))
            smoothing = get_float(cfg, "smoothing", prefix, 0.0, min_value=0.0)
            n_res = get_int(cfg, "n_resample", prefix, 400, min_value=3)
            return Routing.from_points(pts, smoothing, n_res, key=key("points_m"))
        if "curvature_profile" in cfg:
            reject_unknown(cfg, {"curvature_profile", "length_m"}, prefix)
            prof = _as_pairs(cfg["curvature_profile"], key("curvature_profile"))
            length = get_float(cfg, "length_m", prefix, None, min_value=0.0, min_exclusive=True) \
                if cfg.get("length_m") is not None else None
            if length is not None and length < prof[-1, 0]:
                raise ConfigError(key("length_m"), f"must be >= the last profile sample s = {prof[-1, 0]}, got {length}")
            return Routing.from_curvature_samples(prof[:, 0], prof[:, 1], length, key=key("curvature_profile"))
        reject_unknown(cfg, {"length_m", "theta_rad"}, prefix)
        if "length_m" not in cfg and "theta_rad" not in cfg:
            raise ConfigError(prefix or "routing",
                              "needs {length_m, theta_rad}, {curvature_profile: [[s_m, kappa], ...]} or {points_m: [[x, y], ...]}")
        length = get_float(cfg, "length_m", prefix, min_value=0.0, min_exclusive=True)
        theta = get_float(cfg, "theta_rad", prefix, min_value=0.0)
        return Routing.uniform(length, theta)

    # ------------------------------------------------------------------ queries
    def curvature_profile(self) -> tuple[np.ndarray, np.ndarray]:
        """The knots ``(s_m, kappa_1_per_m)`` of the piecewise-linear profile (read-only arrays)."""
        return self._s, self._k

    def kappa_1_per_m(self, s_m: ArrayLike) -> np.ndarray:
        """Curvature magnitude [1/m] at arc length(s) ``s_m`` [m]; held constant outside [0, L]."""
        return np.interp(np.asarray(s_m, dtype=float), self._s, self._k)

    def cumulative_bending_rad(self, s_m: ArrayLike) -> np.ndarray:
        """Exact ``int_0^s kappa ds`` [rad] of the piecewise-linear profile; ``s`` clipped to [0, L]."""
        s = np.clip(np.asarray(s_m, dtype=float), 0.0, self.length_m)
        j = np.clip(np.searchsorted(self._s, s, side="right") - 1, 0, self._s.size - 2)
        h = self._s[j + 1] - self._s[j]
        x = s - self._s[j]
        slope = (self._k[j + 1] - self._k[j]) / h
        return self._c[j] + self._k[j] * x + 0.5 * slope * x * x

    def segment_bending_rad(self, n: int) -> np.ndarray:
        """(n,) bending angles ``theta_i = int kappa ds`` over n equal arc-length segments [rad].

        Segment i (0-based) spans ``[i L/n, (i+1) L/n]``; the angles are integrated exactly
        (not sampled), so they sum to :attr:`theta_total_rad`.

        :raises ValueError: if ``n < 1``.
        """
        if int(n) < 1:
            raise ValueError(f"number of segments must be >= 1, got {n}")
        edges = np.linspace(0.0, self.length_m, int(n) + 1)
        c = self.cumulative_bending_rad(edges)
        c[0], c[-1] = 0.0, self.theta_total_rad
        return np.diff(c)

    def arc_length_at_bending_m(self, bending_rad: float) -> tuple[float, float]:
        """The arc-length interval ``[s_lo, s_hi]`` [m] on which ``int_0^s kappa = bending_rad``.

        The cumulative bending is non-decreasing, so the solution set is an interval
        (a point unless the routing is straight there). Values outside ``[0, theta]``
        are clipped to the ends.
        """
        c = float(bending_rad)
        if c <= 0.0:
            return 0.0, self._upper_root(0.0)
        if c >= self.theta_total_rad:
            return self._lower_root(self.theta_total_rad), self.length_m
        return self._lower_root(c), self._upper_root(c)

    # ------------------------------------------------------------------ internals
    def _solve_in_segment(self, j: int, d: float) -> float:
        """Offset x in segment j with ``kappa_j x + 0.5 a x^2 = d`` (d >= 0, smallest root)."""
        if d <= 0.0:
            return 0.0
        h = self._s[j + 1] - self._s[j]
        kj = self._k[j]
        a = (self._k[j + 1] - kj) / h
        disc = max(kj * kj + 2.0 * a * d, 0.0)
        den = kj + np.sqrt(disc)
        x = 2.0 * d / den if den > 0.0 else h
        return float(min(max(x, 0.0), h))

    def _lower_root(self, c: float) -> float:
        """inf{s : C(s) >= c} for 0 < c <= theta."""
        j = int(np.searchsorted(self._c, c, side="left")) - 1
        j = min(max(j, 0), self._s.size - 2)
        return float(self._s[j] + self._solve_in_segment(j, c - self._c[j]))

    def _upper_root(self, c: float) -> float:
        """sup{s : C(s) <= c} for 0 <= c < theta."""
        j = int(np.searchsorted(self._c, c, side="right")) - 1
        if j >= self._s.size - 1:
            return self.length_m
        return float(self._s[j] + self._solve_in_segment(j, c - self._c[j]))

    def __repr__(self) -> str:
        return (f"Routing(length_m={self.length_m:.4g}, theta_total_rad={self.theta_total_rad:.4g}, "
                f"knots={self._s.size})")


def _as_pairs(value: Any, key: str) -> np.ndarray:
    """Parse a YAML list of [a, b] pairs into an (M, 2) float array.

    :raises ConfigError: if it is not a non-empty list of numeric pairs.
    """
    if not isinstance(value, (list, tuple)) or len(value) == 0:
        raise ConfigError(key, "must be a non-empty list of [a, b] pairs")
    rows = []
    for i, row in enumerate(value):
        if not isinstance(row, (list, tuple)) or len(row) != 2 or any(
                isinstance(v, bool) or not isinstance(v, (int, float)) for v in row):
            raise ConfigError(key, f"entry {i} must be a pair of numbers, got {row!r}")
        rows.append((float(row[0]), float(row[1])))
    return np.array(rows, dtype=float)
