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
    if L is None:
        if sw.lti:     # the shared C again (an earlier elimination made one per step)
            sw.C = np.broadcast_to(sw._C0, sw.C.shape)
        return None
    X, U = sw.X[:T], sw.U
    K = np.linalg.solve(sw.H, L)                                   # H^-1 L
    h = sw.h + np.einsum("tij,tj->ti", L, X)                       # h + L x_bar
    if sw.lti:     # a shared C (its one matrix kept unchanged in sw._C0): one per step, made afresh here
        sw.C = np.array(np.broadcast_to(sw._C0, sw.C.shape))
    B = sw.C[:, :n, :m]
    sw.C[:, :n, m:m + n] -= B @ K                                  # A - B K
    RA = sw.RA
    RA[:T, :, :n] -= np.einsum("tki,tkj->tij", L, K)                # R - L^T H^-1 L
    RA[:T, :, n] += np.einsum("tki,tk->ti", L, U) - np.einsum("tki,tk->ti", K, h)
    RA[:T, :, :n] = 0.5 * (RA[:T, :, :n] + np.swapaxes(RA[:T, :, :n], 1, 2))
    sw.h = h
    sw._control_marginals()
    return K
