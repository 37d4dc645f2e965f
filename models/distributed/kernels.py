"""Compiled entry points of :class:`capstan.models.distributed.model.DistributedModel` and its packed
state buffer.

``step()`` is called once per control period from Python, so the cost of the call itself
matters: Numba's dispatcher types and unboxes every argument on every call (~40 ns per
array). The model therefore keeps all of its per-step state, constants and settings in
one contiguous float64 buffer ``fb`` plus one int64 buffer ``ib`` (offsets, ``N`` and the
routing map), and the per-step kernel takes only those two arrays and three scalars. The
model's arrays (``_y``, ``_d0``, ``mu_scale``, ``_work``, ...) are numpy views into ``fb``,
so in-place changes are seen by the kernel without copying.

Float buffer ``fb``: scalar slots ``F_*`` (model time [s], last input torque [Nm],
Newton/error tolerances, adaptive flag; the friction coefficient is read from
``bp[BP_MU]``), then the arrays at the offsets ``ib[O_*]``. Int buffer ``ib``:
``ib[I_N]`` = N, the array offsets, then the routing map (``ib[I_ROUTE:]``, ring entry -> node index, -1 at the pulleys).

Numerics are those of :mod:`capstan.models.distributed.integrator`; the kernels only unpack the
buffers and call it, so results are bit-identical to calling it with separate arrays.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from numba import njit

from capstan.models.distributed import dense as dense
from capstan.models.distributed import integrator as di
from capstan.models.distributed import rhs as rhs

ERR_DT = 5          # dt_s not > 0 (status of the step kernels, beside the di.ERR_* codes)

# scalar slots of fb
F_T, F_U, F_RTOL, F_ATOL, F_ADAPT = range(5)
N_SCALARS = 8       # 5 used; the first array starts on the 64-byte boundary
# slots of ib: N, then the offsets of the arrays in fb, then the routing map
I_N = 0
(O_Y, O_D0, O_THETA, O_MU_SCALE, O_B_NODE, O_C_NODE, O_B_RING, O_BP, O_STATS, O_INFO,
 O_OBS, O_FSEG, O_WORK) = range(1, 14)
I_ROUTE = 14


def lengths(n: int) -> tuple[int, ...]:
    """Lengths of the arrays ``O_Y .. O_WORK`` in ``fb`` for ``n`` internal nodes per cable."""
    m = 2 * n + 2
    return (m + 2, m, 2 * n, 2 * n, 2 * n, m, m, rhs.BP_SIZE, di.N_STATS, 3, 6, m,
            di.N_WORK * (m + 2))


def new_buffers(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Zeroed ``(fb, ib)`` for ``n`` internal nodes per cable, offsets and routing map set.

    Each array starts on an 8-element (64-byte) boundary of ``fb``.
    """
    m = 2 * n + 2
    ib = np.zeros(I_ROUTE + m, dtype=np.int64)
    ib[I_N] = n
    off = N_SCALARS
    for slot, length in zip(range(O_Y, O_WORK + 1), lengths(n)):
        ib[slot] = off
        off += -(-length // 8) * 8
    route = ib[I_ROUTE:]
    route[:] = -1
    for j in range(1, n + 1):
        route[j] = j - 1
    for j in range(n + 2, m):
        route[j] = 3 * n + 1 - j
    return np.zeros(off), ib


def view(fb: np.ndarray, ib: np.ndarray, slot: int) -> np.ndarray:
    """Numpy view of array ``slot`` (``O_*``) of ``fb``; the work array as (N_WORK, m+2)."""
    length = lengths(int(ib[I_N]))[slot - O_Y]
    v = fb[ib[slot]: ib[slot] + length]
    return v.reshape(di.N_WORK, -1) if slot == O_WORK else v


@njit(cache=True)
def node_coefficients(theta_r, mu_scale_r, b_node_r, mu, route, c_node, b_ring) -> int:
    """Per-ring-entry friction factor ``mu*scale*theta/2`` and damping from routing arrays.

    :returns: ``di.OK``, or ``di.ERR_PARAM`` if a damping is not > 0 or a friction
        multiplier not >= 0 (NaN included) or an array has the wrong length.
    """
    if mu_scale_r.shape[0] != theta_r.shape[0] or b_node_r.shape[0] != theta_r.shape[0]:
        return di.ERR_PARAM
    for j in range(route.shape[0]):
        r = route[j]
        if r < 0:
            c_node[j] = 0.0
            b_ring[j] = 1.0
        else:
            if not (b_node_r[r] > 0.0 and mu_scale_r[r] >= 0.0):
                return di.ERR_PARAM
            c_node[j] = 0.5 * mu * mu_scale_r[r] * theta_r[r]
            b_ring[j] = b_node_r[r]
    return di.OK


@njit(cache=True)
def _arr(fb, ib, slot, length):
    o = ib[slot]
    return fb[o: o + length]


@njit(cache=True)
def step_held_with(fb, ib, dt, u, text, mu_scale_r, b_node_r) -> int:
    """One held-input interval of ``dt`` [s] (input torque ``u``, external torque ``text``
    [Nm]) from the state in ``fb``, with the per-node friction multipliers ``mu_scale_r`` and
    dampings ``b_node_r`` (2N,) given; on success time, input and observations are updated."""
    if not dt > 0.0:
        return ERR_DT
    n = ib[I_N]
    m = 2 * n + 2
    y = _arr(fb, ib, O_Y, m + 2)
    d0 = _arr(fb, ib, O_D0, m)
    c_node = _arr(fb, ib, O_C_NODE, m)
    b_ring = _arr(fb, ib, O_B_RING, m)
    bp = _arr(fb, ib, O_BP, rhs.BP_SIZE)
    stats = _arr(fb, ib, O_STATS, di.N_STATS)
    work = _arr(fb, ib, O_WORK, di.N_WORK * (m + 2)).reshape((di.N_WORK, m + 2))
    st = node_coefficients(_arr(fb, ib, O_THETA, 2 * n), mu_scale_r, b_node_r, bp[rhs.BP_MU],
                           ib[I_ROUTE: I_ROUTE + m], c_node, b_ring)
    if st != di.OK:
        return st
    t0 = fb[F_T]
    t1 = t0 + dt
    steps = stats[di.S_STEPS]
    st = di.advance(y, t0, t1, u, u, text, text, n, d0, c_node, b_ring, bp, fb[F_RTOL],
                    fb[F_ATOL], fb[F_ADAPT] != 0.0, work, stats, _arr(fb, ib, O_INFO, 3))
    if st != di.OK:
        return st
    f_seg = _arr(fb, ib, O_FSEG, m)
    obs = _arr(fb, ib, O_OBS, 6)
    if stats[di.S_STEPS] != steps:
        # the last accepted step left the segment forces of the final state in work[W_FS]
        fs = work[di.W_FS]
        for j in range(m):
            f_seg[j] = fs[j]
        di.observe_forces(y, u, n, bp, f_seg, obs)
    else:
        di.observe(y, u, n, d0, bp, f_seg, obs)
    fb[F_T] = t1
    fb[F_U] = u
    return di.OK


@njit(cache=True)
def step_held(fb, ib, dt, u, text) -> int:
    """:func:`step_held_with` with the model's own ``mu_scale`` / ``b_node_Ns_m`` (views of
    ``fb``)."""
    n = ib[I_N]
    return step_held_with(fb, ib, dt, u, text, _arr(fb, ib, O_MU_SCALE, 2 * n),
                          _arr(fb, ib, O_B_NODE, 2 * n))


STEP_HELD_SIG = "int64(float64[::1], int64[::1], float64, float64, float64)"
_entry: list[Callable[..., int]] = []


def step_held_entry() -> Callable[..., int]:
    """The compiled :func:`step_held` for C-contiguous ``(fb, ib)`` and float scalars,
    called without the dispatcher's per-call type resolution (the scalars are converted
    with ``float()`` semantics by the compiled wrapper). Compiles or loads from the cache
    on first use; falls back to the dispatcher where no entry point is available."""
    if not _entry:
        compile_ = getattr(step_held, "compile", None)
        entry = compile_(STEP_HELD_SIG) if compile_ is not None else None
        _entry.append(entry if callable(entry) else step_held)
    return _entry[0]


@njit(cache=True)
def run(y, t, u, te, n, d0, c_node, b_ring, bp, rtol, atol, adaptive, work, stats, info, obs,
        seg, record) -> int:
    """Offline run over the samples ``t`` [s] (inputs piecewise linear), observations into
    ``obs`` and (if ``record``) segment tensions into ``seg`` at each sample."""
    if adaptive:
        return dense.run_dense(y, t, u, te, n, d0, c_node, b_ring, bp, rtol, atol, work, stats,
                               info, obs, seg, record)
    f_seg = work[di.W_FS][: 2 * n + 2]
    di.observe(y, u[0], n, d0, bp, f_seg, obs[0])
    seg[0, :] = f_seg
    for i in range(t.shape[0] - 1):
        st = di.advance(y, t[i], t[i + 1], u[i], u[i + 1], te[i], te[i + 1], n, d0, c_node,
                        b_ring, bp, rtol, atol, False, work, stats, info)
        if st != di.OK:
            return st
        di.observe(y, u[i + 1], n, d0, bp, f_seg, obs[i + 1])
        if record:
            seg[i + 1, :] = f_seg
    return di.OK
