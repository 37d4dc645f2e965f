"""``DistributedModel.step()`` on the packed state buffer (models.distributed_kernels): the
fast path (the model's own ``mu_scale`` / ``b_node_Ns_m``) and the path with replaced
arrays give bit-identical results, inputs are converted like ``float()``, invalid
intervals are refused without touching the state, the settings are kept, and copies
(deepcopy, pickle) get views of their own buffer."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

from capstan.models.distributed import kernels as kern
from capstan.models.distributed.model import BoundaryParams, DistributedModel, TransmissionParams
from capstan.models.common.errors import ConfigError

N = 4


def _model() -> DistributedModel:
    return DistributedModel(TransmissionParams.uniform(N, 3.0, 150.0), BoundaryParams())


def _drive(model: DistributedModel, k0: int, k1: int) -> np.ndarray:
    out = []
    for k in range(k0, k1):
        model.step(1e-3, 2.0 * np.sin(2 * np.pi * 1.5 * k * 1e-3), 0.0)
        out.append((model.tau_out_Nm, model.q_in_rad, model.dq_out_rad_s, model.t_s))
    return np.array(out)


def test_own_and_replaced_node_arrays_give_bit_identical_steps() -> None:
    own, rep = _model(), _model()
    rep.mu_scale = np.ones(2 * N)
    rep.b_node_Ns_m = np.full(2 * N, rep.trans.b_node_Ns_m)
    assert np.array_equal(_drive(own, 0, 300), _drive(rep, 0, 300))
    # in-place changes of either kind of array reach the kernel
    own.mu_scale[:] = 0.6
    rep.mu_scale[:] = 0.6
    own.b_node_Ns_m[1] = 3.0
    rep.b_node_Ns_m[1] = 3.0
    a, b = _drive(own, 300, 600), _drive(rep, 300, 600)
    assert np.array_equal(a, b)
    # and they matter: an unchanged model differs
    ref = _model()
    _drive(ref, 0, 300)
    assert not np.array_equal(_drive(ref, 300, 600), a)
    # back to the model's own arrays (the fast path), given the same values
    rep._own_mu_scale[:] = rep.mu_scale
    rep._own_b_node[:] = rep.b_node_Ns_m
    rep.mu_scale, rep.b_node_Ns_m = rep._own_mu_scale, rep._own_b_node
    assert np.array_equal(_drive(own, 600, 700), _drive(rep, 600, 700))
    assert own.stats == rep.stats


def test_inputs_are_converted_like_float() -> None:
    a, b, c = _model(), _model(), _model()
    for k in range(50):
        a.step(1e-3, 1, 0)
        b.step(np.float64(1e-3), np.float32(1.0), np.int64(0))
        c.step(1e-3, 1.0, 0.0)
    for m in (a, b):
        assert m.tau_out_Nm == c.tau_out_Nm and m.q_in_rad == c.q_in_rad and m.t_s == c.t_s
    with pytest.raises(TypeError):
        a.step(1e-3, None)


@pytest.mark.parametrize("replaced", [False, True])
@pytest.mark.parametrize("dt", [0.0, -1e-3, float("nan")])
def test_non_positive_interval_is_refused_and_state_kept(dt: float, replaced: bool) -> None:
    model = _model()
    if replaced:
        model.mu_scale = np.ones(2 * N)
    model.step(1e-3, 1.0)
    before = (model.t_s, model.tau_out_Nm, model._y.copy(), model.stats)
    with pytest.raises(ConfigError, match="dt_s"):
        model.step(dt, 1.0)
    assert (model.t_s, model.tau_out_Nm) == before[:2]
    assert np.array_equal(model._y, before[2]) and model.stats == before[3]
    model.step(1e-3, 1.0)
    assert model.t_s == pytest.approx(2e-3)


def test_settings_are_kept_and_used() -> None:
    model = _model()
    assert (model.step_adaptive, model.rtol, model.atol) == (False, 1e-6, 1e-9)
    model.step_adaptive, model.rtol, model.atol = True, 1e-8, 1e-11
    assert (model.step_adaptive, model.rtol, model.atol) == (True, 1e-8, 1e-11)
    assert isinstance(model.rtol, float) and isinstance(model.step_adaptive, bool)
    model.step(1e-3, 2.0)
    assert model.stats["n_steps"] > 1          # error control split the first interval
    model.reset()
    model.step_adaptive = False
    model.step(1e-3, 2.0)
    assert model.stats["n_steps"] == 1


def test_model_arrays_are_views_of_the_packed_buffer() -> None:
    model = _model()
    for arr in (model._y, model._d0, model._work, model._bp, model.mu_scale, model.b_node_Ns_m,
                model._c_node, model._b_ring, model._obs, model._fseg, model._stats):
        assert np.shares_memory(arr, model._fb)
    assert np.shares_memory(model._route, model._ib)
    assert callable(kern.step_held_entry())


@pytest.mark.parametrize("how", ["deepcopy", "pickle"])
def test_copied_model_steps_like_the_original(how: str) -> None:
    """The copy's arrays are views of its own buffer again (not of the original's)."""
    a = _model()
    _drive(a, 0, 100)
    a.mu_scale[:] = 0.8
    a.rtol = 1e-7
    b = copy.deepcopy(a) if how == "deepcopy" else pickle.loads(pickle.dumps(a))
    assert b.rtol == 1e-7 and b.mu_scale is b._own_mu_scale and np.all(b.mu_scale == 0.8)
    assert np.shares_memory(b._y, b._fb) and not np.shares_memory(b._y, a._fb)
    assert np.array_equal(_drive(a, 100, 300), _drive(b, 100, 300))
    b.mu_scale = np.full(2 * N, 0.5)          # replaced arrays are copied as they are
    c = copy.deepcopy(b)
    assert c.mu_scale is not c._own_mu_scale and np.all(c.mu_scale == 0.5)
    assert np.array_equal(_drive(b, 300, 400), _drive(c, 300, 400))
