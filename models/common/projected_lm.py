"""A small bounded Levenberg-Marquardt for output-error fits on long runs, with the
finite-difference Jacobian's columns simulated in parallel threads.

Why not :func:`scipy.optimize.least_squares` here: on millions of samples its cost is the
simulations, and it evaluates the Jacobian's columns one after the other and a last
Jacobian after the final step whether or not anybody needs it. This driver

* forms each column by the same forward difference as scipy's ``'2-point'`` scheme with a
  relative ``diff_step`` (step ``diff_step * x``, flipped where it would leave the bounds),
  one simulation per column, the columns on a thread pool (the
  simulation kernel releases the GIL: ``nogil``);
* solves the damped normal equations ``(A + lam diag(A)) d = -g`` in the scaled variables
  (``A = J^T J``, ``g = J^T r``; a few parameters, so ``p x p``) for the parameters not held
  on a bound (one is held where its descent direction leaves the domain) and projects the
  step onto the bounds; a step is kept only if it lowers the sum of squares, otherwise
  ``lam`` grows;
* stops after ``n_iter`` accepted steps (the caller starts it near the optimum, from a fit
  on a part of the data); a Jacobian for the parameter covariance is the last one computed,
  or one at the final point when asked (``final_jac``).

Worker exceptions are re-raised in the caller (``Future.result``); the pool lives only for
one Jacobian, so no thread outlives a call.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Callable

import numpy as np

from capstan.models.common.errors import ModelError

#: threads for the Jacobian's columns (the machine's cores, at most 4)
N_THREADS = max(1, min(4, os.cpu_count() or 1))
#: damping trials per iteration before giving up (each costs one simulation)
MAX_TRIALS = 4
LAMBDA0 = 1e-3

Residual = Callable[[np.ndarray], np.ndarray]


@dataclass
class LMResult:
    """Result of :func:`projected_lm`.

    :ivar x: the parameters at the end.
    :ivar r: the residual vector there.
    :ivar jac: a Jacobian (``n x p``), or None when not asked for.
    :ivar jac_at_x: True when ``jac`` is the Jacobian at ``x`` (else at the previous point).
    :ivar nfev: residual evaluations (simulations), Jacobian columns included.
    :ivar n_accepted: steps that lowered the sum of squares.
    """

    x: np.ndarray
    r: np.ndarray
    jac: np.ndarray | None
    nfev: int
    n_accepted: int
    jac_at_x: bool = False

    @property
    def cost(self) -> float:
        """Half the sum of squares (scipy's convention)."""
        return 0.5 * float(np.dot(self.r, self.r))


def fd_steps(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, diff_step: float,
             abs_step: np.ndarray | None = None) -> np.ndarray:
    """Forward-difference steps as scipy's ``'2-point'`` scheme with relative step
    ``diff_step``: ``diff_step * sign(x) * |x|`` (``sqrt(eps) * max(1, |x|)`` where that is 0),
    or ``abs_step`` where given and finite; negated where ``x + h`` leaves ``[lo, hi]`` and
    ``-h`` fits, else towards the farther bound."""
    sign = np.where(x >= 0.0, 1.0, -1.0)
    h = diff_step * sign * np.abs(x)
    h = np.where((x + h) - x == 0.0, np.sqrt(np.finfo(float).eps) * sign * np.maximum(1.0, np.abs(x)), h)
    if abs_step is not None:
        h = np.where(np.isfinite(abs_step), sign * np.abs(abs_step), h)
    lower, upper = x - lo, hi - x
    violated = (x + h < lo) | (x + h > hi)
    fitting = np.abs(h) <= np.maximum(lower, upper)
    h = np.where(violated & fitting, -h, h)
    h = np.where(~fitting & (upper >= lower), upper, h)
    h = np.where(~fitting & (upper < lower), -lower, h)
    return h


def fd_jacobian(fun: Residual, x: np.ndarray, r0: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                diff_step: float, n_threads: int = N_THREADS, abs_step: np.ndarray | None = None) -> np.ndarray:
    """Forward-difference Jacobian of ``fun`` at ``x`` (``r0 = fun(x)``), columns in parallel.

    :raises ModelError: if a column is not finite; whatever ``fun`` raises.
    """
    h = fd_steps(x, lo, hi, diff_step, abs_step)
    J = np.empty((r0.shape[0], x.shape[0]), order="F")

    def column(j: int) -> None:
        xj = x.copy()
        xj[j] = x[j] + h[j]
        dx = xj[j] - x[j]
        J[:, j] = (fun(xj) - r0) / dx

    if n_threads <= 1 or x.shape[0] == 1:
        for j in range(x.shape[0]):
            column(j)
    else:
        with ThreadPoolExecutor(max_workers=n_threads, thread_name_prefix="fd-jacobian") as ex:
            for fut in [ex.submit(column, j) for j in range(x.shape[0])]:
                fut.result()
    if not np.all(np.isfinite(J)):
        raise ModelError("finite-difference Jacobian: a column is not finite (the simulation diverged)")
    return J


def projected_lm(fun: Residual, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray, x_scale: np.ndarray,
                 n_iter: int, diff_step: float, want_jac: bool = False, final_jac: bool = True,
                 n_threads: int = N_THREADS, abs_step: np.ndarray | None = None,
                 r0: np.ndarray | None = None, max_trials: int = MAX_TRIALS) -> LMResult:
    """Bounded Levenberg-Marquardt from ``x0`` (see the module docstring).

    :param fun: residual vector of the parameters (one simulation per call).
    :param x_scale: characteristic size of each parameter (the steps are solved in ``x / x_scale``).
    :param n_iter: accepted steps at most (each costs ``len(x0)`` + 1..``MAX_TRIALS`` evaluations).
    :param abs_step: absolute difference steps per parameter (NaN: relative ``diff_step``);
        for coefficients that start at 0, where a relative step is no step.
    :param max_trials: damping trials per iteration (each one simulation).
    :param r0: ``fun(x0)`` when the caller has it (used if ``x0`` is inside the bounds).
    :param want_jac: return a Jacobian: the one at the final point when ``final_jac``
        (``len(x0)`` more evaluations after an accepted step), else the last one computed
        (at the point before the last step; :attr:`LMResult.jac_at_x` says which).
    :raises ModelError: if the residual at the start is not finite.
    """
    x = np.clip(np.asarray(x0, dtype=float), lo, hi)
    if r0 is not None and np.array_equal(x, x0):
        r, nfev = r0, 0
    else:
        r, nfev = fun(x), 1
    if not np.all(np.isfinite(r)):
        raise ModelError("projected LM: the residual at the start is not finite")
    sse = float(np.dot(r, r))
    lam = LAMBDA0
    accepted = 0
    J: np.ndarray | None = None
    jac_at_x = False
    for _ in range(n_iter):
        J = fd_jacobian(fun, x, r, lo, hi, diff_step, n_threads, abs_step)
        nfev += x.size
        jac_at_x = True
        Js = J * x_scale
        A = Js.T @ Js
        g = Js.T @ r
        dA = np.maximum(np.diag(A), 1e-12 * max(float(np.max(np.diag(A))), 1e-300))
        # active set: a parameter on a bound whose descent direction leaves the domain is held
        free = ~(((x <= lo) & (g > 0.0)) | ((x >= hi) & (g < 0.0)))
        moved = False
        for _trial in range(max_trials):
            d = np.zeros_like(x)
            try:
                Af = A[np.ix_(free, free)] + lam * np.diag(dA[free])
                d[free] = np.linalg.solve(Af, -g[free])
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            xn = np.clip(x + x_scale * d, lo, hi)
            if np.array_equal(xn, x):
                break
            rn = fun(xn)
            nfev += 1
            sn = float(np.dot(rn, rn)) if np.all(np.isfinite(rn)) else np.inf
            if sn < sse:
                x, r, sse, moved = xn, rn, sn, True
                lam = max(lam / 10.0, 1e-9)
                break
            lam *= 10.0
        if not moved:
            break                       # J is still the Jacobian at x
        accepted += 1
        jac_at_x = False
    if want_jac and (J is None or (final_jac and not jac_at_x)):
        J = fd_jacobian(fun, x, r, lo, hi, diff_step, n_threads, abs_step)
        nfev += x.size
        jac_at_x = True
    return LMResult(x, r, J if want_jac else None, nfev, accepted, jac_at_x and want_jac)
