"""A direct-transcription reference for small problems: the best feasible cost known from a start.

The problem ``min cost(X, U)`` over the states ``X (T+1, n)`` (``x_0`` the start) and controls ``U (T, m)``
subject to the planning dynamics ``x_{t+1} = f(x_t, u_t)`` as equality constraints and the hard bounds of
``problem.bounds`` (joint ranges per step as :meth:`raico.planning.problem.Bounds.position_box` gives them from the
start, velocity limits, effort limits) as boxes, solved by Drake's ``MathematicalProgram`` with IPOPT or
SNOPT: an independent solver of the same problem (no messages, no augmented Lagrangian), to measure how far a
plan's cost lies above the best feasible one. The cost's gradient is the problem's own (``l_x``, ``l_u``, exact
for its least-squares terms), the dynamics' Jacobians the model's ``linearize`` (checked against finite
differences in the tests); Python callbacks, one per step: for ``T n`` up to a few thousand.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from raico.planning.problem import Problem


@dataclass
class TranscriptionResult:
    """``X (T+1, n)``, ``U (T, m)``, the problem's cost of them, whether the solver reported success, its
    name and status line, the largest dynamics defect (state units) and the wall time (s)."""

    X: np.ndarray
    U: np.ndarray
    cost: float
    success: bool
    solver: str
    message: str
    defect: float
    seconds: float


def transcribe(problem: Problem, X_init: np.ndarray, U_init: np.ndarray, solver: str = "ipopt",
               max_iterations: int = 3000, tol: float = 1e-8) -> TranscriptionResult:
    """Solve ``problem`` by direct transcription from the guess ``X_init (T+1, n)``, ``U_init (T, m)`` with
    ``solver`` (``"ipopt"`` or ``"snopt"``)."""
    from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff
    from pydrake.solvers import IpoptSolver, MathematicalProgram, SnoptSolver, SolverOptions

    T, n, m = problem.T, problem.n_x, problem.n_u
    dyn = problem.dynamics
    prog = MathematicalProgram()
    Xv = prog.NewContinuousVariables(T, n, "x")     # x_1..x_T
    Uv = prog.NewContinuousVariables(T, m, "u")
    x0 = problem.x0

    def split(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.vstack([x0, z[:T * n].reshape(T, n)]), z[T * n:].reshape(T, m)

    def cost(z):
        ad = z.dtype == object
        v = ExtractValue(z).reshape(-1) if ad else z
        X, U = split(v)
        c = problem.cost(X, U)
        if not ad:
            return c
        problem.set_nominal(X, U)
        lx, _ = problem.state_derivatives(X)
        lu, _ = problem.control_derivatives(U)
        g = np.concatenate([lx[1:].reshape(-1), lu.reshape(-1)])
        return InitializeAutoDiff(np.array([c]), (g @ ExtractGradient(z))[None, :])[0, 0]

    prog.AddCost(cost, np.concatenate([Xv.reshape(-1), Uv.reshape(-1)]))

    def defect(t: int):
        def g(z):
            ad = z.dtype == object
            v = ExtractValue(z).reshape(-1) if ad else z
            x = x0 if t == 0 else v[:n]
            off = 0 if t == 0 else n
            u, x1 = v[off:off + m], v[off + m:off + m + n]
            r = x1 - dyn.step(x, u)
            if not ad:
                return r
            A, _, B = dyn.linearize(x, u)
            J = np.hstack(([] if t == 0 else [-A]) + [-B, np.eye(n)])
            return InitializeAutoDiff(r, J @ ExtractGradient(z))
        return g

    for t in range(T):
        vars_t = np.concatenate(([] if t == 0 else [Xv[t - 1]]) + [Uv[t], Xv[t]])
        prog.AddConstraint(defect(t), np.zeros(n), np.zeros(n), vars_t)
    b = problem.bounds
    if b is not None:
        if b.has_positions:
            dt = getattr(dyn, "dt", 1.0)
            lo, hi = b.position_box(x0, float(dt), T)
            for j, qi in enumerate(b.q_index):
                prog.AddBoundingBoxConstraint(lo[1:, j], hi[1:, j], Xv[:, qi])
        if b.has_velocities:
            for j, vi in enumerate(b.v_index):
                prog.AddBoundingBoxConstraint(np.full(T, b.v_lower[j]), np.full(T, b.v_upper[j]), Xv[:, vi])
        if b.has_controls:
            for j in range(m):
                if np.isfinite(b.u_lower[j]) or np.isfinite(b.u_upper[j]):
                    prog.AddBoundingBoxConstraint(np.full(T, b.u_lower[j]), np.full(T, b.u_upper[j]), Uv[:, j])
    guess = np.concatenate([np.asarray(X_init, float)[1:].reshape(-1), np.asarray(U_init, float).reshape(-1)])
    opts = SolverOptions()
    if solver == "ipopt":
        s = IpoptSolver()
        opts.SetOption(s.solver_id(), "max_iter", max_iterations)
        opts.SetOption(s.solver_id(), "tol", tol)
        opts.SetOption(s.solver_id(), "print_level", 0)
    elif solver == "snopt":
        s = SnoptSolver()
        opts.SetOption(s.solver_id(), "Major iterations limit", max_iterations)
        opts.SetOption(s.solver_id(), "Major optimality tolerance", tol)
        opts.SetOption(s.solver_id(), "Iterations limit", 100 * max_iterations)
    else:
        raise ValueError(f"solver must be ipopt or snopt, got {solver!r}")
    t0 = time.perf_counter()
    res = s.Solve(prog, guess, opts)
    seconds = time.perf_counter() - t0
    X, U = split(res.GetSolution(np.concatenate([Xv.reshape(-1), Uv.reshape(-1)])))
    gap = max((float(np.abs(X[t + 1] - dyn.step(X[t], U[t])).max()) for t in range(T)), default=0.0)
    c = problem.cost(X, U)
    return TranscriptionResult(X, U, c if math.isfinite(c) else math.inf, bool(res.is_success()), solver,
                               str(res.get_solution_result()), gap, seconds)
