"""Named, weighted cost terms with vectorized values and Gauss-Newton models.

Every term has a ``name`` and a ``weight`` (weight 0 switches it off; ``Problem.without``
removes it). Conventions (see ``raico.planning.problem``):

- state terms act on rows ``X (K, n_x)`` at time steps ``idx (K,)`` (default ``0..K-1``)
  and only at their ``times`` (``None``: every step); ``value`` gives ``(K,)`` per-time
  costs, ``derivatives`` the gradient ``l_x (K, n_x)`` and Gauss-Newton Hessian
  ``l_xx (K, n_x, n_x)``, ``quadratize`` the task message ``R = l_xx``,
  ``r = l_xx x - l_x`` (cost ``1/2 x^T R x - r^T x``);
- control terms act on ``U (K, n_u)`` at every step: ``value (K,)``,
  ``derivatives -> l_u (K, n_u), l_uu (K, n_u, n_u)``, ``quadratize -> H = l_uu,
  h = l_uu u - l_u``. State-control cross terms are zero.

For a via-point ``w (x* - phi(q))^T C (x* - phi(q))`` linearized at ``q0`` this gives
``R = 2 w J^T C J`` and ``r = 2 w J^T C (x* - phi(q0) + J q0)`` on the ``q`` block (the
velocity block is zero).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from raico.plants.taskmaps import TASKMAP_EXAMPLES, FramePoints, TaskMap, TaskMapExample


def _diag_or_matrix(precision, dim: int, what: str) -> np.ndarray:
    """A symmetric ``(dim, dim)`` precision from ``None`` (identity), a diagonal or a matrix."""
    if precision is None:
        return np.eye(dim)
    P = np.asarray(precision, dtype=float)
    if P.ndim == 1:
        if P.shape != (dim,):
            raise ValueError(f"{what}: precision has shape {P.shape}, expected ({dim},)")
        P = np.diag(P)
    if P.shape != (dim, dim):
        raise ValueError(f"{what}: precision has shape {P.shape}, expected ({dim}, {dim})")
    if not np.all(np.isfinite(P)):
        raise ValueError(f"{what}: precision must be finite")
    return 0.5 * (P + P.T)


def _check_weight(weight: float, what: str) -> float:
    w = float(weight)
    if not np.isfinite(w) or w < 0:
        raise ValueError(f"{what}: weight must be finite and >= 0, got {weight}")
    return w


class StateTerm:
    """Base class of state terms: subclasses implement ``_value`` and ``_derivs`` on active rows."""

    name: str
    weight: float
    times: np.ndarray | None

    def _set_times(self, times) -> None:
        if times is None:
            self.times = None
        else:
            t = np.unique(np.asarray(list(times), dtype=int).reshape(-1))
            self.times = t
        self._active_last: tuple | None = None

    def active(self, idx: np.ndarray) -> np.ndarray:
        """Boolean mask ``(K,)``: which time steps ``idx`` this term costs (read-only: the mask of
        the last ``idx`` is remembered, as solvers ask for the same steps every iteration)."""
        if self.times is None:
            return np.ones(len(idx), dtype=bool)
        last = getattr(self, "_active_last", None)
        if last is not None and last[0].shape == np.shape(idx) and np.array_equal(last[0], idx):
            return last[1]
        m = np.isin(idx, self.times)
        m.flags.writeable = False
        self._active_last = (np.array(idx, copy=True), m)
        return m

    def is_active_at(self, t: int) -> bool:
        """Whether this term costs step ``t`` (``times`` is sorted and unique)."""
        if self.times is None:
            return True
        i = int(np.searchsorted(self.times, t))
        return i < len(self.times) and self.times[i] == t

    @staticmethod
    def _idx(X: np.ndarray, idx) -> np.ndarray:
        return np.arange(X.shape[0]) if idx is None else np.asarray(idx).reshape(-1)

    def value(self, X: np.ndarray, idx=None) -> np.ndarray:
        """Per-time costs ``(K,)`` of rows ``X (K, n_x)`` at time steps ``idx``."""
        X = np.atleast_2d(X)
        idx = self._idx(X, idx)
        out = np.zeros(X.shape[0])
        m = self.active(idx)
        if self.weight != 0 and m.any():
            out[m] = self._value(X[m], idx[m])
        return out

    def derivatives(self, X: np.ndarray, idx=None) -> tuple[np.ndarray, np.ndarray]:
        """Gradient ``(K, n_x)`` and Gauss-Newton Hessian ``(K, n_x, n_x)``."""
        X = np.atleast_2d(X)
        lx = np.zeros(X.shape)
        lxx = np.zeros((X.shape[0], X.shape[1], X.shape[1]))
        self.add_derivatives(X, self._idx(X, idx), lx, lxx)
        return lx, lxx

    def add_derivatives(self, X: np.ndarray, idx: np.ndarray, lx: np.ndarray,
                        lxx: np.ndarray) -> None:
        """Add this term's gradient and GN Hessian into ``lx (K, n_x)``, ``lxx (K, n_x, n_x)``."""
        m = self.active(idx)
        if self.weight == 0 or not m.any():
            return
        g, H = self._derivs(X[m], idx[m])
        if m.all():
            lx += g
            lxx += H
        else:
            lx[m] += g
            lxx[m] += H

    def quadratize(self, X: np.ndarray, idx=None) -> tuple[np.ndarray, np.ndarray]:
        """Task message ``R (K, n_x, n_x)``, ``r (K, n_x)`` of ``1/2 x^T R x - r^T x`` at ``X``."""
        X = np.atleast_2d(X)
        lx, lxx = self.derivatives(X, idx)
        return lxx, np.einsum("kij,kj->ki", lxx, X) - lx

    def add_point_derivatives(self, x: np.ndarray, t: int, lx: np.ndarray,
                              lxx: np.ndarray) -> None:
        """Add the gradient and GN Hessian at one state ``x (n_x,)`` of step ``t`` into
        ``lx (n_x,)``, ``lxx (n_x, n_x)`` (the same as ``add_derivatives`` on one row; terms
        override it to skip the batch bookkeeping). The step is looked up in ``times`` directly: the
        batch's remembered mask (:meth:`active`) is left to the batches."""
        if self.weight == 0 or not self.is_active_at(t):
            return
        g, H = self._derivs(x[None, :], np.array([t]))
        lx += g[0]
        lxx += H[0]

    def _value(self, X: np.ndarray, idx: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _derivs(self, X: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError


class _OnPositions(StateTerm):
    """A state term of the joint positions only: its derivatives are the ``q`` blocks that
    ``_q_blocks(X) -> (g (K, n_q), H (K, n_q, n_q), n_q)`` gives, zero elsewhere."""

    taskmap: Any                # the task map the term reads (``raico.plants.taskmaps.TaskMap``)
    _last: tuple | None = None  # (taskmap, Q, phi, J) of the last batch evaluated

    def _map(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``phi (K, dim)`` and ``J (K, dim, n_q)`` at ``Q (K, n_q)``.

        The last batch is remembered: a solver evaluates the cost of a rollout and then
        linearizes at the same trajectory, so the (expensive, e.g. Drake) task map runs once
        for both. Hits need bitwise-equal ``Q`` and the same task map; the arrays returned
        are shared with the memo and must not be modified.
        """
        last = self._last
        if (last is not None and last[0] is self.taskmap and last[1].shape == Q.shape
                and np.array_equal(last[1], Q)):
            return last[2], last[3]
        phi, J = self.taskmap.values_and_jacobians(Q)
        self._last = (self.taskmap, np.array(Q, dtype=float), phi, J)
        return phi, J

    def _at_point(self, x: np.ndarray, t: int):
        """``(n_q, phi, J)`` of the task map at the state ``x`` of step ``t``, or ``None`` where the
        term adds nothing there (zero weight, inactive step)."""
        if self.weight == 0 or not self.is_active_at(t):
            return None
        n_q = x.shape[0] // 2
        return (n_q, *self.taskmap.value_and_jacobian(x[:n_q]))

    def _derivs(self, X, idx):
        g, H, n_q = self._q_blocks(X)
        lx = np.zeros(X.shape)
        lxx = np.zeros((X.shape[0], X.shape[1], X.shape[1]))
        lx[:, :n_q] = g
        lxx[:, :n_q, :n_q] = H
        return lx, lxx


class ViaPoint(_OnPositions):
    """Task-space via-point ``w (x* - phi(q_t))^T C (x* - phi(q_t))`` at the listed steps.

    Args:
        taskmap: ``phi`` (``raico.plants.taskmaps.TaskMap``) on ``q = x[:n_q]``, ``n_q = n_x / 2``.
        target: ``x* (dim,)`` in the task map's units (m or rad).
        times: step indices in ``[0, T]``; ``None`` means every step.
        weight: ``w`` (thesis eq. 3.7: 1e4).
        precision: diagonal of ``C (dim,)`` (default ones) or a full ``(dim, dim)`` matrix.
        name: unique name of the term.
        tol: the term's own tolerance of "task achieved" in its unit (:func:`task_errors`; a frame
            placement ``[m, rad]``); None: its kind's default.
    """

    def __init__(self, taskmap: TaskMap, target, times, weight: float = 1e4,
                 precision=None, name: str | None = None, tol=None):
        self.taskmap = taskmap
        self.tol = tol
        self.target = np.asarray(target, dtype=float).reshape(-1)
        if self.target.shape != (taskmap.dim,):
            raise ValueError(f"ViaPoint target has shape {self.target.shape}, "
                             f"task map {taskmap.name!r} has dim {taskmap.dim}")
        self.name = name or f"via_{taskmap.name}"
        self.weight = _check_weight(weight, self.name)
        self.C = _diag_or_matrix(precision, taskmap.dim, self.name)
        self._set_times(times)
        self._last = None  # (taskmap, Q, phi, J) of the last batch evaluated

    def _errors(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        n_q = X.shape[1] // 2
        phi, J = self._map(X[:, :n_q])
        return self.target - phi, J, n_q

    def _value(self, X, idx):
        e, _, _ = self._errors(X)
        return self.weight * np.einsum("ki,ij,kj->k", e, self.C, e)

    def _q_blocks(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """Gradient ``(K, n_q)`` and GN Hessian ``(K, n_q, n_q)`` on the ``q`` block."""
        e, J, n_q = self._errors(X)
        CJ = np.matmul(self.C, J)                                    # (K, dim, n_q)
        g = (-2.0 * self.weight) * np.matmul(e[:, None, :], CJ)[:, 0]  # -2w J^T C e
        H = (2.0 * self.weight) * np.matmul(np.swapaxes(J, 1, 2), CJ)  # 2w J^T C J
        return g, H, n_q

    def add_point_derivatives(self, x, t, lx, lxx) -> None:
        """As ``StateTerm.add_point_derivatives``: one task-map evaluation, ``q`` blocks only."""
        point = self._at_point(x, t)
        if point is None:
            return
        n_q, phi, J = point
        CJ = self.C @ J
        lx[:n_q] -= (2.0 * self.weight) * ((self.target - phi) @ CJ)
        lxx[:n_q, :n_q] += (2.0 * self.weight) * (J.T @ CJ)


    def add_derivatives(self, X, idx, lx, lxx) -> None:
        """As ``StateTerm.add_derivatives``, touching only the ``q`` blocks."""
        m = self.active(idx)
        if self.weight == 0 or not m.any():
            return
        if m.all():
            g, H, n_q = self._q_blocks(X)
            lx[:, :n_q] += g
            lxx[:, :n_q, :n_q] += H
        else:
            steps = np.flatnonzero(m)
            rows: np.ndarray | slice = steps
            if steps[-1] - steps[0] + 1 == steps.size:   # one run of steps: views, no gathers
                rows = slice(int(steps[0]), int(steps[-1]) + 1)
            g, H, n_q = self._q_blocks(X[rows])
            lx[rows, :n_q] += g
            lxx[rows, :n_q, :n_q] += H


class TaskInequality(_OnPositions):
    """One-sided task-space bounds, a squared-hinge penalty at the listed steps:
    ``w sum_i max(0, a_i . phi(q_t) - b_i)^2`` (zero where ``A phi(q_t) <= b``).

    ``a_i`` unit vectors make ``b_i - a_i . phi`` the signed distance (m) of ``phi`` to the
    bound's line/plane (> 0 on the allowed side): a support polygon with a margin on the CoG's
    ground projection (``raico.stages.plan.balance``), or a height bound on sole points (``A = -I``).
    Gradient ``l_q = 2 w J^T A^T h`` (``h = max(0, A phi - b)``, exact); Gauss-Newton Hessian
    ``l_qq = 2 w J^T A_act^T A_act J`` over the violated rows (exact up to the task map's
    curvature, as for a via-point); both zero on the velocity block.

    Args:
        taskmap: ``phi`` on ``q = x[:n_q]``.
        A: ``(m, dim)`` bound directions (rows, in the task map's units).
        b: ``(m,)`` offsets (m or rad).
        times: step indices in ``[0, T]``; ``None`` means every step.
        weight: ``w`` per (task unit)^2 of violation.
        name: unique name of the term.
    """

    def __init__(self, taskmap: TaskMap, A, b, times, weight: float = 1e6, name: str | None = None):
        self.taskmap = taskmap
        self.A = np.atleast_2d(np.asarray(A, dtype=float))
        self.b = np.asarray(b, dtype=float).reshape(-1)
        self.name = name or f"bound_{taskmap.name}"
        if self.A.shape != (self.b.shape[0], taskmap.dim):
            raise ValueError(f"{self.name}: A has shape {self.A.shape}, expected ({self.b.shape[0]}, "
                             f"{taskmap.dim}) for {self.b.shape[0]} bounds on task map {taskmap.name!r}")
        if not (np.all(np.isfinite(self.A)) and np.all(np.isfinite(self.b))):
            raise ValueError(f"{self.name}: A and b must be finite")
        self.weight = _check_weight(weight, self.name)
        self._set_times(times)
        self._last = None

    def _hinge(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """``h (K, m)``, ``A J (K, m, n_q)`` and ``n_q`` at rows ``X (K, n_x)``."""
        n_q = X.shape[1] // 2
        phi, J = self._map(X[:, :n_q])
        h = np.maximum(phi @ self.A.T - self.b, 0.0)
        return h, np.matmul(self.A, J), n_q

    def _value(self, X, idx):
        h, _, _ = self._hinge(X)
        return self.weight * np.einsum("km,km->k", h, h)

    def _q_blocks(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """Gradient ``(K, n_q)`` and GN Hessian ``(K, n_q, n_q)`` on the ``q`` block."""
        h, AJ, n_q = self._hinge(X)
        g = (2.0 * self.weight) * np.einsum("km,kmi->ki", h, AJ)
        AJa = AJ * (h > 0)[:, :, None]
        H = (2.0 * self.weight) * np.matmul(np.swapaxes(AJa, 1, 2), AJa)
        return g, H, n_q

    def add_point_derivatives(self, x, t, lx, lxx) -> None:
        """As ``StateTerm.add_point_derivatives``: one task-map evaluation, ``q`` blocks only."""
        point = self._at_point(x, t)
        if point is None:
            return
        n_q, phi, J = point
        h = np.maximum(self.A @ phi - self.b, 0.0)
        if not h.any():
            return
        AJ = self.A[h > 0] @ J
        lx[:n_q] += (2.0 * self.weight) * (h[h > 0] @ AJ)
        lxx[:n_q, :n_q] += (2.0 * self.weight) * (AJ.T @ AJ)


class Collision(TaskInequality):
    """Collision avoidance: signed distances ``d(q_t) (m,)`` (m) of geometry pairs kept at least ``margin``
    away, crocoddyl's pair-collision style: ``w sum_pairs max(0, margin - d)^2`` at the listed steps (a
    squared hinge on the distance below the margin; :class:`TaskInequality` with ``A = -I``,
    ``b = -margin``).

    ``hard``: the problem asks for ``d >= margin`` as a constraint. AICO and R-AICO keep it in their
    augmented Lagrangian (``raico.planning.constraints.DistanceConstraint``; the term leaves their cost);
    :meth:`constraints` gives ``g(x_t) <= 0`` per step with its Jacobian to any other constrained solver; the
    others minimize the stiff penalty this term is (its weight: the problem's, by default
    :data:`HARD_COLLISION_WEIGHT`). The hinge's distances are queried only where a pair may come within the
    margin (``SignedDistances.evaluate``'s ``cull``): beyond it the hinge is zero.

    Args:
        taskmap: the distances (``raico.plants.scene.SignedDistances``, ``dim`` pairs, capped at its
            ``max_distance``).
        margin: the smallest distance allowed (m, >= 0).
        times: step indices in ``[0, T]``; ``None``: every step.
        weight: ``w`` per m^2 of the distance below the margin.
        hard: whether the problem states the margin as a hard constraint.
        name: unique name of the term.
    """

    def __init__(self, taskmap: TaskMap, margin: float, times, weight: float = 1e6, hard: bool = True,
                 name: str | None = None):
        m = taskmap.dim
        super().__init__(taskmap, -np.eye(m), -float(margin) * np.ones(m), times, weight,
                         name=name or f"collision_{taskmap.name}")
        if not 0 <= float(margin) < math.inf:
            raise ValueError(f"{self.name}: margin must be >= 0 (m), got {margin}")
        self.margin, self.hard = float(margin), bool(hard)

    def _map(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """As :meth:`_OnPositions._map`, the pairs culled at the margin (beyond it the hinge is zero: the
        value and the derivatives are those of the uncapped query)."""
        last = self._last
        if (last is not None and last[0] is self.taskmap and last[1].shape == Q.shape
                and np.array_equal(last[1], Q)):
            return last[2], last[3]
        cull = self.margin if hasattr(self.taskmap, "evaluate") else None
        phi, J = (self.taskmap.evaluate(Q, cull=cull)[:2] if cull is not None
                  else self.taskmap.values_and_jacobians(Q))
        self._last = (self.taskmap, np.array(Q, dtype=float), phi, J)
        return phi, J

    def constraints(self, X: np.ndarray, idx=None) -> tuple[np.ndarray, np.ndarray]:
        """The inequality ``g(x_t) = margin - d(q_t) <= 0`` at rows ``X (K, n_x)`` of steps ``idx``: ``g (K, m)``
        (m) and its Jacobian ``G (K, m, n_x)`` (``-J`` on the positions, zero on the velocities); rows of
        steps the term does not cover are ``-inf`` with a zero Jacobian (never active)."""
        X = np.atleast_2d(X)
        idx = self._idx(X, idx)
        K, n_x = X.shape
        n_q = n_x // 2
        g = np.full((K, self.taskmap.dim), -np.inf)
        G = np.zeros((K, self.taskmap.dim, n_x))
        m = self.active(idx)
        if m.any():
            d, J = self.taskmap.values_and_jacobians(X[m][:, :n_q])
            g[m] = self.margin - d
            G[np.flatnonzero(m), :, :n_q] = -J
        return g, G

    def smallest(self, X: np.ndarray) -> tuple[float, int, int]:
        """The smallest distance (m, capped at the map's ``max_distance``) over rows ``X (K, n_x)`` of steps
        ``0..K-1`` this term covers, its step and its pair's index."""
        X = np.atleast_2d(X)
        idx = np.flatnonzero(self.active(np.arange(len(X))))
        if idx.size == 0 or self.taskmap.dim == 0:
            return math.inf, -1, -1
        n_q = X.shape[1] // 2
        d = self.taskmap.evaluate(X[idx, :n_q], jacobians=False)[0]
        d = np.where(np.isfinite(d), d, np.inf)
        k, p = np.unravel_index(int(np.argmin(d)), d.shape)
        return float(d[k, p]), int(idx[k]), int(p)


HARD_COLLISION_WEIGHT = 1e6   # the stiff penalty of a hard collision term without a weight (per m^2)


@runtime_checkable
class StepInequality(Protocol):
    """What a constrained solver reads of a state term the problem states as hard: per time step
    ``g(x_t) <= 0`` (``m`` rows) and its Jacobian. :class:`Collision` is one (``margin - d(q_t)``, m)."""

    name: str
    hard: bool

    def constraints(self, X: np.ndarray, idx=None) -> tuple[np.ndarray, np.ndarray]:
        """``g (K, m)`` and ``G (K, m, n_x)`` at rows ``X (K, n_x)`` of steps ``idx``; ``-inf`` rows (zero
        Jacobian) at steps the term does not cover."""
        ...


def hard_inequalities(state_terms) -> list:
    """The state terms a problem states as hard inequalities (:class:`StepInequality` with ``hard``): a
    constrained solver keeps ``g <= 0`` for them (and drops their penalty); the others minimize the penalty."""
    return [t for t in state_terms if isinstance(t, StepInequality) and t.hard]


class StateTarget(StateTerm):
    """Quadratic cost on the full state ``w (x_t - x*)^T C (x_t - x*)`` at the listed steps.

    Args:
        target: ``x* (n_x,)`` (rad, rad/s), or one per step, ``(T+1, n_x)`` (a reference trajectory: row ``t``
            is step ``t``'s target; an MPC window's copy follows the absolute steps, raico.planning.mpc).
        times: step indices in ``[0, T]``; ``None`` means every step.
        weight: ``w``.
        precision: diagonal ``(n_x,)`` (default ones) or full ``(n_x, n_x)`` PSD matrix ``C``.
        name: unique name of the term.
    """

    def __init__(self, target, times=None, weight: float = 1.0, precision=None,
                 name: str = "state_target"):
        t = np.asarray(target, dtype=float)
        self.target = np.ascontiguousarray(t) if t.ndim == 2 else t.reshape(-1)
        self.name = name
        self.weight = _check_weight(weight, name)
        self.C = _diag_or_matrix(precision, self.target.shape[-1], name)
        self._set_times(times)

    @property
    def per_step(self) -> bool:
        """Whether the target is one per step (``(T+1, n_x)``)."""
        return self.target.ndim == 2

    def _target(self, idx):
        return self.target[idx] if self.target.ndim == 2 else self.target

    def _value(self, X, idx):
        e = X - self._target(idx)
        return self.weight * np.einsum("ki,ij,kj->k", e, self.C, e)

    def _derivs(self, X, idx):
        e = X - self._target(idx)
        lx = 2.0 * self.weight * e @ self.C
        lxx = np.broadcast_to(2.0 * self.weight * self.C, (X.shape[0], *self.C.shape))
        return lx, lxx


class ControlTerm:
    """Base class of control terms (time-invariant, every step ``t = 0..T-1``)."""

    name: str
    weight: float

    def value(self, U: np.ndarray) -> np.ndarray:
        """Per-time costs ``(K,)`` of ``U (K, n_u)``."""
        raise NotImplementedError

    def derivatives(self, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gradient ``l_u (K, n_u)`` and Gauss-Newton Hessian ``l_uu (K, n_u, n_u)``."""
        raise NotImplementedError

    def quadratize(self, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Control message ``H (K, n_u, n_u)``, ``h (K, n_u)`` of ``1/2 u^T H u - h^T u``."""
        U = np.atleast_2d(U)
        lu, luu = self.derivatives(U)
        return luu, np.einsum("kij,kj->ki", luu, U) - lu


class ControlCost(ControlTerm):
    """Control effort ``w_u (u_t - u*)^T C (u_t - u*)`` (``u* = 0``, ``C = I`` by default):
    ``H = 2 w_u C``.

    Args:
        weight: ``w_u`` (thesis eq. 3.7: 1e-2), per (control unit)^2.
        target: optional ``u* (n_u,)`` (then ``h = 2 w_u C u*``).
        precision: optional diagonal of ``C (n_u,)``: per-joint weights (relative to ``w_u``).
        name: unique name of the term.
    """

    def __init__(self, weight: float = 1e-2, target=None, name: str = "control", precision=None):
        self.name = name
        self.weight = _check_weight(weight, name)
        self.target = None if target is None else np.asarray(target, dtype=float).reshape(-1)
        self.c = None if precision is None else np.asarray(precision, dtype=float).reshape(-1)
        if self.c is not None and (np.any(self.c < 0) or not np.all(np.isfinite(self.c))):
            raise ValueError(f"{name}: precision must be finite values >= 0")

    def _err(self, U: np.ndarray) -> np.ndarray:
        U = np.atleast_2d(U)
        return U if self.target is None else U - self.target

    def value(self, U):
        e = self._err(U)
        if self.c is not None:
            return self.weight * np.einsum("ki,i,ki->k", e, self.c, e)
        return self.weight * np.einsum("ki,ki->k", e, e)

    def derivatives(self, U):
        e = self._err(U)
        n_u = e.shape[1]
        C = np.eye(n_u) if self.c is None else np.diag(self.c)
        luu = np.broadcast_to(2.0 * self.weight * C, (e.shape[0], n_u, n_u)).copy()
        return 2.0 * self.weight * (e if self.c is None else e * self.c), luu


class ControlLimit(ControlTerm):
    """Soft control limits (thesis §4.1): ``w sum_i max(0, u_i - upper_i)^2 + max(0, lower_i - u_i)^2``.

    Its Gauss-Newton model is exact on each side: ``l_uu = 2 w diag(active)``.

    Args:
        lower: lower limits ``(n_u,)`` or a scalar (control units, e.g. N m).
        upper: upper limits, as ``lower``.
        weight: ``w`` per (control unit)^2 of violation.
        name: unique name of the term.
    """

    def __init__(self, lower, upper, weight: float = 1e4, name: str = "control_limit"):
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        if np.any(self.lower > self.upper):
            raise ValueError(f"{name}: lower limit above upper limit")
        self.name = name
        self.weight = _check_weight(weight, name)

    def _viol(self, U: np.ndarray) -> np.ndarray:
        """Signed violation ``(K, n_u)``: ``u - upper`` above, ``u - lower`` below, else 0."""
        U = np.atleast_2d(U)
        return np.maximum(U - self.upper, 0.0) + np.minimum(U - self.lower, 0.0)

    def value(self, U):
        v = self._viol(U)
        return self.weight * np.einsum("ki,ki->k", v, v)

    def derivatives(self, U):
        v = self._viol(U)
        act = (v != 0).astype(float)
        K, n_u = v.shape
        luu = np.zeros((K, n_u, n_u))
        luu[:, np.arange(n_u), np.arange(n_u)] = 2.0 * self.weight * act
        return 2.0 * self.weight * v, luu


SIGMA_UNITS = ("raw", "standardized")  # the uncertainty term's g: (rad/s^2)^2, or over the data's variance


class JointTerm:
    """What a term on ``(x_t, u_t)`` together (``t = 0..T-1``) shares: the nominal trajectory it is split at
    (``set_nominal``), its state-part view at the nominal controls (``value``, ``derivatives``) and its
    control-part view at the nominal states (``control_value``, ``control_derivatives``). A subclass gives
    ``T``, ``joint_value``, ``add_derivatives`` and ``add_control_derivatives``."""

    T: int
    _X: np.ndarray | None = None
    _U: np.ndarray | None = None

    def joint_value(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def add_derivatives(self, X: np.ndarray, idx: np.ndarray, lx: np.ndarray, lxx: np.ndarray) -> None:
        raise NotImplementedError

    def add_control_derivatives(self, U: np.ndarray, lu: np.ndarray, luu: np.ndarray) -> None:
        raise NotImplementedError

    def set_nominal(self, X: np.ndarray, U: np.ndarray) -> None:
        """The nominal trajectory ``X (T+1, n_x)``, ``U (T, n_u)`` the split models use."""
        self._X, self._U = np.array(X[:self.T], float), np.array(U, float)

    def active(self, idx: np.ndarray) -> np.ndarray:
        return np.asarray(idx) < self.T

    def is_active_at(self, t: int) -> bool:
        return 0 <= t < self.T

    def value(self, X: np.ndarray, idx=None) -> np.ndarray:
        """State-part view: costs at rows ``X`` with the nominal controls of steps ``idx``."""
        X = np.atleast_2d(X)
        idx = np.arange(len(X)) if idx is None else np.asarray(idx).reshape(-1)
        out = np.zeros(len(X))
        m = self.active(idx)
        if self._U is not None and m.any():
            out[m] = self.joint_value(X[m], self._U[idx[m]])
        return out

    def derivatives(self, X: np.ndarray, idx=None) -> tuple[np.ndarray, np.ndarray]:
        X = np.atleast_2d(X)
        lx, lxx = np.zeros(X.shape), np.zeros((len(X), X.shape[1], X.shape[1]))
        self.add_derivatives(X, np.arange(len(X)) if idx is None else np.asarray(idx), lx, lxx)
        return lx, lxx

    def control_derivatives(self, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``l_u (T, n_u)``, ``l_uu (T, n_u, n_u)`` at ``U`` with the nominal states."""
        U = np.atleast_2d(U)
        lu, luu = np.zeros(U.shape), np.zeros((len(U), U.shape[1], U.shape[1]))
        self.add_control_derivatives(U, lu, luu)
        return lu, luu

    def control_value(self, U: np.ndarray) -> np.ndarray:
        """Control-part view: costs at ``U (T, n_u)`` with the nominal states."""
        return self.joint_value(self._X, np.atleast_2d(U))


class Uncertainty(JointTerm):
    """The model-uncertainty objective (thesis eq. 4.3), a joint term on ``(x_t, u_t)``:

    ``c_t = (sigma* - g(x_t, u_t))^T C_sigma (sigma* - g(x_t, u_t))``, ``C_sigma = w I``,
    at every step ``t = 0..T-1``, with ``g`` the GP's latent predictive variance of each
    output (joint acceleration): ``units="raw"`` in (rad/s^2)^2 as the thesis's ``var(x*)``
    (eq. 4.3), or ``units="standardized"``: the variance divided by the training outputs'
    variance, so ``g`` is near 0 where the model is sure and near the prior variance (about 1)
    far from the data, and ``sigma*`` means the same on every plant. Gauss-Newton models with ``J_x = dg/dx``, ``J_u = dg/du`` at the nominal
    trajectory: the state part ``l_x = -2 w J_x^T e``, ``l_xx = 2 w J_x^T J_x`` (into ``R, r``)
    at the nominal controls, the control part likewise (into ``H, h``) at the nominal states;
    the cross terms ``d^2 c / dx du`` are dropped. ``model``: a dynamics model with
    ``predict_variance(X, U) -> var (K, D), dvar/dx (K, D, n_x), dvar/du (K, D, n_u)`` and
    ``model.model.y_std`` (``raico.plants.learned.LearnedDynamics``).
    """

    def __init__(self, model, sigma_star: float, weight: float, T: int, name: str = "uncertainty",
                 units: str = "standardized"):
        if units not in SIGMA_UNITS:
            raise ValueError(f"uncertainty units must be one of {', '.join(SIGMA_UNITS)}, got '{units}'")
        self.model = model
        self.units = units
        self.sigma_star = float(sigma_star)
        self.name = name
        self.weight = _check_weight(weight, name)
        self.T = int(T)
        self.times = np.arange(self.T)
        y_std = np.asarray(model.model.y_std, float)
        self._scale = 1.0 / y_std ** 2 if units == "standardized" else np.ones_like(y_std)  # (D,)
        self._X: np.ndarray | None = None   # the nominal trajectory (set_nominal)
        self._U: np.ndarray | None = None
        self._memo: tuple | None = None

    # -- the model ----------------------------------------------------------------------------
    def variance(self, X: np.ndarray, U: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``g (K, D)`` (in the term's units) and its Jacobians ``(K, D, n_x)``, ``(K, D, n_u)``."""
        key = (X.shape, U.shape, X.tobytes(), U.tobytes())
        if self._memo is None or self._memo[0] != key:
            var, dx, du = self.model.predict_variance(X, U)
            s = self._scale
            self._memo = (key, (var * s, dx * s[:, None], du * s[:, None]))
        return self._memo[1]

    def joint_value(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """Per-step costs ``(K,)`` at ``X (K, n_x)``, ``U (K, n_u)``."""
        if self.weight == 0:
            return np.zeros(len(X))
        g, _, _ = self.variance(np.atleast_2d(X), np.atleast_2d(U))
        e = self.sigma_star - g
        return self.weight * np.einsum("kd,kd->k", e, e)

    def _gn(self, e: np.ndarray, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        w = self.weight
        return -2.0 * w * np.einsum("kdi,kd->ki", J, e), 2.0 * w * np.einsum("kdi,kdj->kij", J, J)

    # -- the state part (as a state term) -----------------------------------------------------
    def add_derivatives(self, X: np.ndarray, idx: np.ndarray, lx: np.ndarray, lxx: np.ndarray) -> None:
        """Add the state part at rows ``X (K, n_x)`` of steps ``idx`` (nominal controls)."""
        m = self.active(np.asarray(idx))
        if self.weight == 0 or self._U is None or not m.any():
            return
        g, Jx, _ = self.variance(X[m], self._U[np.asarray(idx)[m]])
        gx, Hx = self._gn(self.sigma_star - g, Jx)
        lx[m] += gx
        lxx[m] += Hx

    def add_point_derivatives(self, x: np.ndarray, t: int, lx: np.ndarray, lxx: np.ndarray) -> None:
        """The state part at one state ``x (n_x,)`` of step ``t`` (the sweeps' relinearization): the
        model's compiled one-point variance where it has one (``point_variance``), else the batch path."""
        point = getattr(self.model, "point_variance", None)
        if point is not None and t < self.T:
            if self.weight == 0 or self._U is None:
                return
            var, Jx, _ = point(x, self._U[t])
            s = self._scale
            gx, Hx = self._gn((self.sigma_star - var * s)[None], (Jx * s[:, None])[None])
            lx += gx[0]
            lxx += Hx[0]
        elif t < self.T:
            g, G = np.zeros((1, x.size)), np.zeros((1, x.size, x.size))
            self.add_derivatives(x[None], np.array([t]), g, G)
            lx += g[0]
            lxx += G[0]

    # -- the control part --------------------------------------------------------------------
    def add_control_derivatives(self, U: np.ndarray, lu: np.ndarray, luu: np.ndarray) -> None:
        if self.weight == 0 or self._X is None or len(U) != len(self._X):
            return   # no nominal trajectory of this length (e.g. a probe at one control)
        g, _, Ju = self.variance(self._X, U)
        gu, Hu = self._gn(self.sigma_star - g, Ju)
        lu += gu
        luu += Hu


class ControlGravity(JointTerm):
    """Control effort toward the gravity-compensating torque, a joint term on ``(x_t, u_t)``:
    ``c_t = w (u_t - g(q_t))^T C (u_t - g(q_t))`` at every step ``t = 0..T-1`` (crocoddyl's
    ``ResidualModelControlGrav``), ``g`` the torques that hold the robot still
    (:class:`raico.plants.dynamics.GravityTorques`, N m) and ``C`` diagonal (per-joint weights, default ones).

    An arm that holds itself up pays for its own weight under a control cost toward zero; this one
    costs only what the controls add to holding it. Derivatives as the other joint term's
    (:class:`Uncertainty`): the gradient is exact, ``l_x = -2 w G^T C r`` on the ``q`` block
    (``G = dg/dq``, ``r = u - g(q)``) at the nominal controls and ``l_u = 2 w C r`` at the nominal
    states; the Gauss-Newton Hessians ``2 w G^T C G`` and ``2 w C`` (the latter exact); the cross
    term ``l_ux = -2 w C G`` (``add_cross_derivatives``) is kept by R-AICO's robust schedule and dropped by
    the other solvers (``l_ux = 0``).

    Args:
        robot: a robot (``raico.plants.robots.Robot``) with torque controls.
        weight: ``w`` per (N m)^2.
        T: the horizon (steps).
        precision: diagonal of ``C (n_q,)``.
        name: unique name of the term.
    """

    def __init__(self, robot, weight: float, T: int, precision=None, name: str = "control"):
        from raico.plants.fast_analytic import gravity_torques

        self.gravity = gravity_torques(robot)   # on the compiled tree where it builds, else Drake's
        self.name = name
        self.weight = _check_weight(weight, name)
        self.T = int(T)
        self.times = np.arange(self.T)
        n = robot.n_q
        self.c = np.ones(n) if precision is None else np.asarray(precision, float).reshape(-1)
        if self.c.shape != (n,) or np.any(self.c < 0) or not np.all(np.isfinite(self.c)):
            raise ValueError(f"{name}: precision must be {n} finite values >= 0")
        self._X: np.ndarray | None = None   # the nominal trajectory (set_nominal)
        self._U: np.ndarray | None = None
        self._memo: tuple | None = None

    def _g(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``g (K, n)`` and ``dg/dq (K, n, n)`` at the rows' positions (the last batch remembered)."""
        n = self.c.size
        Q = np.ascontiguousarray(np.atleast_2d(X)[:, :n])
        key = (Q.shape, Q.tobytes())
        if self._memo is None or self._memo[0] != key:
            self._memo = (key, self.gravity.values_and_jacobians(Q))
        return self._memo[1]

    def _g_only(self, X: np.ndarray) -> np.ndarray:
        """``g (K, n)`` at the rows' positions, without the Jacobians where none are remembered for them (a
        cost alone: a rollout's, a trial's)."""
        n = self.c.size
        Q = np.ascontiguousarray(np.atleast_2d(X)[:, :n])
        if self._memo is not None and self._memo[0] == (Q.shape, Q.tobytes()):
            return self._memo[1][0]
        return self.gravity.values(Q)

    def joint_value(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """Per-step costs ``(K,)`` at ``X (K, n_x)``, ``U (K, n_u)``."""
        if self.weight == 0:
            return np.zeros(len(X))
        r = np.atleast_2d(U) - self._g_only(X)
        return self.weight * np.einsum("ki,i,ki->k", r, self.c, r)

    # -- the state part (as a state term) -----------------------------------------------------
    def _state_gn(self, X: np.ndarray, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``l_q (K, n)``, GN ``l_qq (K, n, n)`` at rows ``X``, controls ``U``."""
        g, G = self._g(X)
        CG = self.c[None, :, None] * G
        w2 = 2.0 * self.weight
        return -w2 * np.einsum("kij,ki->kj", CG, U - g), w2 * np.einsum("kij,kil->kjl", G, CG)

    def add_derivatives(self, X: np.ndarray, idx: np.ndarray, lx: np.ndarray, lxx: np.ndarray) -> None:
        """Add the state part at rows ``X (K, n_x)`` of steps ``idx`` (nominal controls), ``q`` block."""
        m = self.active(np.asarray(idx))
        if self.weight == 0 or self._U is None or not m.any():
            return
        n = self.c.size
        gq, Hq = self._state_gn(X[m], self._U[np.asarray(idx)[m]])
        lx[m, :n] += gq
        sub = lxx[m]
        sub[:, :n, :n] += Hq
        lxx[m] = sub

    def add_point_derivatives(self, x: np.ndarray, t: int, lx: np.ndarray, lxx: np.ndarray) -> None:
        """The state part at one state ``x (n_x,)`` of step ``t`` (the sweeps' relinearization)."""
        if self.weight == 0 or self._U is None or not self.is_active_at(t):
            return
        n = self.c.size
        g, G = self.gravity.value_and_jacobian(x[:n])
        CG = self.c[:, None] * G
        lx[:n] -= 2.0 * self.weight * (CG.T @ (self._U[t] - g))
        lxx[:n, :n] += 2.0 * self.weight * (G.T @ CG)

    def add_cross_derivatives(self, X: np.ndarray, lux: np.ndarray) -> None:
        """Add the cross term ``l_ux = -2 w C G`` (exact) at rows ``X (T, n_x)`` to ``lux (T, n_u, n_x)``'s
        ``q`` block (a solver that keeps it: R-AICO's robust schedule, ``AICOOptions.cross_terms``)."""
        if self.weight == 0:
            return
        n = self.c.size
        _, G = self._g(X)
        lux[:, :, :n] -= 2.0 * self.weight * self.c[None, :, None] * G

    # -- the control part --------------------------------------------------------------------
    def add_control_derivatives(self, U: np.ndarray, lu: np.ndarray, luu: np.ndarray) -> None:
        """Add ``l_u = 2 w C (u - g(q))`` (nominal states) and ``l_uu = 2 w C``. Without a nominal
        trajectory of ``U``'s length (a probe at one control, e.g. AICO's check that the control cost is
        positive definite) only the Hessian, which does not depend on the states."""
        if self.weight == 0:
            return
        idx = np.arange(self.c.size)
        luu[:, idx, idx] += 2.0 * self.weight * self.c
        if self._X is not None and len(U) == len(self._X):
            lu += 2.0 * self.weight * self.c * (U - self._g_only(self._X))



# --------------------------------------------------------------------------------------------
# Examples: a configured instance of every cost term class, checked against finite
# differences by tests/plants/test_derivatives.py (raico.plants.numdiff.check_cost_term). Via-points are
# made on every registered task map example. A new term class registers an example here.
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CostTermExample:
    """``build(robot, q0) -> term`` (``q0 (n_q,)`` rad); ``kind`` is ``"state"`` or
    ``"control"``; ``plants``: where it applies (``None``: every plant); ``exact_hessian``:
    the Gauss-Newton Hessian is the exact one (quadratic terms, away from kinks)."""

    name: str
    build: Callable[[Any, np.ndarray], StateTerm | ControlTerm | Uncertainty | ControlGravity]
    kind: str
    plants: tuple[str, ...] | None = None
    exact_hessian: bool = False

    def applies_to(self, plant: str) -> bool:
        return self.plants is None or plant in self.plants


COST_TERM_EXAMPLES: dict[str, CostTermExample] = {}


def register_cost_term_example(name: str, build: Callable[[Any, np.ndarray], StateTerm | ControlTerm | Uncertainty | ControlGravity],
                               kind: str, plants: tuple[str, ...] | None = None,
                               exact_hessian: bool = False) -> CostTermExample:
    """Register an example cost term (unique ``name``; ``kind`` ``"state"``, ``"control"`` or
    ``"joint"`` for a term on ``(x_t, u_t)``)."""
    if kind not in ("state", "control", "joint"):
        raise ValueError(f"cost term example '{name}': kind must be 'state', 'control' or 'joint'")
    if name in COST_TERM_EXAMPLES:
        raise ValueError(f"cost term example '{name}' is already registered")
    COST_TERM_EXAMPLES[name] = CostTermExample(name, build, kind, plants, exact_hessian)
    return COST_TERM_EXAMPLES[name]


EXAMPLE_TIMES = (1, 3)  # steps at which the example state terms are active


def _via_point_example(taskmap_example: TaskMapExample):
    """A via-point on the task map example, off its value at ``q0`` (non-zero residual)."""
    def build(robot, q0: np.ndarray) -> ViaPoint:
        tm = taskmap_example.build(robot)
        phi0 = tm.value_and_jacobian(q0)[0]
        offset = 0.1 * np.cos(np.arange(tm.dim) + 1.0)
        return ViaPoint(tm, phi0 + offset, EXAMPLE_TIMES, 1e4,
                        precision=np.linspace(1.0, 3.0, tm.dim), name=f"via_{taskmap_example.name}")
    return build


def _state_target_example(robot, q0: np.ndarray) -> StateTarget:
    n_x = 2 * len(q0)
    L = np.tril(np.cos(np.add.outer(np.arange(n_x), 2 * np.arange(n_x)))) + 2 * np.eye(n_x)
    target = np.concatenate([q0 + 0.1, 0.2 * np.ones(len(q0))])
    return StateTarget(target, EXAMPLE_TIMES, 3.0, precision=L @ L.T)


def _register_via_point_examples() -> None:
    for ex in TASKMAP_EXAMPLES.values():
        register_cost_term_example(f"via_{ex.name}", _via_point_example(ex), "state", ex.plants)


_register_via_point_examples()
register_cost_term_example("state_target", _state_target_example, "state", exact_hessian=True)


def _support_example(robot, q0: np.ndarray) -> TaskInequality:
    """The CoG's ground projection inside a hexagon of radius 1 cm about its value at ``q0``, with a
    2 mm margin: the example postures (0.1-0.3 rad off ``q0``) violate some edges, not others."""
    from raico.plants.taskmaps import CenterOfMass

    tm = CenterOfMass(robot, axes=(0, 1), name="cog_xy")
    c0 = tm.value(q0)
    ang = np.pi / 6 + np.arange(6) * np.pi / 3
    A = np.c_[np.cos(ang), np.sin(ang)]           # outward unit normals
    b = A @ c0 + 0.01 * np.cos(np.pi / 6) - 0.002  # apothem less the margin
    return TaskInequality(tm, A, b, EXAMPLE_TIMES, 1e6, name="support_polygon")


def _lower_bound_example(robot, q0: np.ndarray) -> TaskInequality:
    """Heights of three points of the first end effector bounded below, 0.25 m, -0.02 m and 0.03 m
    off their values at ``q0`` (``A = -I``; the sole-lift bound of the single-support balance on
    any plant): on every plant some example rows violate some bounds, not others."""
    tm = FramePoints(robot, next(iter(robot.end_effectors.values())), points=[[0, 0, 0], [0.1, 0, 0], [0, 0.05, 0.02]],
                     axes=(2,), name="ee_heights")
    z0 = tm.value(q0)
    return TaskInequality(tm, -np.eye(3), -(z0 + np.array([0.25, -0.02, 0.03])), EXAMPLE_TIMES, 1e6, name="lower_bound")


register_cost_term_example("support_polygon", _support_example, "state")
register_cost_term_example("lower_bound", _lower_bound_example, "state")
register_cost_term_example("control", lambda r, q0: ControlCost(1e-2), "control",
                           exact_hessian=True)
register_cost_term_example(
    "control_target", lambda r, q0: ControlCost(0.5, target=np.linspace(-1.0, 1.0, len(q0)),
                                                name="control_target"),
    "control", exact_hessian=True)
register_cost_term_example(
    "control_per_joint", lambda r, q0: ControlCost(0.5, target=np.linspace(-1.0, 1.0, len(q0)),
                                                   name="control_per_joint",
                                                   precision=np.linspace(0.1, 3.0, len(q0))),
    "control", exact_hessian=True)
register_cost_term_example(
    "control_limit", lambda r, q0: ControlLimit(-0.5 * np.ones(len(q0)), 0.7 * np.ones(len(q0)),
                                                1e3),
    "control", exact_hessian=True)


def uncertainty_example(robot, q0: np.ndarray, units: str = "standardized") -> Uncertainty:
    """The uncertainty term on a small GP (``raico.plants.learned.example_params``), sigma* = 0.2."""
    from raico.plants.learned import build_learned, example_params

    model = build_learned(robot, 0.01, example_params(robot))
    return Uncertainty(model, 0.2, 1e-2, T=4, units=units)


register_cost_term_example("uncertainty", uncertainty_example, "joint")
register_cost_term_example("uncertainty_raw", lambda r, q0: uncertainty_example(r, q0, "raw"), "joint")
register_cost_term_example(
    "control_gravity", lambda r, q0: ControlGravity(r, 0.3, T=4, precision=np.linspace(0.5, 2.0, len(q0)),
                                                    name="control_gravity"), "joint")


class _SphereClearance:
    """The example's distances: two points of the first end effector to a sphere of radius ``r`` (m) about
    ``c (3,)``, ``d_i = |p_i(q) - c| - r`` (m), ``J_i = (p_i - c)^T / |p_i - c| dp_i/dq``. A stand-in for the
    scene's :class:`raico.plants.scene.SignedDistances` (whose gradients tests/plants/test_scene.py checks) on a
    plant without collision geometry, so the term's hinge and its derivatives are checked on every plant."""

    def __init__(self, robot, c: np.ndarray, r: float):
        self.points = FramePoints(robot, next(iter(robot.end_effectors.values())),
                                  points=[[0, 0, 0], [0.1, 0, 0]], name="clearance_points")
        self.c, self.r, self.dim, self.name = np.asarray(c, float), float(r), 2, "sphere_clearance"

    def values_and_jacobians(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        P, JP = self.points.values_and_jacobians(np.atleast_2d(Q))   # (K, 6), (K, 6, n_q)
        K = P.shape[0]
        delta = P.reshape(K, 2, 3) - self.c
        dist = np.linalg.norm(delta, axis=2)
        J = np.einsum("kpi,kpiq->kpq", delta / dist[..., None], JP.reshape(K, 2, 3, -1))
        return dist - self.r, J

    def value_and_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d, J = self.values_and_jacobians(q[None])
        return d[0], J[0]

    def value(self, q: np.ndarray) -> np.ndarray:
        return self.values_and_jacobians(q[None])[0][0]

    def evaluate(self, Q: np.ndarray, jacobians: bool = True, cull=None):
        d, J = self.values_and_jacobians(Q)
        return (d, J) if jacobians else (d, None)


def _collision_example(robot, q0: np.ndarray) -> Collision:
    """Two end-effector points kept 4 cm from a 2 cm sphere 5 cm off the effector at ``q0``: at the example
    postures (0.1-0.3 rad off ``q0``) some distances fall below the margin, others not."""
    p0 = FramePoints(robot, next(iter(robot.end_effectors.values())), name="p0").value(q0)
    tm = _SphereClearance(robot, p0 + np.array([0.05, 0.0, 0.0]), 0.02)
    return Collision(tm, 0.04, EXAMPLE_TIMES, 1e4, hard=False, name="collision")


register_cost_term_example("collision", _collision_example, "state")


def via_point_errors(problem, X: np.ndarray) -> dict[str, float]:
    """``{"<term>@<t>": error}``: Euclidean task error over the dimensions that count.

    Dimensions count whose precision is at least 1% of the largest (balance: the lateral
    axis only). Terms held at every step (the Nao's right sole) report their largest error.
    A step whose state is not finite has error ``inf``. A term that also costs step 0 (where
    ``x0`` is given: a running cost in crocoddyl's sense, e.g. a goal pulled towards on every node)
    is not a via-point and is left out.
    """
    n_q = X.shape[1] // 2
    out: dict[str, float] = {}
    for term in problem.state_terms:
        if not isinstance(term, ViaPoint) or term.is_active_at(0):
            continue
        w = np.diag(term.C)
        keep = w >= 0.01 * w.max()
        idx = np.flatnonzero(term.active(np.arange(problem.T + 1)))
        errs = np.full(idx.size, np.inf)
        good = np.all(np.isfinite(X[idx]), axis=1)
        if good.any():
            phi, _ = term.taskmap.values_and_jacobians(X[idx[good], :n_q])
            errs[good] = np.linalg.norm((term.target - phi)[:, keep], axis=1)
        if idx.size > 3:
            out[f"{term.name}@max"] = float(errs.max())
        else:
            out.update({f"{term.name}@{t}": float(e) for t, e in zip(idx, errs)})
    return out
