"""Error-controlled integration of the distributed model across sample times.

Offline counterpart of :func:`capstan.models.distributed.integrator.advance`: the same SDIRK2 steps
and error control, but the steps are chosen by the error estimate and may span several
input samples (the input is piecewise linear between its samples and is evaluated at the
stage times). Two limits keep the input resolved: a step spans at most
``MAX_STEP_SAMPLES`` sample intervals, and it ends on a sample wherever the piecewise-
linear input deviates at an interior sample by more than ``rtol * max|input|`` (at least
``rtol`` x 1 Nm) from the quadratic through its values at the step's three points - a
kink or jump between samples, which the stage evaluations would not see. Smooth inputs
deviate by O(h^3) only.

Outputs at the sample times come from the quadratic through the step's three points
``(t, y_n)``, ``(t + gamma h, Z_1)``, ``(t + h, Z_2)``; its error is of the size of the
embedded error estimate the step passed (both are first-order terms of ``h``), so the
outputs keep the requested tolerance.

Every function returns a status code instead of raising (Numba).
"""

from __future__ import annotations

import math

from numba import njit

from capstan.models.distributed import integrator as di

#: longest step, in sample intervals
MAX_STEP_SAMPLES = 8


@njit(cache=True)
def _input_at(t_s, x, k, tq) -> tuple:
    """Piecewise-linear ``x`` at ``tq`` searching forward from sample ``k``; ``(value, k)``."""
    last = t_s.shape[0] - 1
    while k < last - 1 and t_s[k + 1] <= tq:
        k += 1
    s = (tq - t_s[k]) / (t_s[k + 1] - t_s[k])
    if s > 1.0:
        s = 1.0
    return x[k] + (x[k + 1] - x[k]) * s, k


@njit(cache=True)
def _lagrange(th: float) -> tuple:
    """Weights of the quadratic through theta = 0, gamma, 1 at ``th``."""
    g = di.GAMMA
    return ((th - g) * (th - 1.0) / g, th * (th - 1.0) / (g * (g - 1.0)), th * (th - g) / (1.0 - g))


@njit(cache=True)
def _input_dev(t_s, x, k, t, h) -> float:
    """Largest deviation of the piecewise-linear ``x`` at the samples strictly inside
    ``(t, t + h)`` (searching from sample ``k``) from the quadratic through its values at
    the step's points ``t``, ``t + gamma h``, ``t + h`` (zero for a smooth input up to
    O(h^3); a kink or jump between samples shows)."""
    xa, _ = _input_at(t_s, x, k, t)
    x1, _ = _input_at(t_s, x, k, t + di.GAMMA * h)
    xb, _ = _input_at(t_s, x, k, t + h)
    dev = 0.0
    ns = t_s.shape[0]
    t_end = t + h
    while k < ns and t_s[k] < t_end:
        if t_s[k] > t:
            l0, l1, l2 = _lagrange((t_s[k] - t) / h)
            dev = max(dev, abs(x[k] - (l0 * xa + l1 * x1 + l2 * xb)))
        k += 1
    return dev


@njit(cache=True)
def _resolved_step(t_s, u, te, kt, t, h, tol_u, tol_e) -> float:
    """``h``, or a shorter step ending on a sample, such that the inputs between samples
    are represented by their values at the step's points within ``tol_u``/``tol_e`` (a
    kink or jump of the input inside a step would otherwise go unseen by the stages)."""
    while True:
        if _input_dev(t_s, u, kt, t, h) <= tol_u and _input_dev(t_s, te, kt, t, h) <= tol_e:
            return h
        t_end = t + h
        k = kt + 1
        while t_s[k + 1] < t_end:
            k += 1
        # t_s[k] is the last sample inside (t, t_end): end the step there
        h = t_s[k] - t


@njit(cache=True)
def run_dense(y, t_s, u, te, n, d0, c_node, b_node, bp, rtol, atol, work, stats, info, obs,
              seg, record) -> int:
    """Integrate from ``t_s[0]`` to ``t_s[-1]``; observations at every sample into ``obs``.

    :param y: state, advanced in place to ``t_s[-1]``.
    :param u, te: input torque and external torque samples at ``t_s`` [Nm].
    :param obs: (len(t_s), 6) observations (see :func:`di.observe`); row 0 = the start.
    :param seg: (len(t_s), m) segment tensions if ``record`` (else (1, m), row 0 only).
    :param stats: counters; ``stats[S_H]`` is the initial step proposal (0: a tenth of the
        first sample interval) and receives the last proposal.
    :returns: status code (OK, ERR_SLACK, ERR_NEWTON, ERR_NONFINITE).
    """
    m = 2 * n + 2
    ns = t_s.shape[0]
    f_seg = work[di.W_FS][:m]
    yi = work[di.W_YI]
    di.setup(n, b_node, bp, atol, work)
    di.observe(y, u[0], n, d0, bp, f_seg, obs[0])
    seg[0, :] = f_seg
    u_max = 1.0
    e_max = 1.0
    for i in range(ns):
        u_max = max(u_max, abs(u[i]))
        e_max = max(e_max, abs(te[i]))
    tol_u = rtol * u_max
    tol_e = rtol * e_max
    t_end = t_s[ns - 1]
    t = t_s[0]
    h = stats[di.S_H] if stats[di.S_H] > 0.0 else 0.1 * (t_s[1] - t_s[0])
    rejected = False
    kt = 0          # input cursor at t
    k_out = 0       # last sample written
    g = di.GAMMA
    Y0 = work[di.W_Y0]
    Z1 = work[di.W_Z1]
    Z2 = work[di.W_Z2]
    while t < t_end:
        h_cand = h
        h = min(h, t_s[min(kt + MAX_STEP_SAMPLES, ns - 1)] - t)
        remaining = t_end - t
        last = h >= remaining * (1.0 - 1e-9)
        if last:
            h = remaining
        else:
            h = _resolved_step(t_s, u, te, kt, t, h, tol_u, tol_e)
            last = h >= remaining * (1.0 - 1e-9)
        u1, k1 = _input_at(t_s, u, kt, t + g * h)
        e1, _ = _input_at(t_s, te, kt, t + g * h)
        u2, _ = _input_at(t_s, u, k1, t + h)
        e2, _ = _input_at(t_s, te, k1, t + h)
        err = di.try_step(n, y, h, u1, e1, u2, e2, d0, c_node, b_node, bp, work, rtol, True,
                          stats)
        if not math.isfinite(err):
            stats[di.S_NEWTON_FAIL] += 1.0
            h *= 0.25
            if h < di.H_MIN_S:
                info[di.I_T] = t
                return di.ERR_NEWTON
            continue
        if err > 1.0:
            rejected = True
            stats[di.S_REJECT] += 1.0
            h *= max(0.2, 0.9 / math.sqrt(err))
            if h < di.H_MIN_S:
                info[di.I_T] = t
                return di.ERR_NEWTON
            continue
        t_new = t_end if last else t + h
        # outputs inside (t, t_new]: quadratic through Y0 (0), Z1 (gamma), Z2 (1)
        while k_out < ns - 1 and (t_s[k_out + 1] <= t_new or (last and k_out + 1 == ns - 1)):
            k_out += 1
            l0, l1, l2 = _lagrange(min((t_s[k_out] - t) / h, 1.0))
            for i in range(m + 2):
                yi[i] = l0 * Y0[i] + l1 * Z1[i] + l2 * Z2[i]
            di.observe(yi, u[k_out], n, d0, bp, f_seg, obs[k_out])
            if record:
                seg[k_out, :] = f_seg
        st = di.accept(n, h, t_new, y, d0, bp, work, stats, info)
        if st != di.OK:
            return st
        t = t_new
        while kt < ns - 2 and t_s[kt + 1] <= t:
            kt += 1
        fac = di.step_factor(err)
        if rejected:
            fac = min(fac, 1.0)
            rejected = False
        # a step shortened by the sample or input limits does not shrink the proposal
        h = max(h * fac, h_cand) if fac >= 1.0 else h * fac
    stats[di.S_H] = h
    # the last row is the committed end state (not an interpolant)
    di.observe(y, u[ns - 1], n, d0, bp, f_seg, obs[ns - 1])
    if record:
        seg[ns - 1, :] = f_seg
    return di.OK
