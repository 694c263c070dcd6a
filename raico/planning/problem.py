"""The planning problem, the result every solver returns, and the options base.

Contract (shared by every solver, trajax style):

- horizon ``T`` steps; states ``X`` of shape ``(T+1, n_x)`` with ``X[0] = x0``; controls
  ``U`` of shape ``(T, n_u)``; ``x_{t+1} = f(x_t, u_t)`` with ``f = problem.dynamics.step``.
  ``x = (q, qdot)``, ``n_x = 2 n_q``; task maps act on ``q = x[:n_q]``.
- cost: the plain sum of the terms' values, ``sum_t sum_i c_i(x_t) + sum_t sum_j c_j(u_t)``
  (state terms at ``t = 0..T``, control terms at ``t = 0..T-1``), e.g.
  ``w (x* - phi(q_t))^T C (x* - phi(q_t)) + w_u u_t^T u_t``. This is the cost every
  solver reports.
- quadratic (Gauss-Newton) models of a term use one convention: a term is
  ``1/2 x^T R x - r^T x`` (likelihood ``exp(-cost)``), so ``R = l_xx`` and
  ``r = l_xx x0 - l_x`` at the linearization point ``x0``; the same for controls with
  ``H = l_uu`` and ``h = l_uu u0 - l_u``.
- the time-varying feedback controller of a result is ``u_t = o_t + O_t x_t`` with
  ``o (T, n_u)`` and ``O (T, n_u, n_x)``.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, ClassVar, TypeGuard

import numpy as np

from raico.plants.codegen.c_backend import check_shapes
from raico.plants.dynamics import Dynamics, LinearDynamics, stepped_rollout


class Status(StrEnum):
    """Why a solver stopped. A ``str`` (``StrEnum``: ``(str, Enum)`` whose ``str()`` and
    ``format()`` give the value): equal to, and written (``str``, f-strings, JSON) as, its
    value, e.g. ``Status.CONVERGED == "converged"``."""

    CONVERGED = "converged"            # a convergence test was met
    MAX_ITERATIONS = "max-iterations"  # iteration budget, or a regularization limit (iLQG, crocoddyl FDDP)
    DIVERGED = "diverged"              # cost not finite or exploded, or a numerical failure
    OUT_OF_BOUNDS = "out-of-bounds"    # the plan leaves its hard bounds (joint range, effort) beyond tolerance


STATUSES = tuple(s.value for s in Status)


RANGE_STATUS_TOL = 1e-3  # rad: a plan beyond a joint range by more than this says so in its status
TORQUE_STATUS_TOL = 1e-3  # relative to the largest effort limit: a plan's torques beyond one by more say so


@dataclass(frozen=True)
class Bounds:
    """Hard bounds a solver keeps (beside any soft limit term): controls ``u_lower <= u_t <= u_upper``
    ``(n_u,)`` (``None``: unbounded; ``inf`` entries unbounded) and the positions ``q_lower <= x_t[j] <=
    q_upper`` of the state coordinates ``q_index (k,)`` (rad; ``None``: none), and the joint velocities
    ``v_lower <= x_t[j] <= v_upper`` of the state coordinates ``v_index`` (rad/s; ``None``: none). Where
    the controls are accelerations (pseudo-dynamics), ``tau_model`` (``inverse_dynamics(q, v, a)`` and
    ``qddot_derivatives(q, v, tau)``: an analytic model) and ``tau_limit (n_q,)`` (N m, ``inf``: none) bound
    the torques ``|M(q) u_t + h(q, v)| <= tau_limit`` the plan asks of the robot's motors."""

    u_lower: np.ndarray | None = None
    u_upper: np.ndarray | None = None
    q_index: np.ndarray | None = None
    q_lower: np.ndarray | None = None
    q_upper: np.ndarray | None = None
    v_index: np.ndarray | None = None
    v_lower: np.ndarray | None = None
    v_upper: np.ndarray | None = None
    tau_model: Any = None
    tau_limit: np.ndarray | None = None

    @property
    def has_torques(self) -> bool:
        return self.tau_model is not None and self.tau_limit is not None and bool(np.any(np.isfinite(self.tau_limit)))

    def torques(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """``tau (T, n_q)``: the torques of the accelerations ``U (T, n_q)`` at ``X[:-1]`` (``tau_model``)."""
        n = U.shape[1]
        return np.array([self.tau_model.inverse_dynamics(x[:n], x[n:], u) for x, u in zip(X[:-1], U)])

    def torque_violation(self, X: np.ndarray, U: np.ndarray) -> float:
        """Largest excess (N m) of the torques of ``U`` beyond ``tau_limit`` (0 inside or without one)."""
        if not self.has_torques or not np.all(np.isfinite(X)):
            return 0.0
        with np.errstate(invalid="ignore"):
            return float(np.nanmax(np.abs(self.torques(X, U)) - self.tau_limit, initial=0.0))

    @property
    def has_controls(self) -> bool:
        return self.u_lower is not None and bool(np.any(np.isfinite(self.u_lower) | np.isfinite(self.u_upper)))

    @property
    def has_positions(self) -> bool:
        return self.q_index is not None and len(self.q_index) > 0

    @property
    def has_velocities(self) -> bool:
        return self.v_index is not None and len(self.v_index) > 0

    def velocity_violation(self, X: np.ndarray) -> float:
        """Largest excess (rad/s) of ``X (T+1, n_x)`` (steps 1..T) beyond the velocity limits (0 inside)."""
        if not self.has_velocities:
            return 0.0
        V = X[1:, self.v_index]
        return float(max(0.0, np.max(V - self.v_upper), np.max(self.v_lower - V)))

    def position_box(self, x0: np.ndarray, dt: float, T: int) -> tuple[np.ndarray, np.ndarray]:
        """The ranges per step ``(T+1, k)`` a plan from ``x0`` must keep: the joint ranges, and for a joint
        that starts outside its range, as far as its velocity limit lets it come back by step ``t``
        (:func:`raico.planning.constraints.reachable_box`)."""
        from raico.planning.constraints import reachable_box

        vmax = np.full(len(self.q_index), np.inf)
        if self.has_velocities:
            n_q = x0.shape[0] // 2
            for j, qi in enumerate(self.q_index):
                hit = np.flatnonzero(np.asarray(self.v_index) == qi + n_q)
                if len(hit):
                    vmax[j] = min(-self.v_lower[hit[0]], self.v_upper[hit[0]])
        return reachable_box(self.q_lower, self.q_upper, x0[self.q_index], vmax, dt, T)

    def violation(self, X: np.ndarray, U: np.ndarray) -> tuple[float, float]:
        """Largest excess ``(positions (rad), controls)`` of ``X (T+1, n_x)`` (steps 1..T), ``U (T, n_u)``
        beyond the bounds (0 inside)."""
        q = u = 0.0
        if self.has_positions:   # from step 1: x_0 is the start, no plan changes it
            Q = X[1:, self.q_index]
            q = float(max(0.0, np.max(Q - self.q_upper), np.max(self.q_lower - Q)))
        if self.has_controls:
            u = float(max(0.0, np.max(U - self.u_upper), np.max(self.u_lower - U)))
        return q, u


@dataclass(eq=False)
class Problem:
    """A finite-horizon optimal control problem.

    Attributes:
        dynamics: the planning model ``x_{t+1} = f(x_t, u_t)`` (``raico.plants.dynamics.Dynamics``).
        x0: initial state ``(n_x,)``.
        T: horizon in steps (the movement lasts ``T * dynamics.dt`` seconds).
        state_terms: costs on ``x_t`` (``raico.planning.costs`` state terms), ``t = 0..T``.
        control_terms: costs on ``u_t`` (control terms), ``t = 0..T-1``.
        joint_terms: costs on ``(x_t, u_t)`` together, ``t = 0..T-1`` (the GP-uncertainty term).
            Their value uses both; their quadratic models are split: the state part at the
            nominal controls goes into the task messages ``R, r``, the control part at the
            nominal states into ``H, h``, and the state-control cross terms are dropped.
            A solver sets the nominal trajectory with :meth:`set_nominal` before
            it asks for derivatives.
        bounds: hard bounds (``Bounds``) for the solvers that keep them (AICO / R-AICO, BoxFDDP),
            or ``None``.
    """

    dynamics: Dynamics
    x0: np.ndarray
    T: int
    state_terms: list = field(default_factory=list)
    control_terms: list = field(default_factory=list)
    joint_terms: list = field(default_factory=list)
    bounds: Bounds | None = None

    def controller_rollout(self, o: np.ndarray, O: np.ndarray, *, kernel: bool = True
                           ) -> tuple[np.ndarray, np.ndarray]:
        """The problem's one rollout of ``u_t = o_t + O_t x_t`` from ``x0`` (every solver's line search
        calls it): ``X (T+1, n_x)``, ``U (T, n_u)``, compiled where possible with the same formulas:
        the model's own loop (``FastAnalyticDynamics``), the sweep kernel's C loop for a time-invariant
        ``LinearDynamics`` whose ``step`` is the affine map (``kernel``: allowed), else
        :func:`controller_rollout`, the reference Python loop."""
        dynamics, x0 = self.dynamics, self.x0
        own = getattr(dynamics, "controller_rollout", None)
        if own is not None:
            return own(x0, o, O)
        if kernel and is_lti(dynamics) and type(dynamics).step is LinearDynamics.step:
            from raico.planning import kernels

            lib = kernels.library()
            if lib is not None:
                T, m, n = np.shape(o)[0], dynamics.n_u, x0.shape[0]
                A, a, B = (np.ascontiguousarray(z, dtype=float) for z in (dynamics.A, dynamics.a, dynamics.B))
                x0, o, O = (np.ascontiguousarray(z, dtype=float) for z in (x0, o, O))
                check_shapes("lti_rollout", A=(A, (n, n)), a=(a, (n,)), B=(B, (n, m)), o=(o, (T, m)),
                             O=(O, (T, m, n)))
                X, U = np.empty((T + 1, n)), np.empty((T, m))
                lib.lti_rollout(T, n, m, *(z.ctypes.data for z in (A, a, B, x0, o, O, X, U)))
                return X, U
        return controller_rollout(dynamics, x0, o, O)

    def bounded_rollout(self, o: np.ndarray, O: np.ndarray, *, kernel: bool = True
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The controller ``u_t = o_t + O_t x_t`` rolled out: ``X (T+1, n)``, ``U (T, m)`` and the controller
        ``o, O`` that gives them. With control bounds (``bounds``) every control is clipped into its box as it
        is applied (a projection: the effort limits hold exactly), and the controller returned is the
        consistent one: a clipped control's feedforward is its clipped value and its feedback row zero
        (BoxDDP's clamped directions: near the plan a saturated motor stays saturated)."""
        b = self.bounds
        if b is None or not b.has_controls:
            X, U = self.controller_rollout(o, O, kernel=kernel)
            return X, U, o, O
        with np.errstate(invalid="ignore"):   # no control beyond its box: the unbounded rollout's numbers
            X, U = self.controller_rollout(o, O, kernel=kernel)
            if np.all(np.isfinite(X)) and np.all((U >= b.u_lower) & (U <= b.u_upper)):
                return X, U, o, O
        T, step = o.shape[0], self.dynamics.step
        X, U = np.empty((T + 1, self.n_x)), np.empty(o.shape)
        X[0] = self.x0
        clipped = np.zeros(o.shape, dtype=bool)
        with np.errstate(all="ignore"):
            for t in range(T):
                raw = o[t] + O[t] @ X[t]
                U[t] = np.clip(raw, b.u_lower, b.u_upper)
                clipped[t] = U[t] != raw
                X[t + 1] = step(X[t], U[t])
        if clipped.any():
            o, O = o.copy(), O.copy()
            o[clipped] = U[clipped]
            O[clipped] = 0.0
        return X, U, o, O

    def __post_init__(self) -> None:
        self.x0 = np.asarray(self.x0, dtype=float).reshape(-1)
        if self.x0.shape != (self.dynamics.n_x,):
            raise ValueError(f"x0 has shape {self.x0.shape}, expected ({self.dynamics.n_x},)")
        if not np.all(np.isfinite(self.x0)):
            raise ValueError("x0 must be finite")
        if int(self.T) != self.T or self.T < 1:
            raise ValueError(f"T must be an integer >= 1, got {self.T}")
        self.T = int(self.T)
        names = [t.name for t in self.all_terms()]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"cost term names must be unique, repeated: {dup}")
        for term in self.state_terms:
            times = getattr(term, "times", None)
            if times is not None and len(times) and (min(times) < 0 or max(times) > self.T):
                raise ValueError(f"term {term.name!r}: times must lie in [0, T={self.T}]")

    # -- sizes ---------------------------------------------------------------
    @property
    def n_x(self) -> int:
        return self.dynamics.n_x

    @property
    def n_u(self) -> int:
        return self.dynamics.n_u

    # -- terms ---------------------------------------------------------------
    def all_terms(self) -> list:
        return [*self.state_terms, *self.control_terms, *self.joint_terms]

    def term(self, name: str):
        """The cost term called ``name``."""
        for t in self.all_terms():
            if t.name == name:
                return t
        raise KeyError(f"no cost term {name!r}; terms: {self.term_names()}")

    def term_names(self) -> list[str]:
        return [t.name for t in self.all_terms()]

    def set_nominal(self, X: np.ndarray, U: np.ndarray) -> None:
        """The trajectory ``X (T+1, n_x)``, ``U (T, n_u)`` the joint terms split their models at."""
        for term in self.joint_terms:
            term.set_nominal(X, U)

    def without(self, *names: str) -> Problem:
        """A copy without the named terms (ablations)."""
        for n in names:
            self.term(n)
        return dataclasses.replace(
            self,
            state_terms=[t for t in self.state_terms if t.name not in names],
            control_terms=[t for t in self.control_terms if t.name not in names],
            joint_terms=[t for t in self.joint_terms if t.name not in names],
        )

    # -- costs ---------------------------------------------------------------
    def cost_terms(self, X: np.ndarray, U: np.ndarray) -> dict[str, float]:
        """Total value of each term along ``X (T+1, n_x)``, ``U (T, n_u)``."""
        out = {t.name: float(np.sum(t.value(X))) for t in self.state_terms}
        out.update({t.name: float(np.sum(t.value(U))) for t in self.control_terms})
        out.update({t.name: float(np.sum(t.joint_value(X[:-1], U))) for t in self.joint_terms})
        return out

    def cost(self, X: np.ndarray, U: np.ndarray) -> float:
        """The reported cost: plain sum of all terms' values (``inf`` if not finite)."""
        with np.errstate(all="ignore"):
            c = sum(self.cost_terms(X, U).values(), 0.0)
        return float(c) if math.isfinite(c) else math.inf

    def state_derivatives(
        self, X: np.ndarray, idx: np.ndarray | None = None,
        out: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Summed ``l_x (K, n_x)`` and Gauss-Newton ``l_xx (K, n_x, n_x)`` at rows ``X (K, n_x)``.

        ``idx (K,)`` are the time steps of the rows (default ``0..K-1``); ``out`` optional
        buffers ``(l_x, l_xx)`` of those shapes (may be views) to write into.
        """
        X = np.atleast_2d(X)
        idx = np.arange(X.shape[0]) if idx is None else np.asarray(idx)
        if out is None:
            lx = np.zeros(X.shape)
            lxx = np.zeros((X.shape[0], X.shape[1], X.shape[1]))
        else:
            lx, lxx = out
            lx[...] = 0.0
            lxx[...] = 0.0
        for term in self.state_terms:
            term.add_derivatives(X, idx, lx, lxx)
        for term in self.joint_terms:
            term.add_derivatives(X, idx, lx, lxx)
        return lx, lxx

    def active_state_terms(self) -> list[list]:
        """For each step ``t = 0..T``: the state terms with nonzero weight that cost ``x_t``.

        Where the list is empty the task message does not depend on ``x_t``.
        """
        steps = np.arange(self.T + 1)
        out: list[list] = [[] for _ in steps]
        for term in self.state_terms + self.joint_terms:
            times = getattr(term, "times", None)
            if term.weight == 0 or (times is not None and len(times) == 0):   # costs no step (outside a window)
                continue
            for t in np.flatnonzero(term.active(steps)):
                out[t].append(term)
        return out

    def point_state_derivatives(self, x: np.ndarray, t: int,
                                terms: list | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Summed ``l_x (n_x,)`` and GN ``l_xx (n_x, n_x)`` at one state ``x (n_x,)`` of step ``t``.

        ``terms``: the state terms to sum (default all; inactive ones add nothing), e.g.
        ``active_state_terms()[t]`` to skip the others without asking them.
        """
        lx = np.zeros(x.shape[0])
        lxx = np.zeros((x.shape[0], x.shape[0]))
        for term in self.state_terms + self.joint_terms if terms is None else terms:
            term.add_point_derivatives(x, t, lx, lxx)
        return lx, lxx

    def control_derivatives(self, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Summed ``l_u (K, n_u)`` and Gauss-Newton ``l_uu (K, n_u, n_u)`` at ``U (K, n_u)``."""
        U = np.atleast_2d(U)
        lu = np.zeros(U.shape)
        luu = np.zeros((U.shape[0], U.shape[1], U.shape[1]))
        for term in self.control_terms:
            g, h = term.derivatives(U)
            lu += g
            luu += h
        for term in self.joint_terms:
            term.add_control_derivatives(U, lu, luu)
        return lu, luu

    def quadratize_states(
        self, X: np.ndarray, idx: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Task messages ``R (K, n_x, n_x)``, ``r (K, n_x)`` (``1/2 x^T R x - r^T x``) at ``X``."""
        lx, lxx = self.state_derivatives(X, idx)
        return lxx, np.einsum("kij,kj->ki", lxx, np.atleast_2d(X)) - lx

    def quadratize_controls(self, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Control messages ``H (K, n_u, n_u)``, ``h (K, n_u)`` (``1/2 u^T H u - h^T u``) at ``U``."""
        lu, luu = self.control_derivatives(U)
        return luu, np.einsum("kij,kj->ki", luu, np.atleast_2d(U)) - lu


@dataclass
class IterationRecord:
    """One solver iteration.

    Attributes:
        iteration: 1-based iteration number.
        cost: cost of rolling the current controller out on the planning dynamics.
        time_s: wall time of this iteration in seconds (linearization included).
        elapsed_s: wall time since the solver started, seconds.
        step: step-size parameter (R-AICO: alpha of this iteration; iLQG: accepted
            line-search step, 0 if none was accepted).
        mu: regularization (iLQG: mu after the iteration's update; AICO: 0).
        repeats: AICO only: number of relinearization repeats in the sweeps.
        accepted: whether the iterate moved to this iteration's result (False: a trial the adaptive
            R-AICO schedule rejected, keeping the previous iterate; an iLQG iteration without an
            accepted step; a numerical failure).
    """

    iteration: int
    cost: float
    time_s: float
    elapsed_s: float
    step: float
    mu: float = 0.0
    repeats: int = 0
    accepted: bool = True


@dataclass(eq=False)
class Result:
    """What every solver returns (shapes in the module docstring).

    Attributes:
        X: final trajectory ``(T+1, n_x)`` (rollout of the controller on the planning model).
        U: its controls ``(T, n_u)``.
        o: controller offsets ``(T, n_u)``; ``u_t = o_t + O_t x_t``.
        O: controller gains ``(T, n_u, n_x)``.
        status: a ``Status`` (a plain status string is converted): ``"converged"``,
            ``"max-iterations"`` (stopped without meeting a convergence test: iteration budget,
            or iLQG's regularization limit) or ``"diverged"``.
        history: one ``IterationRecord`` per iteration.
        iterations: number of iterations run.
        message: one human-readable line on why the solver stopped.
        initial_cost: cost of the initial guess rolled out (zero controls unless warm-started).
        beliefs: AICO only: belief means ``b_t (T+1, n_x)`` of the last sweep.
        solver: name of the solver.
        X_initial: the initial guess rolled out ``(T+1, n_x)`` (the trajectory whose cost is
            ``initial_cost``; ``None`` if the solver does not report it).
        X_iterations: every iteration's states at the steps ``t_iterations``,
            ``(iterations + 1, K, n_x)`` float32 (a display copy, ``IterateHistory``); filled
            by ``raico.planning.solvers.solve``, ``None`` otherwise.
        t_iterations: the steps kept ``(K,)`` (``iterate_steps``).
    """

    X: np.ndarray
    U: np.ndarray
    o: np.ndarray
    O: np.ndarray
    status: Status
    history: list[IterationRecord]
    iterations: int
    message: str
    initial_cost: float = math.nan
    beliefs: np.ndarray | None = None
    solver: str = ""
    X_initial: np.ndarray | None = None
    X_iterations: np.ndarray | None = None
    t_iterations: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status {self.status!r} not in {STATUSES}")
        self.status = Status(self.status)

    @property
    def cost(self) -> float:
        """Cost of the last iteration (``initial_cost`` if none ran)."""
        return self.history[-1].cost if self.history else self.initial_cost

    @property
    def costs(self) -> np.ndarray:
        """Per-iteration costs ``(iterations,)``."""
        return np.array([h.cost for h in self.history])


def bounds_status(problem: Problem, res: Result) -> None:
    """Status ``out-of-bounds`` (and why) for a plan beyond a joint range by more than ``RANGE_STATUS_TOL`` (rad;
    from a start outside a range: beyond the range as far as the velocity limits let the joint come back,
    :meth:`Bounds.position_box`), beyond a velocity limit by more than ``RANGE_STATUS_TOL`` (rad/s) or beyond an
    effort limit (relative 1e-9); a diverged plan keeps its status. A start outside a range is said in the
    message (with the first step the plan is inside), whatever the status."""
    b = problem.bounds
    note = start_outside_note(problem, res.X) if np.all(np.isfinite(res.X)) else ""
    if note:
        res.message = f"{note}; {res.message}"
    if res.status is Status.DIVERGED or not np.all(np.isfinite(res.X)):
        return
    _, u = b.violation(res.X, res.U)
    q = 0.0
    if b.has_positions:
        lo, hi = b.position_box(problem.x0, _dt(problem), problem.T)
        Q = res.X[1:, b.q_index]
        q = float(max(0.0, np.max(Q - hi[1:]), np.max(lo[1:] - Q)))
    v = b.velocity_violation(res.X)
    scale = float(np.max(np.abs(np.where(np.isfinite(b.u_upper), b.u_upper, 0.0)))) if b.has_controls else 0.0
    tau = b.torque_violation(res.X, res.U)
    tau_tol = TORQUE_STATUS_TOL * float(np.max(np.where(np.isfinite(b.tau_limit), b.tau_limit, 0.0))) if b.has_torques else 0.0
    if q > RANGE_STATUS_TOL or v > RANGE_STATUS_TOL or u > 1e-9 * max(scale, 1.0) or tau > tau_tol:
        what = (f"a joint range by {q:.3g} rad" if q > RANGE_STATUS_TOL else
                f"a velocity limit by {v:.3g} rad/s" if v > RANGE_STATUS_TOL else
                f"an effort limit by {u:.3g}" if u > 1e-9 * max(scale, 1.0) else
                f"an effort limit by {tau:.3g} N m (the torques of its accelerations)")
        res.status = Status.OUT_OF_BOUNDS
        res.message = f"the plan leaves {what} ({res.message})"


def _dt(problem: Problem) -> float:
    dt = getattr(problem.dynamics, "dt", None)
    return float(dt) if isinstance(dt, (int, float)) and dt > 0 else 1.0


def start_outside_note(problem: Problem, X: np.ndarray) -> str:
    """``""``, or where the start lies outside a joint range of ``problem.bounds``: which joints, by how much
    and the first step at which the plan ``X (T+1, n_x)`` is inside every range."""
    b = problem.bounds
    if b is None or not b.has_positions:
        return ""
    q0 = problem.x0[b.q_index]
    excess = np.maximum(b.q_lower - q0, q0 - b.q_upper)
    out = np.flatnonzero(excess > 0)
    if not len(out):
        return ""
    Q = X[:, b.q_index]
    inside = np.all((Q >= b.q_lower - RANGE_STATUS_TOL) & (Q <= b.q_upper + RANGE_STATUS_TOL), axis=1)
    first = int(np.argmax(inside)) if inside.any() else None
    which = ", ".join(f"coordinate {b.q_index[j]} by {excess[j]:.3g} rad" for j in out[:4])
    return (f"the start is outside a joint range ({which}); the plan is inside "
            + (f"from step {first}" if first is not None else f"at no step of its {problem.T}"))


def is_lti(dynamics) -> TypeGuard[LinearDynamics]:
    """Whether ``dynamics`` linearizes to the same ``A, a, B`` everywhere (a ``LinearDynamics``
    that keeps its ``linearize``): then relinearizing never changes them."""
    return (isinstance(dynamics, LinearDynamics)
            and type(dynamics).linearize is LinearDynamics.linearize
            and type(dynamics).linearize_trajectory is LinearDynamics.linearize_trajectory)


def controller_rollout(
    dynamics: Dynamics, x0: np.ndarray, o: np.ndarray, O: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Roll ``u_t = o_t + O_t x_t`` out on ``dynamics`` from ``x0``: ``X (T+1, n_x)``, ``U (T, n_u)``
    (``raico.plants.dynamics.stepped_rollout``, the reference Python loop).

    Non-finite states propagate (NaN) instead of raising; callers check the result.
    """
    return stepped_rollout(dynamics, x0, o, O)


@dataclass(frozen=True)
class Flag:
    """A solver option as a plan-stage config field ``name`` (the CLI's ``--name``, dashes for
    underscores) of type ``type`` with ``default`` and ``help``.

    ``option``: the options-class field it sets (``None``: ``name``); ``to_option``: that option's
    value from the field's (``None`` from it: the option's own default); ``resolve``: the value in
    force given the field's and whether the problem is a problem file (``None``: the field's);
    ``unused``: the value a config stores (its cache key) where it goes unused; ``only``:
    ``(flag, values, why)``: used only while that other flag's value is one of ``values``."""

    name: str
    type: type
    default: Any
    help: str
    unused: Any
    option: str | None = None
    to_option: Callable[[Any], Any] | None = None
    resolve: Callable[[Any, bool], Any] | None = None
    only: tuple[str, tuple, str] | None = None


class OptionsBase:
    """Mixin for frozen option dataclasses: strict construction from a dict. ``FLAGS``: the options
    the plan stage exposes as config fields and CLI flags (:class:`Flag`)."""

    FLAGS: ClassVar[tuple[Flag, ...]] = ()

    def validate(self) -> None:  # overridden
        pass

    def __post_init__(self) -> None:
        self.validate()

    @classmethod
    def field_names(cls) -> list[str]:
        return [f.name for f in dataclasses.fields(cls)]  # type: ignore[arg-type]

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None = None, **defaults: Any):
        """Build options from ``d``; unknown keys raise ``ValueError`` naming the valid ones.

        ``defaults`` (keyword arguments) are applied first and overridden by ``d``.
        """
        d = dict(d or {})
        valid = cls.field_names()
        unknown = sorted(set(d) - set(valid))
        if unknown:
            raise ValueError(
                f"unknown {cls.__name__} option(s) {unknown}; valid options: {valid}"
            )
        return cls(**{**defaults, **d})

    def to_dict(self) -> dict[str, Any]:
        out = {}
        for k, v in dataclasses.asdict(self).items():  # type: ignore[call-overload]
            out[k] = v.tolist() if isinstance(v, np.ndarray) else v
        return out


def check_range(name: str, value: Any, lo: float | None = None, hi: float | None = None,
                lo_open: bool = False, integer: bool = False) -> None:
    """Raise ``ValueError`` unless ``value`` is a finite number in the given range."""
    ok_type = isinstance(value, (int, np.integer)) if integer else isinstance(
        value, (int, float, np.integer, np.floating))
    if isinstance(value, bool) or not ok_type:
        kind = "an integer" if integer else "a number"
        raise ValueError(f"option {name} must be {kind}, got {value!r}")
    v = float(value)
    if math.isnan(v):
        raise ValueError(f"option {name} must not be NaN")
    if lo is not None and (v <= lo if lo_open else v < lo):
        raise ValueError(f"option {name} must be {'>' if lo_open else '>='} {lo}, got {value}")
    if hi is not None and v > hi:
        raise ValueError(f"option {name} must be <= {hi}, got {value}")


Callback = Callable[[IterationRecord, np.ndarray, np.ndarray], None]
"""Per-iteration hook ``callback(record, X (T+1, n_x), U (T, n_u))`` (recording, progress)."""

ITERATE_SAMPLES = 50  # steps kept per iterate: every ceil(T / 50)-th one (plus the last and via-points)
VIA_POINT_STEPS = 10  # a state term active at more steps is a running cost, not a via-point


def iterate_steps(problem: Problem, samples: int = ITERATE_SAMPLES) -> np.ndarray:
    """The steps ``(K,)`` kept of each iterate's trajectory (``IterateHistory``): every n-th step
    from 0 (``n = ceil(T / samples)``), the last step ``T`` and every via-point step of the
    objective (the times of state terms active at no more than ``VIA_POINT_STEPS`` steps; a term
    held over many steps, the Nao's right sole, adds none). ``K <= samples + 1 + via-points``."""
    T = problem.T
    every = max(1, -(-T // max(int(samples), 1)))
    vias = [int(t) for term in problem.state_terms
            if getattr(term, "times", None) is not None and 0 < len(term.times) <= VIA_POINT_STEPS
            for t in term.times]
    return np.unique(np.r_[np.arange(0, T + 1, every), T, vias].astype(np.int64))


class IterateHistory:
    """Every iteration's trajectory at the steps ``steps`` (a ``Callback``): row 0 the initial
    trajectory (``start``), row ``i`` the iterate of iteration ``i`` as the solver reports it
    through its callback. A display copy in float32 (about 7 significant digits, enough to draw;
    the plan's own ``X`` stays float64). Iterations that report nothing (they diverged) stay NaN.
    """

    def __init__(self, steps: np.ndarray, start: np.ndarray | None = None):
        self.steps = np.asarray(steps, dtype=np.int64)
        self.rows: dict[int, np.ndarray] = {}
        if start is not None:
            self.rows[0] = self._keep(start)

    def _keep(self, X: np.ndarray) -> np.ndarray:
        with np.errstate(all="ignore"):
            x = np.asarray(X, dtype=float)[self.steps].astype(np.float32)
        return np.where(np.isfinite(x), x, np.float32(np.nan))

    def __call__(self, record: IterationRecord, X: np.ndarray, U: np.ndarray) -> None:
        self.rows[int(record.iteration)] = self._keep(X)

    def set(self, iteration: int, X: np.ndarray) -> None:
        """Row ``iteration`` from a full trajectory ``X (T+1, n_x)``."""
        self.rows[int(iteration)] = self._keep(X)

    def array(self, iterations: int, n_x: int) -> np.ndarray:
        """``(iterations + 1, K, n_x)`` float32, NaN where nothing was reported."""
        out = np.full((iterations + 1, len(self.steps), n_x), np.nan, dtype=np.float32)
        for i, row in self.rows.items():
            if 0 <= i <= iterations:
                out[i] = row
        return out


_BLAS_CONTROLLER: list[Any] = [None, -1]   # threadpoolctl's controller, len(sys.modules) when it was built


def single_threaded_blas():
    """Context limiting BLAS/LAPACK to one thread while a solver runs.

    The solvers issue many small (n <= 100) dense operations; a multithreaded BLAS gains
    nothing on them and, on a loaded machine, spin-waiting threads slow them down by an
    order of magnitude. The scan of the loaded libraries (about 1 ms) is kept from one solve
    to the next and redone only when a module was imported since (it may have loaded a BLAS).
    """
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # pragma: no cover - threadpoolctl comes with scikit-learn
        import contextlib
        return contextlib.nullcontext()
    n_modules = len(sys.modules)
    if _BLAS_CONTROLLER[0] is None or _BLAS_CONTROLLER[1] != n_modules:
        _BLAS_CONTROLLER[:] = [ThreadpoolController(), n_modules]
    return _BLAS_CONTROLLER[0].limit(limits=1, user_api="blas")
