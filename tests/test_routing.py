"""Routing: curvature profile, exact bending integrals, spline fit of planar points, YAML forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from capstan.models.common.errors import ConfigError
from capstan.models.transmission.routing import Routing

# a two-bend routing with a straight middle part and a non-zero start sample (as in formats.md)
MULTI_S = [0.057, 0.2, 0.35, 0.5, 0.7, 0.9, 1.05, 1.2, 1.379]
MULTI_K = [2.1, 4.0, 6.5, 0.0, 0.0, 3.0, 7.5, 2.0, 0.5]


def _kappa_ref(s: float) -> float:
    """Independent reference of the profile: held before the first sample, linear between samples."""
    return float(np.interp(s, MULTI_S, MULTI_K))


def test_uniform_routing_has_constant_curvature_and_total_bending() -> None:
    r = Routing.uniform(1.379, 3.0)
    assert r.length_m == pytest.approx(1.379)
    assert r.theta_total_rad == pytest.approx(3.0, rel=1e-14)
    assert np.allclose(r.kappa_1_per_m([0.0, 0.5, 1.379]), 3.0 / 1.379)
    seg = r.segment_bending_rad(7)
    assert np.allclose(seg, 3.0 / 7, rtol=1e-12)


def test_cumulative_bending_is_exact_integral_of_piecewise_linear_profile() -> None:
    r = Routing.from_curvature_samples(MULTI_S, MULTI_K)
    for s in (0.0, 0.03, 0.057, 0.31, 0.6, 1.0, 1.379):
        ref, _ = quad(_kappa_ref, 0.0, s, points=[x for x in MULTI_S if x < s] or None, epsabs=1e-13, limit=200)
        assert r.cumulative_bending_rad(s) == pytest.approx(ref, abs=1e-11)
    # first sample at s > 0: curvature held from s = 0
    assert r.kappa_1_per_m(0.0) == pytest.approx(2.1)


@pytest.mark.parametrize("n", [1, 3, 10, 37])
def test_segment_bending_is_integrated_not_sampled_and_sums_to_theta(n: int) -> None:
    r = Routing.from_curvature_samples(MULTI_S, MULTI_K)
    seg = r.segment_bending_rad(n)
    assert seg.shape == (n,)
    assert seg.sum() == pytest.approx(r.theta_total_rad, rel=1e-13)
    edges = np.linspace(0.0, 1.379, n + 1)
    for i in range(n):
        a, b = edges[i], edges[i + 1]
        ref, _ = quad(_kappa_ref, a, b, points=[x for x in MULTI_S if a < x < b] or None, epsabs=1e-13, limit=200)
        assert seg[i] == pytest.approx(ref, abs=1e-11)
    # sampling kappa at segment midpoints would differ on the curved profile: the test can tell
    if n == 3:
        sampled = r.kappa_1_per_m(0.5 * (edges[1:] + edges[:-1])) * (1.379 / n)
        assert np.max(np.abs(sampled - seg)) > 1e-3


def test_length_beyond_last_sample_holds_last_curvature() -> None:
    r = Routing.from_curvature_samples([0.0, 1.0], [1.0, 2.0], length_m=1.5)
    assert r.length_m == 1.5
    assert r.theta_total_rad == pytest.approx(1.5 + 0.5 * 2.0)


def test_arc_length_at_bending_returns_the_straight_interval() -> None:
    r = Routing.from_curvature_samples(MULTI_S, MULTI_K)
    c_mid = float(r.cumulative_bending_rad(0.6))  # inside the straight part [0.5, 0.7]
    lo, hi = r.arc_length_at_bending_m(c_mid)
    assert lo == pytest.approx(0.5, abs=1e-12)
    assert hi == pytest.approx(0.7, abs=1e-12)
    lo, hi = r.arc_length_at_bending_m(float(r.cumulative_bending_rad(1.1)))
    assert lo == pytest.approx(1.1, abs=1e-9) and hi == pytest.approx(1.1, abs=1e-9)


@pytest.mark.parametrize("radius_m, angle_rad", [(0.5, 2.0), (0.25, 4.5), (1.0, 0.6)])
def test_points_on_a_circle_give_inverse_radius_and_arc_angle(radius_m: float, angle_rad: float) -> None:
    phi = np.linspace(0.0, angle_rad, 40)
    xy = np.column_stack((radius_m * np.cos(phi), radius_m * np.sin(phi)))
    r = Routing.from_points(xy)
    assert r.length_m == pytest.approx(radius_m * angle_rad, rel=1e-3)
    assert r.theta_total_rad == pytest.approx(angle_rad, rel=0.01)
    s = np.linspace(0.05, 0.95, 50) * r.length_m
    assert np.allclose(r.kappa_1_per_m(s), 1.0 / radius_m, rtol=0.01)


def test_points_on_a_straight_line_give_zero_curvature() -> None:
    x = np.linspace(0.0, 1.2, 15)
    r = Routing.from_points(np.column_stack((x, 0.3 * x + 0.1)))
    assert r.length_m == pytest.approx(1.2 * math.hypot(1.0, 0.3), rel=1e-9)
    assert np.max(r.curvature_profile()[1]) < 1e-6
    assert r.theta_total_rad < 1e-6


def test_smoothing_spline_tames_marker_noise() -> None:
    rng = np.random.default_rng(3)
    radius, angle, sigma = 0.5, 2.0, 0.5e-3
    phi = np.linspace(0.0, angle, 60)
    xy = np.column_stack((radius * np.cos(phi), radius * np.sin(phi))) + rng.normal(0.0, sigma, (60, 2))
    raw = Routing.from_points(xy)
    smooth = Routing.from_points(xy, smoothing=60 * 2 * sigma**2)
    assert abs(smooth.theta_total_rad - angle) < abs(raw.theta_total_rad - angle)
    assert smooth.theta_total_rad == pytest.approx(angle, rel=0.05)


def test_from_mapping_accepts_the_three_forms() -> None:
    r1 = Routing.from_mapping({"length_m": 1.379, "theta_rad": 3.0})
    assert r1.theta_total_rad == pytest.approx(3.0)
    r2 = Routing.from_mapping({"curvature_profile": [list(p) for p in zip(MULTI_S, MULTI_K)], "length_m": 1.379})
    assert r2.theta_total_rad == pytest.approx(Routing.from_curvature_samples(MULTI_S, MULTI_K).theta_total_rad)
    phi = np.linspace(0, 1.0, 12)
    r3 = Routing.from_mapping({"points_m": [[math.cos(p), math.sin(p)] for p in phi], "n_resample": 100})
    assert r3.theta_total_rad == pytest.approx(1.0, rel=0.01)


@pytest.mark.parametrize("cfg, key", [
    ({"length_m": 1.0, "theta_rad": 1.0, "thetta": 2}, "routing.thetta"),
    ({"length_m": 1.0}, "routing.theta_rad"),
    ({"length_m": -1.0, "theta_rad": 1.0}, "routing.length_m"),
    ({"curvature_profile": [[0.0, 1.0], [0.5, -2.0]]}, "routing.curvature_profile"),
    ({"curvature_profile": [[0.0, 1.0], [0.5, 2.0], [0.4, 2.0]]}, "routing.curvature_profile"),
    ({"curvature_profile": [[0.0, 1.0], [0.5]]}, "routing.curvature_profile"),
    ({"curvature_profile": [[0.0, 1.0], [1.0, 1.0]], "length_m": 0.5}, "routing.length_m"),
    ({"curvature_profile": [[0.0, 1.0], [1.0, 1.0]], "theta_rad": 2.0}, "routing.theta_rad"),
    ({"points_m": [[0.0, 0.0], [1.0, 1.0]]}, "routing.points_m"),
    ({"points_m": [[0.0, 0.0], [1.0, 1.0], [2.0, 0.0]], "smoothing": -1}, "routing.smoothing"),
    ({}, "routing"),
])
def test_from_mapping_rejects_bad_input_naming_the_key(cfg: dict, key: str) -> None:
    with pytest.raises(ConfigError) as exc:
        Routing.from_mapping(cfg, "routing")
    assert exc.value.key == key
