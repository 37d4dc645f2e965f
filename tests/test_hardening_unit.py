"""The torsional unit with strain-hardening cable paths (models/transmission/hardening.py)
against physics:

* the limiting case ``c_node = 0`` is the linear unit, bit for bit;
* the static torque-stretch curve of the hardening spring ``K e (1 + c e^2) = L`` (the root
  of the cubic, numpy's companion-matrix solver), with friction (the node held until the load
  exceeds the capacity) and without;
* the two-path (two-angle) unit's torque at the closed form of two equal springs in series;
* the implicit step stays stable at a stiffness far beyond what explicit Euler survives;
* the one-node mapping ``c_node = 4 c r^2 / (1 + 3 c D0^2)`` against the *distributed*
  model's own cubic cable (written independently of this unit): a frictionless pull-pull
  pair ramped slowly, its torque-deflection curve against the pair's exact law, and the
  cables' mean tension rising with the deflection squared (the stiffening candidate's
  friction term, ``beta``).
"""

from __future__ import annotations


import numpy as np
import pytest

from capstan.models.distributed.model import BoundaryParams, DistributedModel, TransmissionParams
from capstan.models.transmission.hardening import hardening_torque_Nm, simulate_unit_hardening
from capstan.models.transmission.stick_slip import capacity_Nm, simulate_unit

K = 500.0          # elastic path stiffness [Nm/rad]
C_NODE = 2000.0    # hardening [1/rad^2]: +60 % tangent stiffness at 10 mrad


def _static_stretch(load_Nm: float, K_Nm_rad: float, c: float) -> float:
    """The real root of ``K c e^3 + K e - L = 0`` (monotone: exactly one)."""
    r = np.roots([K_Nm_rad * c, 0.0, K_Nm_rad, -load_Nm])
    real = r[np.abs(r.imag) < 1e-9].real
    assert real.size == 1
    return float(real[0])


def _run(t: np.ndarray, a: np.ndarray, anchor: np.ndarray, c_node: float, tau_fc: float = 0.0, c0: float = 0.5,
         kx: float = K, anchor2: np.ndarray | None = None, K2: float = 0.0, dahl_exp: float = 1.0,
         cap: np.ndarray | None = None) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    n = t.size
    x, v, f = np.empty(n), np.empty(n), np.empty(n)
    done = simulate_unit_hardening(t, a, np.array([0, n]), np.array([0.0]), np.array([c0]), np.array([kx]), 5e4,
                                   tau_fc, 1.3, 0.05, 0.01, x, v, f, np.empty(0) if cap is None else cap, 0.0,
                                   dahl_exp, c_node, K, anchor, K2, np.empty(0) if anchor2 is None else anchor2)
    return done, x, v, f


@pytest.mark.parametrize("dahl_exp", [1.0, 2.0])
def test_zero_hardening_is_the_linear_unit_bit_for_bit(dahl_exp: float) -> None:
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 4.0, 1e-3)
    q = 0.01 * np.sin(2 * np.pi * 0.7 * t) + 2e-3 * np.sin(2 * np.pi * 3.1 * t)
    load = 1.5 * np.sin(2 * np.pi * 0.3 * t)
    a = K * q - load
    cap = 1.0 + 0.3 * rng.random(t.size)
    done, x, v, f = _run(t, a, q, 0.0, tau_fc=0.8, dahl_exp=dahl_exp, cap=cap)
    xl, vl, fl = np.empty(t.size), np.empty(t.size), np.empty(t.size)
    assert simulate_unit(t, a, np.array([0, t.size]), np.array([0.0]), np.array([0.5]), np.array([K]), 5e4, 0.8,
                         1.3, 0.05, 0.01, xl, vl, fl, cap, 0.0, dahl_exp) == t.size
    assert done == t.size
    assert np.array_equal(x, xl) and np.array_equal(v, vl) and np.array_equal(f, fl)


@pytest.mark.parametrize("load_Nm", [-6.0, -0.7, 0.3, 2.0, 5.0, 9.0])
def test_static_curve_is_the_hardening_spring_root(load_Nm: float) -> None:
    # anchor fixed at 0, a constant load L on the node: K e (1 + c e^2) = L at rest, e = -x
    t = np.arange(0.0, 2.0, 1e-3)
    a = np.full(t.size, -load_Nm)
    done, x, v, _ = _run(t, a, np.zeros(t.size), C_NODE)
    assert done == t.size
    e = -x[-1]
    assert abs(v[-1]) < 1e-9
    assert e == pytest.approx(_static_stretch(load_Nm, K, C_NODE), rel=1e-8)
    assert hardening_torque_Nm(K, C_NODE, e) == pytest.approx(load_Nm, rel=1e-8)
    # and the linear spring's stretch is larger by the hardening's share (physics, not the code)
    assert abs(e) < abs(load_Nm) / K


def test_static_curve_with_friction_holds_until_the_capacity() -> None:
    # a slow load ramp 0 -> 6 Nm on a node with capacity 1 Nm (zeta_s 1.3): at rest the path
    # carries L - f with |f| <= capacity; the stretch sits on the hardening curve of that torque
    t = np.arange(0.0, 6.0, 1e-3)
    load = t.copy()
    done, x, v, f = _run(t, -load, np.zeros(t.size), C_NODE, tau_fc=1.0, c0=0.05)
    assert done == t.size
    e = -x
    carried = hardening_torque_Nm(K, C_NODE, e)
    # torque balance at every sample: path torque = load - friction - damping (b_vis + c0)
    assert np.max(np.abs(carried - (load + f + 0.06 * v))) < 1e-6
    assert np.max(np.abs(f)) <= 1.3 * 1.0 + 1e-9
    # held: friction (presliding stiffness 100 K) takes the load until it nears the capacity
    assert np.max(np.abs(carried[load < 0.5])) < 0.02
    # sliding: friction at the (Stribeck) capacity of the sliding speed
    assert carried[-1] == pytest.approx(load[-1] - capacity_Nm(v[-1], 1.0, 1.3, 0.05), abs=0.01)


def test_two_paths_in_series_give_the_closed_form() -> None:
    # the two-angle form: node between q_in (K_h) and q_out = 0 (K_h), no friction; symmetric
    # stretch e = theta / 2, torque K_h (theta / 2)(1 + c (theta / 2)^2)
    t = np.arange(0.0, 10.0, 1e-3)
    theta = 0.02 * np.sin(2 * np.pi * 0.05 * t)
    done, x, _, _ = _run(t, K * theta, theta, C_NODE, c0=1e-3, kx=2 * K, anchor2=np.zeros(t.size), K2=K)
    assert done == t.size
    tau = hardening_torque_Nm(K, C_NODE, x)           # output half: stretch x - 0
    closed = hardening_torque_Nm(K, C_NODE, theta / 2)
    assert np.max(np.abs(tau - closed)) < 1e-4 * np.max(np.abs(closed))
    # and it is not the linear series pair
    assert np.max(np.abs(closed - K * theta / 2)) > 0.15 * np.max(np.abs(closed))


def test_implicit_step_is_stable_where_explicit_euler_is_not() -> None:
    # stiff hardening, 10 ms steps, tiny damping: explicit Euler's limit dt < c0 / K_t is
    # exceeded a thousandfold at the peak tangent stiffness; the implicit step settles monotonically
    t = np.arange(0.0, 1.0, 1e-2)
    load = 20.0
    done, x, v, _ = _run(t, np.full(t.size, -load), np.zeros(t.size), 1e6, c0=1e-3)
    assert done == t.size and np.all(np.isfinite(x))
    e = -x
    assert np.all(np.diff(e) >= -1e-15)
    assert e[-1] == pytest.approx(_static_stretch(load, K, 1e6), rel=1e-8)


def test_negative_hardening_is_refused() -> None:
    t = np.arange(0.0, 0.1, 1e-3)
    assert _run(t, np.zeros(t.size), np.zeros(t.size), -1.0)[0] == 0


@pytest.mark.slow
def test_node_mapping_against_the_distributed_cubic_cable() -> None:
    # frictionless pull-pull pair (mu = 0), uniform pretension T0, cable law k_c D (1 + c D^2)
    c, T0, n = 1e5, 150.0, 6
    trans = TransmissionParams.uniform(n, 3.0, T0, mu=0.0)
    model = DistributedModel(trans, BoundaryParams(k_out_Nm_rad=40.0, b_out_Nms_rad=2.0))
    model.stiffness_cubic_1_m2 = c
    model.reset()
    t = np.arange(0.0, 8.0, 1e-3)
    u = 9.0 * np.sin(2 * np.pi * 0.05 * t)           # slow: quasi-static
    res = model.simulate(t, u, adaptive=True, rtol=1e-6)
    theta = res.q_in_rad - res.q_out_rad
    r = 0.04
    k_c = trans.cable_stiffness_N_m
    D0 = _static_stretch(T0, k_c, c)                  # k_c D0 (1 + c D0^2) = T0
    K_lin = 2.0 * r * r * k_c * (1.0 + 3.0 * c * D0 * D0)
    c_node = 4.0 * c * r * r / (1.0 + 3.0 * c * D0 * D0)
    # the node form: two half paths K_h = 2 K_lin, stretch theta / 2 each
    pred = hardening_torque_Nm(2.0 * K_lin, c_node, theta / 2.0)
    peak = float(np.max(np.abs(res.tau_out_Nm)))
    assert np.max(np.abs(pred - res.tau_out_Nm)) < 0.01 * peak
    # the cubic is material here (the linear pair with the raised stiffness misses it)
    assert np.max(np.abs(K_lin * theta - res.tau_out_Nm)) > 0.03 * peak
    # the even part: both cables' mean tension rises by 3 c D0 k_c d^2 (d = r theta), which the
    # stiffening candidate's friction term carries: T0 (1 + beta c_node e^2 / ...) with e = theta / 2,
    # beta = 3 (1 + x) / (1 + x / 3), x = 3 c D0^2 (models/closure/dynamic/candidates.py)
    fix = res.fixture_tensions_N
    t_mean = 0.25 * fix.sum(axis=1)
    d = r * theta
    rise = t_mean - T0
    closed_rise = 3.0 * c * D0 * k_c * d * d
    assert np.max(np.abs(rise - closed_rise)) < 0.02 * np.max(closed_rise)
    x = 3.0 * c * D0 * D0
    beta = 3.0 * (1.0 + x) / (1.0 + x / 3.0)
    assert np.allclose(T0 * beta * c_node * (theta / 2.0) ** 2, closed_rise, rtol=1e-9)
    assert 3.0 <= beta <= 9.0


def test_stiffening_outside_its_physical_friction_coupling_is_implausible() -> None:
    from capstan.models.closure.dynamic.closure import implausible
    from capstan.models.closure.dynamic.candidates import BETA_PLAUSIBLE, InModelEffect, stiffening_beta, stiffening_k_scale
    eff = InModelEffect("strain_stiffening", ("deflection",), ("rise", "friction_rise"), (0.0, 0.0), (3.0, 3.0),
                        ({},), lambda s, sh, c: None)     # type: ignore[arg-type, return-value]
    # beta = 3 friction_rise / rise: the cables' mean tension rise over the stiffness rise
    assert stiffening_beta(0.1, 0.15) == pytest.approx(4.5)
    assert implausible(eff, np.array([0.1, 0.15])) == ""
    assert "beta 12" in implausible(eff, np.array([0.1, 0.4]))
    assert "beta 0.9" in implausible(eff, np.array([0.1, 0.03]))
    assert "no stiffening" in implausible(eff, np.array([0.0, 0.1]))   # friction alone: not this mechanism
    assert implausible(eff, np.array([0.0, 0.0])) == ""
    assert BETA_PLAUSIBLE == (3.0, 9.0)
    # the linear stiffness kept: K e (1 + c e^2) / (1 + keep rise / 3) -> K e as rise -> 0
    assert stiffening_k_scale(0.0, 0.8) == 1.0 and stiffening_k_scale(1.5, 0.8) == pytest.approx(1 / 1.4)


def test_hardening_in_the_closure_simulation_refuses_what_it_cannot_mean() -> None:
    from capstan.models.closure.dynamic.baseline import Mods, _predict
    from capstan.models.closure.dynamic.forms import DrivingForm, param_names
    from capstan.models.closure.signals import signals_from_tables
    from capstan.models.common.errors import ModelError
    from capstan.models.common.measurement_table import MeasurementTable
    t = np.arange(0.0, 1.0, 1e-3)
    q = 0.01 * np.sin(2 * np.pi * t)
    cols = {"t": t, "tau_in": np.sin(2 * np.pi * t), "q_out": q, "tau_out": 0.5 * q, "q_in": 1.5 * q}
    env = signals_from_tables([MeasurementTable(cols, {"environment": {"k_out": 20.0, "b_out": 2.0}}, "env")])
    p_tb = np.array([20.0, 2.0, 0.5, 1e4, 1.2, 0.1, 0.01, 0.0])
    assert len(p_tb) == len(param_names(DrivingForm.TESTBED))
    with pytest.raises(ModelError, match="TESTBED"):
        _predict(DrivingForm.TESTBED, p_tb, env, True, Mods(c_node_1_rad2=100.0))
    ang = signals_from_tables([MeasurementTable(cols, {"r_in": 0.04, "r_out": 0.04}, "ang")])
    assert ang.ratio_q == 1.0
    p_an = np.array([240.0, 0.5, 1e4, 1.2, 0.1, 0.01, 0.0, 0.0])
    assert len(p_an) == len(param_names(DrivingForm.ANGLES))
    with pytest.raises(ModelError, match="c_node_1_rad2 must be >= 0"):
        _predict(DrivingForm.ANGLES, p_an, ang, False, Mods(c_node_1_rad2=-1.0))
    # the two-angle output with hardening and no friction: the node sits half way, both torques are
    # K_h (theta / 2)(1 + c (theta / 2)^2), theta = q_in - q_out (r_in = r_out)
    p_free = np.array([240.0, 0.0, 1e4, 1.0, 0.1, 1e-3, 0.0, 0.0])
    tau_out, tau_in = _predict(DrivingForm.ANGLES, p_free, ang, False, Mods(c_node_1_rad2=1e4))
    half = 0.5 * (cols["q_in"] - cols["q_out"])
    closed = hardening_torque_Nm(480.0, 1e4, half)
    assert np.max(np.abs(tau_out - closed)) < 1e-3 * np.max(np.abs(closed))
    assert tau_in is not None and np.max(np.abs(tau_in - closed)) < 1e-3 * np.max(np.abs(closed))
    assert np.max(np.abs(closed - 480.0 * half)) > 0.05 * np.max(np.abs(closed))
