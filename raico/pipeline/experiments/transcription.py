"""A direct-transcription reference: a planning problem as one nonlinear program, solved by SNOPT or IPOPT.

The decision variables are every state and control of the plan, ``X (T+1, n_x)`` and ``U (T, n_u)``, as
Drake's ``MathematicalProgram`` holds them; the program is the problem every solver of this package
solves, written out:

- ``X[0] = x0``; the dynamics ``X[t+1] = f(X[t], U[t])`` as equality constraints, ``f =
  problem.dynamics.step`` (the planners' own discretization, its Jacobians from ``dynamics.linearize``);
- the cost ``sum_t sum_i c_i(X[t]) + sum_t sum_j c_j(U[t])`` (``problem.cost``), one cost per state and
  per control with the terms' exact gradients (``l_x``, ``l_u``);
- the hard bounds ``problem.bounds``: the positions ``q_lower <= X[t, q_index] <= q_upper`` and the joint
  velocities ``v_lower <= X[t, v_index] <= v_upper`` (the model file's velocity limits) from step 1 (``x_0``
  is the start, no plan changes it), the controls' box, and for acceleration controls the torques they ask
  for, ``|tau(x_t, u_t)| <= tau_limit`` (``M(q) u + h(q, v)``, the bounds' ``tau_model``; its Jacobians as
  :class:`raico.planning.constraints.TorqueBox` takes them) at steps ``0..T-1``.

Second derivatives are left to the solver's quasi-Newton approximation (SNOPT's, IPOPT's limited-memory
BFGS). Warm-started from a plan (``X``, ``U`` of a solver), it gives the best feasible cost known for
problems small enough to transcribe (a few joints, a hundred steps: the program has ``(T+1) n_x + T n_u``
variables). Joint terms (cost terms on a state and its control together) are not transcribed:
:func:`refusal` says so. A reference is kept by :func:`cache_key`: its warm start, solver, iteration limit and
the transcribed problem's start, horizon and bounds.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from raico.planning.problem import Problem

SOLVERS = ("snopt", "ipopt")
FEASIBILITY_TOL = 1e-6   # the solvers' constraint tolerance (dynamics defect, bounds), in the variables' units
FORMAT = 2               # what the transcription constrains: 2 with the velocity limits (in every cache key) ...
FORMAT_TORQUES = 3       # ... 3 the torques of acceleration controls too (the key of a problem with them)


@dataclass
class Transcribed:
    """The reference's result: the plan ``X (T+1, n_x)``, ``U (T, n_u)``, its cost (``problem.cost``), the
    solver's status, whether the plan is feasible (the dynamics defect and the bounds' excess below
    ``tol``), those numbers (the velocity limits' excess apart), the solver and its wall time (s)."""

    X: np.ndarray
    U: np.ndarray
    cost: float
    status: str
    feasible: bool
    defect: float        # largest |X[t+1] - f(X[t], U[t])| (state units)
    bound_excess: float  # largest excess over the hard bounds' ranges and controls (rad, N m)
    solver: str
    time_s: float
    velocity_excess: float = 0.0  # largest excess over the velocity limits (rad/s)
    torque_excess: float = 0.0    # largest excess of the accelerations' torques over the effort limits (N m)

    def record(self) -> dict[str, Any]:
        """The scalars, for a table."""
        return {"cost": self.cost if math.isfinite(self.cost) else None, "status": self.status,
                "feasible": self.feasible, "defect": self.defect, "range_excess": self.bound_excess,
                "velocity_excess": self.velocity_excess, "torque_excess": self.torque_excess,
                "solver": self.solver, "time_s": self.time_s}


def refusal(problem: Problem, max_joints: int = 7, max_steps: int = 100) -> str:
    """Why ``problem`` is not transcribed ("" where it is): more than ``max_joints`` positions or
    ``max_steps`` steps, or joint terms."""
    n_q = problem.n_x // 2
    if n_q > max_joints:
        return f"{n_q} joints > {max_joints}"
    if problem.T > max_steps:
        return f"T = {problem.T} > {max_steps}"
    if problem.joint_terms:
        return "joint cost terms (a state and its control together) are not transcribed"
    b = problem.bounds
    if b is not None and b.has_positions:
        q = problem.x0[b.q_index]
        if np.any(q > b.q_upper + 1e-3) or np.any(q < b.q_lower - 1e-3):
            return "the start lies outside a joint range: no plan is inside from step 1"
    return ""


def _autodiff(fun):
    """A Drake evaluator from ``fun(z (k,)) -> (value (m,), jacobian (m, k))``: floats in, floats out;
    AutoDiffXd in, AutoDiffXd out, the jacobian chained with the inputs' derivatives."""
    from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff

    def evaluate(z):
        z = np.asarray(z)
        if z.dtype != object:
            return fun(z.astype(float))[0]
        value, jac = fun(ExtractValue(z).reshape(-1))
        grad = jac @ ExtractGradient(z)
        return InitializeAutoDiff(value.reshape(-1, 1), grad).reshape(-1)

    return evaluate


def transcribe(problem: Problem, X0: np.ndarray, U0: np.ndarray):
    """The problem as ``(prog, X, U)``: a ``MathematicalProgram`` and its variables, initial guess ``X0
    (T+1, n_x)``, ``U0 (T, n_u)`` (its ``X0[0]`` is replaced by the start)."""
    from pydrake.solvers import MathematicalProgram

    if problem.joint_terms:
        raise ValueError("joint cost terms are not transcribed")
    T, n, m = problem.T, problem.n_x, problem.n_u
    dyn = problem.dynamics
    prog = MathematicalProgram()
    X = prog.NewContinuousVariables(T + 1, n, "x")
    U = prog.NewContinuousVariables(T, m, "u")
    prog.AddBoundingBoxConstraint(problem.x0, problem.x0, X[0])

    def defect(z):   # z = (x_t, u_t, x_{t+1}) -> f(x_t, u_t) - x_{t+1}
        x, u, x1 = z[:n], z[n:n + m], z[n + m:]
        A, _, B = dyn.linearize(x, u)
        return dyn.step(x, u) - x1, np.hstack([A, B, -np.eye(n)])

    dyn_eval = _autodiff(defect)
    for t in range(T):
        prog.AddConstraint(dyn_eval, np.zeros(n), np.zeros(n), np.concatenate([X[t], U[t], X[t + 1]]))

    active = problem.active_state_terms()
    for t in range(T + 1):
        terms = active[t]
        if not terms:
            continue

        def state_cost(x, t=t, terms=terms):
            value = sum(float(term.value(x[None, :], np.array([t]))[0]) for term in terms)
            lx, _ = problem.point_state_derivatives(x, t, terms)
            return np.array([value]), lx[None, :]

        cost_eval = _autodiff(state_cost)
        prog.AddCost(lambda z, f=cost_eval: f(z)[0], X[t])
    if problem.control_terms:
        def control_cost(u):
            value = sum(float(term.value(u[None, :])[0]) for term in problem.control_terms)
            lu, _ = problem.control_derivatives(u[None, :])
            return np.array([value]), lu

        ctrl = _autodiff(control_cost)
        for t in range(T):
            prog.AddCost(lambda z, f=ctrl: f(z)[0], U[t])

    b = problem.bounds
    if b is not None and b.has_positions:
        for t in range(1, T + 1):
            prog.AddBoundingBoxConstraint(b.q_lower, b.q_upper, X[t, b.q_index])
    if b is not None and b.has_velocities:
        for t in range(1, T + 1):
            prog.AddBoundingBoxConstraint(b.v_lower, b.v_upper, X[t, b.v_index])
    if b is not None and b.has_controls:
        for t in range(T):
            prog.AddBoundingBoxConstraint(b.u_lower, b.u_upper, U[t])
    if b is not None and b.has_torques:
        torque_eval, idx, limit = _torques(b, n)
        for t in range(T):
            prog.AddConstraint(torque_eval, -limit, limit, np.concatenate([X[t], U[t]]))
    X0 = np.array(X0, float, copy=True)
    X0[0] = problem.x0
    prog.SetInitialGuess(X, X0)
    prog.SetInitialGuess(U, np.asarray(U0, float))
    return prog, X, U


def _torques(b, n: int):
    """The torques of acceleration controls as a Drake evaluator of ``(x_t, u_t)`` (the joints ``idx`` with a finite
    effort limit), ``idx`` and their limits: ``tau = M(q) u + h(q, v)`` by ``b.tau_model.inverse_dynamics``, its
    Jacobians ``tau_q = -M a_q``, ``tau_v = -M a_v``, ``tau_u = M`` from ``qddot_derivatives`` (differentiating
    ``a(q, v, tau(q, v, u)) = u``, as :class:`raico.planning.constraints.TorqueBox`)."""
    n_q = n // 2
    idx = np.flatnonzero(np.isfinite(b.tau_limit) & (np.asarray(b.tau_limit, float) > 0))
    model = b.tau_model

    def torque(z):
        q, v, u = z[:n_q], z[n_q:n], z[n:]
        tau = np.asarray(model.inverse_dynamics(q, v, u), float)
        _, a_q, a_v, Minv = model.qddot_derivatives(q, v, tau)
        M = np.linalg.inv(Minv)
        return tau[idx], np.hstack([-M @ a_q, -M @ a_v, M])[idx]

    return _autodiff(torque), idx, np.asarray(b.tau_limit, float)[idx]


def solve(problem: Problem, X0: np.ndarray, U0: np.ndarray, solver: str = "snopt",
          max_iterations: int = 3000, tol: float = FEASIBILITY_TOL, time_limit_s: float = 600.0) -> Transcribed:
    """The reference plan of ``problem`` from the guess ``X0 (T+1, n_x)``, ``U0 (T, n_u)`` (a solver's plan)
    by ``solver`` (``snopt`` or ``ipopt``), at most ``max_iterations`` major iterations and
    ``time_limit_s`` seconds (SNOPT's CPU seconds, checked at its own pace; IPOPT's wall-clock seconds). A solver that stops without success still returns its last point, with its
    status: feasibility is judged here."""
    from pydrake.solvers import IpoptSolver, SnoptSolver, SolverOptions

    if solver not in SOLVERS:
        raise ValueError(f"solver '{solver}': one of {', '.join(SOLVERS)}")
    prog, Xv, Uv = transcribe(problem, X0, U0)
    opts = SolverOptions()
    if solver == "snopt":
        drake_solver = SnoptSolver()
        sid = drake_solver.solver_id()
        opts.SetOption(sid, "Major iterations limit", int(max_iterations))
        opts.SetOption(sid, "Iterations limit", int(max_iterations) * 50)
        opts.SetOption(sid, "Major feasibility tolerance", tol)
        opts.SetOption(sid, "Major optimality tolerance", 1e-6)
        opts.SetOption(sid, "Time limit", float(time_limit_s))
    else:
        drake_solver = IpoptSolver()
        sid = drake_solver.solver_id()
        opts.SetOption(sid, "max_iter", int(max_iterations))
        opts.SetOption(sid, "tol", 1e-8)
        opts.SetOption(sid, "constr_viol_tol", tol)
        opts.SetOption(sid, "print_level", 0)
        opts.SetOption(sid, "max_wall_time", float(time_limit_s))
    start = time.perf_counter()
    res = drake_solver.Solve(prog, prog.GetInitialGuess(prog.decision_variables()), opts)
    elapsed = time.perf_counter() - start
    X, U = np.asarray(res.GetSolution(Xv), float), np.asarray(res.GetSolution(Uv), float)
    return judge(problem, X, U, str(res.get_solution_result()).split(".")[-1], solver, elapsed, tol)


def judge(problem: Problem, X: np.ndarray, U: np.ndarray, status: str, solver: str, time_s: float,
          tol: float = FEASIBILITY_TOL) -> Transcribed:
    """The plan ``X``, ``U`` measured: its cost, dynamics defect and bounds' excess (ranges, controls,
    velocity limits, the torques of acceleration controls), feasible where all are within ``tol`` (scaled by the
    states' magnitude for the defect, by the largest effort limit for the torques)."""
    with np.errstate(all="ignore"):
        pred = np.array([problem.dynamics.step(x, u) for x, u in zip(X[:-1], U)])
        defect = float(np.max(np.abs(pred - X[1:]))) if len(U) else 0.0
    b = problem.bounds
    finite = bool(np.all(np.isfinite(X)) and np.all(np.isfinite(U)))
    excess = max(b.violation(X, U)) if b is not None and finite else 0.0
    v_excess = b.velocity_violation(X) if b is not None and finite else 0.0
    t_excess = b.torque_violation(X, U) if b is not None and b.has_torques and finite else 0.0
    scale = max(1.0, float(np.max(np.abs(X))))
    t_scale = max(1.0, float(np.max(np.where(np.isfinite(b.tau_limit), b.tau_limit, 0.0)))) if t_excess else 1.0
    feasible = finite and defect <= 10 * tol * scale and excess <= 10 * tol and v_excess <= 10 * tol \
        and t_excess <= 10 * tol * t_scale
    cost = problem.cost(X, U) if finite else math.inf
    return Transcribed(X, U, cost, status, feasible, defect if finite else math.inf,
                       excess if finite else math.inf, solver, time_s, v_excess if finite else math.inf,
                       t_excess if finite else math.inf)


def key_format(problem: Problem) -> int:
    """The transcription's format for ``problem``'s cache key: :data:`FORMAT_TORQUES` where its bounds carry the
    torques of acceleration controls (transcribed since that format), else :data:`FORMAT` (what an earlier
    reference of it transcribed: still valid)."""
    b = problem.bounds
    return FORMAT_TORQUES if b is not None and b.has_torques else FORMAT


def cache_key(problem: Problem, warm_key: str, solver: str, max_iterations: int) -> str:
    """The name a reference is kept under: its warm start's plan key, ``solver``, ``max_iterations`` and a
    hash of what is transcribed (:func:`key_format`, the start, the horizon, the step and every array of the
    hard bounds), so a reference of other limits or another start is never reused."""
    import hashlib

    b = problem.bounds
    h = hashlib.sha256(f"{key_format(problem)} {problem.T} {problem.n_x} {problem.n_u} "
                       f"{getattr(problem.dynamics, 'dt', None)!r}".encode())
    h.update(np.ascontiguousarray(problem.x0, float).tobytes())
    for name in ("q_index", "q_lower", "q_upper", "v_index", "v_lower", "v_upper", "u_lower", "u_upper",
                 "tau_limit"):
        value = None if b is None else getattr(b, name)
        h.update(name.encode() + (b"-" if value is None else np.ascontiguousarray(value, float).tobytes()))
    return f"{warm_key}-{solver}-{int(max_iterations)}-{h.hexdigest()[:12]}"
