"""The cost's cross term ``l_ux`` in AICO's messages, by a change of control variables.

AICO's control prior ``N[u_t | h_t, H_t]`` knows no coupling of ``u_t`` with ``x_t``; a cost with one (the
control toward gravity, ``u - g(q)``: ``l_ux = -2 w C G``) loses it, and the sweeps' step is then no
Gauss-Newton step (on the bench's chain R-AICO's iterations converged linearly, the model's predicted
decrease half the actual one, docs/planning.md "Convergence"). With the quadratic model's cross term
``(u - u_bar)^T L (x - x_bar)`` and ``K = H^-1 L``, ``u = v - K x`` removes it exactly:

- the control prior of ``v``: ``H`` and ``h + L x_bar``;
- the dynamics ``x' = (A - B K) x + a + B v``;
- the task message ``R - L^T K`` (the Schur complement, positive semi-definite where the joint model is)
  and ``r - K^T (h + L x_bar) + L^T u_bar``;
- the controller ``v = o + O x`` is ``u = o + (O - K) x``.

Done after the linearization, before the sweeps; only without relinearization within the sweeps (``theta =
inf``, the robust schedule), which would relinearize a step without it.
"""

from __future__ import annotations

import numpy as np

from raico.planning.aico.sweeps import _block_form_dt
from raico.planning.problem import Problem


def cross_hessian(problem: Problem, X: np.ndarray) -> np.ndarray | None:
    """``l_ux (T, n_u, n_x)`` of the problem's joint terms that state one (``add_cross_derivatives``) at
    ``X[:T]`` (their nominal controls set by ``set_nominal``), or ``None`` if none does."""
    terms = [t for t in problem.joint_terms if hasattr(t, "add_cross_derivatives")]
    if not terms:
        return None
    L = np.zeros((problem.T, problem.n_u, problem.n_x))
    for term in terms:
        term.add_cross_derivatives(X[:problem.T], L)
    return L if np.any(L) else None


def eliminate(sw, L: np.ndarray | None) -> np.ndarray | None:
    """Rewrite the sweeps' linearization (``sw``: :class:`raico.planning.aico.sweeps.Sweeps` after
    ``linearize_all``) for ``v = u + K x``; returns ``K (T, n_u, n_x)`` (the controller's ``O`` is ``O - K``),
    or ``None`` without a cross term (``L`` ``None``: the linearization as it is)."""
    n, m, T = sw.n, sw.m, sw.T
    sw.cross_K = None
    if L is None:
        if sw.lti:     # the shared C again (an earlier elimination made one per step)
            sw.C = np.broadcast_to(sw._C0, sw.C.shape)
        return None
    X, U = sw.X[:T], sw.U
    # (batched products on C-contiguous operands: numpy's stacked matmul takes BLAS only for those)
    Hinv = np.ascontiguousarray(sw.Hinv)
    K = np.matmul(Hinv, L)                                         # H^-1 L
    h = sw.h + np.matmul(L, X[:, :, None])[:, :, 0]                # h + L x_bar
    if sw.lti:     # a shared C (its one matrix kept unchanged in sw._C0): one per step, made afresh here
        sw.C = np.array(np.broadcast_to(sw._C0, sw.C.shape), order="C")
    B = np.ascontiguousarray(sw.C[:, :n, :m])
    dt = _block_form_dt(sw.p.dynamics)
    block = _block_steps(sw.C, n, m, dt)
    sw.C[:, :n, m:m + n] -= np.matmul(B, K)                        # A - B K
    if block.any():     # keep the block form exact where C had it: the position rows dt times the velocity rows
        h2 = n // 2
        rows = slice(None) if block.all() else np.flatnonzero(block)
        top = dt * sw.C[rows, h2:n, :m + n]
        top[:, np.arange(h2), m + np.arange(h2)] += 1.0
        sw.C[rows, :h2, :m + n] = top
    Lt = np.ascontiguousarray(np.swapaxes(L, 1, 2))
    LK = np.matmul(Lt, K)                                          # L^T H^-1 L, symmetric up to rounding
    RA = sw.RA[:T]
    RA[:, :, :n] -= 0.5 * (LK + np.swapaxes(LK, 1, 2))             # the Schur complement R - L^T H^-1 L
    RA[:, :, n] += np.matmul(Lt, (U - np.matmul(Hinv, h[:, :, None])[:, :, 0])[:, :, None])[:, :, 0]
    sw.h, sw.cross_K = h, K
    # Qbar = q I + B H^-1 B^T is unchanged (B and H are); the drift a + B H^-1 h gains B H^-1 L x_bar
    sw.a_eff = sw.a_eff + np.matmul(B, np.matmul(K, X[:, :, None]))[:, :, 0]
    return K


def _block_steps(C: np.ndarray, n: int, m: int, dt: float) -> np.ndarray:
    """``(T,)`` bool: the steps whose ``C_t`` has the semi-implicit Euler block form the sweep kernel takes (its
    position rows ``dt`` times its velocity rows, plus ``I`` on the position block; ``semi_implicit`` of
    ``raico/planning/csweep.c``, the same test to 8 units in the last place)."""
    h = n // 2
    if not dt > 0 or n != 2 * h:
        return np.zeros(len(C), dtype=bool)
    top, u = C[:, :h, :m + n], dt * C[:, h:n, :m + n]
    u[:, np.arange(h), m + np.arange(h)] += 1.0
    return np.all(np.abs(top - u) <= 8.0 * np.finfo(float).eps * np.abs(u), axis=(1, 2))
