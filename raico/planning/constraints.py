"""Hard constraints ``g_t(x_t, u_t) <= 0`` of AICO / R-AICO, kept by an augmented Lagrangian whose
multipliers and penalty move every iteration.

A constraint (:class:`Constraint`) gives, along a trajectory ``X (T+1, n)``, ``U (T, m)``, its values ``G (T+1,
c)`` (``-inf`` where a step is not constrained), the Jacobians ``G_x (T+1, c, n)`` and ``G_u (T+1, c, m)``
(row ``T`` has no control: zero) and a tolerance per row (its unit: rad, rad/s, m). The joint ranges and the
joint velocity limits are :class:`StateBox` es (selection Jacobians, kept sparse); a hard collision term's
distances ``d(q_t) >= margin`` are a :class:`DistanceConstraint` (rows ``margin - d``, only those that can be
active queried); :class:`FunctionConstraint` takes any other ``g(x, u)``.

The method (:class:`AugmentedLagrangian`): the merit ``L(X, U) = cost + sum_t,i psi(g_ti, y_ti)`` with
``psi = ((max(0, y + mu g))^2 - y^2) / (2 mu)``; its Gauss-Newton model adds ``G_x^T lam`` to the task
gradient and ``mu G_x^T diag(lam > 0) G_x`` to the task Hessian (``lam = max(0, y + mu g)``), likewise on the
controls, so AICO's messages carry the constraints. After every accepted iteration the multipliers take
their first-order step ``y = lam`` at the new iterate and, where the largest scaled violation has not fallen by
``DECREASE`` in ``PATIENCE`` updates, ``mu *= MU_GROWTH`` (bounded): the iteration of ProxDDP / CSQP style
(multipliers inside the iteration, a merit function the step must lower), not an outer loop of inner solves.
In the **endgame** (the budget's last iterations) the multipliers step after every accepted iteration and the
penalty grows at the first update without that decrease: the plan the budget ends on is driven inside its limits.

Why this method, and what was not built: docs/planning.md, "Why this augmented Lagrangian".

Where no row of any constraint is ever active (``y = 0`` and ``g < 0`` at every linearization and rollout) the
merit is the cost and nothing is added to the messages: the iterates are the unconstrained ones, bit for bit.

The effort limits are a :class:`ControlBox` of the same set (the rollouts inside the iterations unclipped, so
that the merit sees what the controller asks for); the plan's last rollout clips its controls into the box (a
projection, :meth:`raico.planning.problem.Problem.bounded_rollout`), which keeps them exactly.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

MU_GROWTH = 10.0     # the penalty's growth where the violation did not fall enough
DECREASE = 0.25      # ... by this factor since the last multiplier update
MU_MAX_FACTOR = 1e8  # the penalty's cap, relative to its start
PATIENCE = 3         # updates without that decrease before the penalty grows (1 in the endgame)


class Constraint(Protocol):
    """``g_t(x_t, u_t) <= 0`` per step ``t = 0..T`` (``c`` rows per step)."""

    name: str
    tol: np.ndarray   # (c,) the largest violation that counts as feasible, in the row's unit

    def values(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """``G (T+1, c)``; ``-inf`` where a row does not constrain a step."""
        ...

    def add_derivatives(self, X: np.ndarray, U: np.ndarray, lam: np.ndarray, mu: float,
                        lx: np.ndarray, lxx: np.ndarray, lu: np.ndarray, luu: np.ndarray) -> None:
        """Add ``G_x^T lam`` to ``lx (T+1, n)``, ``mu G_x^T diag(lam > 0) G_x`` to ``lxx (T+1, n, n)`` and
        the control parts to ``lu (T, m)``, ``luu (T, m, m)`` (``lam (T+1, c) >= 0``)."""
        ...


@dataclass
class StateBox:
    """``lo_t <= x_t[idx] <= hi_t`` for ``t = 1..T`` (``x_0`` is the start: no plan changes it): rows
    ``x[idx] - hi`` and ``lo - x[idx]`` (``2k`` per step). ``lo, hi (T+1, k)`` (``-inf`` / ``inf``: none)."""

    name: str
    idx: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    unit_tol: float

    def __post_init__(self) -> None:
        self.idx = np.asarray(self.idx, dtype=int)
        self.lo, self.hi = np.array(self.lo, dtype=float), np.array(self.hi, dtype=float)
        self.lo[0], self.hi[0] = -np.inf, np.inf
        self.tol = np.full(2 * len(self.idx), self.unit_tol)

    def values(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        Q = X[:, self.idx]
        with np.errstate(invalid="ignore"):
            return np.concatenate([Q - self.hi, self.lo - Q], axis=1)

    def add_derivatives(self, X, U, lam, mu, lx, lxx, lu, luu) -> None:
        k = len(self.idx)
        lx[:, self.idx] += lam[:, :k] - lam[:, k:]
        act = (lam[:, :k] > 0).astype(float) + (lam[:, k:] > 0)
        lxx[:, self.idx, self.idx] += mu * act


@dataclass
class ControlBox:
    """``lo <= u_t[idx] <= hi`` for ``t = 0..T-1`` (the effort limits): rows ``u - hi`` and ``lo - u``; ``scale``:
    the penalty's factor for these rows (per (control unit)^2 against the state's unit)."""

    name: str
    idx: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    tol_: np.ndarray
    scale: float = 1.0

    def __post_init__(self) -> None:
        self.idx = np.asarray(self.idx, dtype=int)
        self.tol = np.concatenate([self.tol_, self.tol_])

    def values(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        G = np.full((U.shape[0] + 1, 2 * len(self.idx)), -np.inf)
        W = U[:, self.idx]
        with np.errstate(invalid="ignore"):
            G[:-1] = np.nan_to_num(np.concatenate([W - self.hi, self.lo - W], axis=1), nan=-np.inf)
        return G

    def add_derivatives(self, X, U, lam, mu, lx, lxx, lu, luu) -> None:
        k = len(self.idx)
        lu[:, self.idx] += lam[:-1, :k] - lam[:-1, k:]
        act = (lam[:-1, :k] > 0).astype(float) + (lam[:-1, k:] > 0)
        luu[:, self.idx, self.idx] += mu * act


@dataclass
class FunctionConstraint:
    """A general ``g(x_t, u_t) <= 0`` from a function ``fn(X, U) -> (G (T+1, c), G_x (T+1, c, n), G_u (T+1, c,
    m) or None)``; ``tol (c,)``."""

    name: str
    fn: Callable[[np.ndarray, np.ndarray], tuple]
    tol: np.ndarray

    def _eval(self, X, U):
        return self.fn(X, U)

    def values(self, X, U):
        return self._eval(X, U)[0]

    def add_derivatives(self, X, U, lam, mu, lx, lxx, lu, luu) -> None:
        _, Gx, Gu = self._eval(X, U)
        act = (lam > 0).astype(float)
        lx += np.einsum("tci,tc->ti", Gx, lam)
        lxx += mu * np.einsum("tci,tc,tcj->tij", Gx, act, Gx)
        if Gu is not None:
            lu += np.einsum("tci,tc->ti", Gu[:-1], lam[:-1])
            luu += mu * np.einsum("tci,tc,tcj->tij", Gu[:-1], act[:-1], Gu[:-1])


class TorqueBox:
    """``|tau_t| <= limit`` for the torques ``tau_t = M(q_t) u_t + h(q_t, v_t)`` of accelerations ``u_t`` (pseudo-
    dynamics), ``t = 0..T-1``: rows ``tau / limit - 1`` and ``-tau / limit - 1`` (fractions of the limit) of the
    joints ``idx`` with a finite one. ``model``: ``inverse_dynamics(q, v, a)`` and ``qddot_derivatives(q, v,
    tau)``, whose ``a_q, a_v, M^-1`` give ``tau_q = -M a_q``, ``tau_v = -M a_v``, ``tau_u = M`` (differentiating
    ``a(q, v, tau(q, v, a)) = a``); ``scale``: the penalty's factor for these rows (as :class:`ControlBox`'s)."""

    def __init__(self, name: str, model, limit: np.ndarray, tol: float, scale: float = 1.0):
        self.name, self.model, self.scale = name, model, scale
        self.idx = np.flatnonzero(np.isfinite(limit) & (limit > 0))
        self.limit = np.asarray(limit, float)[self.idx]
        self.tol = np.full(2 * len(self.idx), tol)
        self._memo: tuple | None = None

    def _eval(self, X: np.ndarray, U: np.ndarray, derivatives: bool):
        if self._memo is not None and np.array_equal(self._memo[0], X) and np.array_equal(self._memo[1], U) \
                and (self._memo[3] is not None or not derivatives):
            return self._memo[2], self._memo[3]
        T, n = U.shape
        k = len(self.idx)
        G = np.full((T + 1, 2 * k), -np.inf)
        D = None
        if derivatives:
            D = (np.zeros((T + 1, 2 * k, X.shape[1])), np.zeros((T + 1, 2 * k, n)))
        for t in range(T):
            q, v = X[t, :n], X[t, n:]
            if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v)) and np.all(np.isfinite(U[t]))):
                continue
            tau = np.asarray(self.model.inverse_dynamics(q, v, U[t]), float)
            r = tau[self.idx] / self.limit
            G[t] = np.concatenate([r - 1.0, -r - 1.0])
            if D is not None:
                _, a_q, a_v, Minv = self.model.qddot_derivatives(q, v, tau)
                M = np.linalg.inv(Minv)
                J = np.concatenate([-M @ a_q, -M @ a_v], axis=1)[self.idx] / self.limit[:, None]
                Ju = M[self.idx] / self.limit[:, None]
                D[0][t] = np.concatenate([J, -J])
                D[1][t] = np.concatenate([Ju, -Ju])
        self._memo = (np.array(X), np.array(U), G, D)
        return G, D

    def values(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        return self._eval(X, U, False)[0]

    def add_derivatives(self, X, U, lam, mu, lx, lxx, lu, luu) -> None:
        rows = np.flatnonzero(lam[:-1].any(axis=1))
        if rows.size == 0:
            return
        _, (Gx, Gu) = self._eval(X, U, True)
        L = lam[rows]
        act = (L > 0).astype(float)[:, :, None]
        lx[rows] += np.einsum("tci,tc->ti", Gx[rows], L)
        lxx[rows] += mu * np.matmul(np.swapaxes(Gx[rows] * act, 1, 2), Gx[rows] * act)
        lu[rows] += np.einsum("tci,tc->ti", Gu[rows], L)
        luu[rows] += mu * np.matmul(np.swapaxes(Gu[rows] * act, 1, 2), Gu[rows] * act)


class DistanceConstraint:
    """``d_p(q_t) >= b_tp`` per geometry pair ``p`` and step ``t`` of a collision term (rows ``g = b - d``, m;
    ``d`` capped at the map's ``max_distance``, zero gradient there), ``b`` the term's margin at the steps it
    covers but step 0 (the start: no plan moves it). From a start closer than the margin, a pair's bound
    rises from its start distance ``d0`` as fast as the velocity limits ``vmax`` let it, to first order:
    ``b_tp = min(margin, d0_p + (t - 1) dt |J_p(q0)| vmax)`` (no limit: the margin from step 1).

    Only rows that can be active are queried: the AL gives each row its slack ``y / mu`` (:meth:`set_slack`)
    and a pair whose distance bound reaches ``b + slack`` has ``lam = 0`` exactly: it is culled there
    (``SignedDistances.evaluate``'s ``cull``). The last evaluations are remembered (the AL asks for values,
    derivatives and the violation at one iterate): one serves where its rows' cull distances are at least
    the ones asked for."""

    def __init__(self, term, n_q: int, T: int, q0: np.ndarray, dt: float, vmax: np.ndarray | None, tol: float):
        self.term, self.n_q, self.name = term, n_q, term.name
        self.m = term.taskmap.dim
        self.tol = np.full(self.m, tol)
        self.cap = float(getattr(term.taskmap, "max_distance", math.inf))
        steps = term.active(np.arange(T + 1)).copy()
        steps[0] = False
        self.steps = np.flatnonzero(steps)
        b = np.full((T + 1, self.m), term.margin)
        d0, J0 = term.taskmap.value_and_jacobian(np.asarray(q0, float))
        start = np.flatnonzero(d0 < term.margin)
        if start.size:
            v = np.full(n_q, np.inf) if vmax is None else np.asarray(vmax, float)
            with np.errstate(invalid="ignore"):
                rate = np.where(J0[start] != 0, np.abs(J0[start]) * v, 0.0).sum(axis=1)
                t = np.maximum(np.arange(T + 1) - 1, 0)[:, None] * dt
                b[:, start] = np.minimum(term.margin, d0[start] + np.where(t > 0, t * rate, 0.0))
        self.bound = b[self.steps]
        self.start_inside = int(start.size)
        self.slack: np.ndarray | None = None
        self._memo: list = []

    def set_slack(self, slack: np.ndarray | None) -> None:
        """The rows' ``y / mu`` (``(T+1, m)``, m), or None (no multipliers yet)."""
        self.slack = None if slack is None else slack[self.steps]

    def _eval(self, X: np.ndarray):
        cull = self.bound if self.slack is None else self.bound + self.slack
        for key, c, out in self._memo:   # a row culled at a larger distance is culled at this one
            if np.array_equal(key, X) and np.all(cull <= c):
                return out
        T1, n = X.shape
        G = np.full((T1, self.m), -np.inf)
        Gx = np.zeros((T1, self.m, n))
        if self.steps.size and self.m:
            D, J = self.term.taskmap.evaluate(X[self.steps, :self.n_q], cull=np.minimum(cull, self.cap))[:2]
            G[self.steps] = self.bound - D
            Gx[self.steps, :, :self.n_q] = -np.nan_to_num(J)
        out = (G, Gx)
        self._memo = [(np.array(X), cull.copy(), out), *self._memo[:2]]
        return out

    def values(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        return self._eval(X)[0]

    def add_derivatives(self, X, U, lam, mu, lx, lxx, lu, luu) -> None:
        _, Gx = self._eval(X)
        rows = np.flatnonzero(lam.any(axis=1))
        if rows.size == 0:
            return
        A, L = Gx[rows][:, :, :self.n_q], lam[rows]
        lx[rows, :self.n_q] += np.einsum("tci,tc->ti", A, L)
        Aa = A * (L > 0)[:, :, None]
        lxx[rows, :self.n_q, :self.n_q] += mu * np.matmul(np.swapaxes(Aa, 1, 2), Aa)


class AugmentedLagrangian:
    """The constraints' multipliers ``y`` (one ``(T+1, c)`` array per constraint, ``>= 0``) and penalty ``mu``
    (per (constraint unit)^2, one for all rows: the constraints share the state's units), the merit's extra
    terms and their Gauss-Newton model; :meth:`update` is the per-iteration step."""

    def __init__(self, constraints: list, T: int, mu: float):
        self.constraints, self.T = list(constraints), T
        self.mu0 = self.mu = float(mu)
        self.y: list[np.ndarray | None] = [None] * len(self.constraints)
        self.last_violation = math.inf   # the scaled violation at the last multiplier update
        self.ref_violation = math.inf    # ... where the penalty last grew or the violation last fell enough
        self.stalled = 0                 # updates since then
        self.updates = 0
        self.endgame = False             # the budget's last iterations: feasibility first (update, patience 1)

    def _mu(self, c) -> float:
        return self.mu * getattr(c, "scale", 1.0)

    def _lams(self, X: np.ndarray, U: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        out = []
        for k, c in enumerate(self.constraints):
            G = c.values(X, U)
            y, mu = self.y[k], self._mu(c)
            with np.errstate(invalid="ignore"):
                z = mu * G if y is None else y + mu * G
            lam = np.maximum(0.0, np.nan_to_num(z, nan=0.0, neginf=0.0, posinf=np.inf))
            out.append((G, lam))
        return out

    def value(self, X: np.ndarray, U: np.ndarray) -> float:
        """``sum psi(g, y)``: 0 where nothing is active (the merit is then the cost, exactly)."""
        s = 0.0
        for k, (_, lam) in enumerate(self._lams(X, U)):
            y, mu = self.y[k], self._mu(self.constraints[k])
            if lam.any():
                s += float(np.sum(lam * lam)) / (2.0 * mu)
            if y is not None and y.any():
                s -= float(np.sum(y * y)) / (2.0 * mu)
        return s

    def model(self, X: np.ndarray, U: np.ndarray) -> tuple | None:
        """The merit's extra gradient and Gauss-Newton Hessian at ``X (T+1, n)``, ``U (T, m)``: ``(l_x (T+1, n),
        l_xx (T+1, n, n), l_u (T, m), l_uu (T, m, m))``, or ``None`` where no row is active (nothing to add)."""
        lams = self._lams(X, U)
        if not any(lam.any() for _, lam in lams):
            return None
        (K, n), (T, m) = X.shape, U.shape
        lx, lxx, lu, luu = np.zeros((K, n)), np.zeros((K, n, n)), np.zeros((T, m)), np.zeros((T, m, m))
        for c, (_, lam) in zip(self.constraints, lams):
            if lam.any():
                c.add_derivatives(X, U, lam, self._mu(c), lx, lxx, lu, luu)
        return lx, lxx, lu, luu

    def violation(self, X: np.ndarray, U: np.ndarray) -> float:
        """The largest violation in units of each row's tolerance (<= 1: feasible)."""
        v = 0.0
        for c in self.constraints:
            G = c.values(X, U)
            if G.size:
                with np.errstate(invalid="ignore"):
                    v = max(v, float(np.nanmax(np.where(np.isneginf(G), 0.0, G) / c.tol, initial=0.0)))
        return v

    def update(self, X: np.ndarray, U: np.ndarray) -> None:
        """The first-order multiplier step ``y = max(0, y + mu g)`` at the accepted iterate ``X, U``; ``mu *=
        MU_GROWTH`` when the scaled violation, beyond tolerance, has not fallen by ``DECREASE`` in ``PATIENCE``
        updates (in the endgame: in one)."""
        viol = self.violation(X, U)
        for k, (_, lam) in enumerate(self._lams(X, U)):
            self.y[k] = lam if (lam.any() or self.y[k] is not None) else None
        self.updates += 1
        self._share_slack()
        if viol <= 1.0 or viol <= DECREASE * self.ref_violation:
            self.ref_violation, self.stalled = viol, 0
        else:
            self.stalled += 1
            if self.stalled >= (1 if self.endgame else PATIENCE):
                self.force_growth()
                self.ref_violation = viol
        self.last_violation = viol

    def force_growth(self) -> None:
        """``mu *= MU_GROWTH`` (up to its cap)."""
        self.mu = min(self.mu * MU_GROWTH, self.mu0 * MU_MAX_FACTOR)
        self.stalled = 0
        self._share_slack()

    def _share_slack(self) -> None:
        """Tell the constraints that cull their rows (``set_slack``) each row's ``y / mu``: beyond it ``lam = 0``."""
        for k, c in enumerate(self.constraints):
            if hasattr(c, "set_slack"):
                y = self.y[k]
                c.set_slack(None if y is None else y / self._mu(c))


def reachable_box(lo: np.ndarray, hi: np.ndarray, q0: np.ndarray, vmax: np.ndarray, dt: float, T: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Per-step ranges ``(T+1, k)`` for a start ``q0 (k,)`` possibly outside ``[lo, hi]``: at step ``t`` a joint
    below its range must be at least ``min(lo, q0 + t dt vmax)`` (above: at most ``max(hi, q0 - t dt vmax)``),
    the farthest its velocity limit ``vmax (k,)`` (rad/s; ``inf``: none, then inside from step 1) lets it come
    back, one step after the start to reach that speed (``(t - 1) dt vmax``); the first step where that reaches
    the range is the first its dynamics allow (the effort limits' own bound on the acceleration left out)."""
    t = np.maximum(np.arange(T + 1) - 1, 0)[:, None] * dt
    with np.errstate(invalid="ignore"):
        reach = np.where(np.isfinite(vmax), t * vmax, np.where(np.arange(T + 1)[:, None] > 0, np.inf, 0.0))
    lo_t = np.where(q0 < lo, np.minimum(lo, q0 + reach), lo)
    hi_t = np.where(q0 > hi, np.maximum(hi, q0 - reach), hi)
    return np.broadcast_to(lo_t, (T + 1, len(lo))).copy(), np.broadcast_to(hi_t, (T + 1, len(hi))).copy()
