"""The controls' box inside AICO's backward pass, as BoxDDP does (Tassa, Mansard, Todorov, ICRA 2014).

At step ``t`` the backward message leaves the control's quadratic model ``1/2 u^T M u - u^T (g - F x)``
(``M = B^T V* B + H``, ``F = B^T V* A``, ``g = B^T V*(m' - a) + h``: :meth:`raico.planning.aico.sweeps.Sweeps.backward`).
Unbounded, its minimizer is the controller ``u = o + O x``. With a box ``lo <= u <= hi`` the control at the
iterate's state ``x_bar`` is the box-constrained QP's solution (:func:`box_qp`, projected Newton); the
clamped rows keep their value (zero feedback), the free rows minimize with the clamped ones held (their
gains from the free block's Cholesky factor), and the backward message is the value of that affine
controller (:func:`boxed_step`), so earlier steps see the saturation. Under the cross term's change of
control variables ``v = u + K x`` (:mod:`raico.planning.aico.cross`) the box on ``u`` at ``x_bar`` is the
box ``lo + K x_bar <= v <= hi + K x_bar`` and a clamped row of ``v`` has feedback ``K`` (``u`` constant).

It applies to simple bounds on the controls (torques with effort limits: ``Bounds.u_lower``/``u_upper``);
where the controls are accelerations the torque limit is no box (:class:`raico.planning.constraints.TorqueBox`
keeps it in the augmented Lagrangian), and joint ranges and velocity limits stay there too.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from raico.planning.problem import Problem

if TYPE_CHECKING:
    from raico.planning.aico.sweeps import Sweeps

MAX_ITER = 100       # projected Newton iterations (each one factorization of the free block)
ARMIJO = 0.1         # sufficient decrease of the projected line search
STEP_FALL = 0.6      # its step factor
MIN_STEP = 1e-22     # the least step tried


def applies(problem: Problem) -> bool:
    """Whether ``problem`` has a box on its controls the backward pass can keep (finite effort limits on the
    controls themselves; not the torques of accelerations as controls)."""
    b = problem.bounds
    return b is not None and b.has_controls


def box_qp(M: np.ndarray, q: np.ndarray, lo: np.ndarray, hi: np.ndarray, u0: np.ndarray | None = None
           ) -> tuple[np.ndarray, np.ndarray, int]:
    """``argmin 1/2 u^T M u + q^T u`` over ``lo <= u <= hi`` (``M (m, m)`` positive definite) by projected
    Newton (Tassa et al.'s boxQP): the rows at a bound whose gradient pushes outward are clamped, a Newton
    step on the free rows with the clamped ones held, a projected Armijo line search; done when the clamped
    set repeats after a full, unclipped step (the free rows then solve their equations exactly) or no descent
    is left. Returns the solution, the free mask and the iterations (0: ``u0`` clipped was it)."""
    m = len(q)
    u = np.clip(np.zeros(m) if u0 is None else np.asarray(u0, dtype=float), lo, hi)
    free = np.ones(m, dtype=bool)
    solved: np.ndarray | None = None   # the free set whose equations the last step solved (a full, unclipped step)
    val = 0.5 * u @ M @ u + q @ u
    for it in range(MAX_ITER):
        grad = q + M @ u
        free = ~(((u <= lo) & (grad > 0)) | ((u >= hi) & (grad < 0)))
        if not free.any() or (solved is not None and np.array_equal(free, solved)):
            return u, free, it
        # Newton on the free rows with the clamped ones held: M_ff (u_f + d_f) = -(q_f + M_fc u_c)
        rhs = q[free] + M[np.ix_(free, ~free)] @ u[~free]
        L = np.linalg.cholesky(M[np.ix_(free, free)])
        d = np.zeros(m)
        d[free] = -np.linalg.solve(L.T, np.linalg.solve(L, rhs)) - u[free]
        slope = float(grad @ d)
        if not slope < 0:      # no descent left on the free rows: the point is stationary
            return u, free, it
        step = 1.0
        while True:
            full = u + step * d
            cand = np.clip(full, lo, hi)
            cval = 0.5 * cand @ M @ cand + q @ cand
            if cval - val <= ARMIJO * step * slope or step < MIN_STEP:
                break
            step *= STEP_FALL
        solved = free if step == 1.0 and np.array_equal(cand, full) else None
        u, val = cand, cval
    return u, free, MAX_ITER


def boxed_step(M: np.ndarray, F: np.ndarray, g: np.ndarray, lo: np.ndarray, hi: np.ndarray, x_bar: np.ndarray,
               Kc: np.ndarray | None, AVA: np.ndarray, AVm: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The controller ``u = k + G x`` of the box at step ``t`` and its backward message, or ``None`` where the
    unbounded controller at ``x_bar`` is inside the box (then the sweeps' own numbers stand).

    ``M, F, g``: the control's model ``1/2 u^T M u - u^T (g - F x)``; ``lo, hi``: the box of ``u`` at ``x_bar``;
    ``Kc (m, n)``: a clamped row's feedback (the cross term's ``K``; ``None``: zero); ``AVA = A^T V* A``,
    ``AVm = A^T V*(m' - a)``. Returns ``k (m,)``, ``G (m, n)``, ``V_t^-1 (n, n)``, ``V_t^-1 v_t (n,)``, the
    message the value of that controller: ``AVA + G^T M G + G^T F + F^T G`` and
    ``AVm + G^T g - G^T M k - F^T k``."""
    L = np.linalg.cholesky(M)
    u_free = np.linalg.solve(L.T, np.linalg.solve(L, g - F @ x_bar))
    if np.all((u_free >= lo) & (u_free <= hi)):
        return None
    u, free, _ = box_qp(M, F @ x_bar - g, lo, hi, np.clip(u_free, lo, hi))
    clamped = ~free
    G = np.zeros_like(F)
    if Kc is not None:
        G[clamped] = Kc[clamped]
    if free.any():   # the free rows' gains, the clamped rows' feedback held: M_ff G_f = -(F_f + M_fc G_c)
        Lf = np.linalg.cholesky(M[np.ix_(free, free)])
        rhs = F[free] + M[np.ix_(free, clamped)] @ G[clamped]
        G[free] = -np.linalg.solve(Lf.T, np.linalg.solve(Lf, rhs))
    k = u - G @ x_bar
    GMG = G.T @ M @ G
    GF = G.T @ F
    Vinv = AVA + GMG + GF + GF.T
    Vinv = 0.5 * (Vinv + Vinv.T)
    Vv = AVm + G.T @ g - G.T @ (M @ k) - F.T @ k
    return k, G, Vinv, Vv


def backward_boxed(sw: Sweeps, t: int, M: np.ndarray, rhs: np.ndarray, FA: np.ndarray) -> bool:
    """The sweeps' backward step ``t`` under the box ``sw.box`` (``(lo, hi)`` of ``u``): the controller
    ``sw.Z[t]`` and the message ``sw.VA[t]`` of :func:`boxed_step` at the iterate's state ``sw.Xprev[t]``
    (the controller is rolled out about it; a relinearization inside the sweeps moves ``sw.X[t]`` toward the
    beliefs, whose forward messages know no box) (``M``; ``rhs = [F | g]``; ``FA = [A^T V* A | A^T V*(m' - a)]``); ``False`` where the box is not active
    there (the caller's unbounded step stands)."""
    n = sw.n
    x_bar, K = sw.Xprev[t], None if sw.cross_K is None else sw.cross_K[t]
    lo, hi = sw.box
    if K is not None:     # the box of v = u + K x at x_bar
        lo, hi = lo + K @ x_bar, hi + K @ x_bar
    out = boxed_step(M, rhs[:, :n], rhs[:, n], lo, hi, x_bar, K, FA[:, :n], FA[:, n])
    if out is None:
        return False
    k, G, Vinv, Vv = out
    sw.Z[t, :, :n], sw.Z[t, :, n] = -G, k
    sw.VA[t, :, :n], sw.VA[t, :, n] = Vinv, Vv
    return True
