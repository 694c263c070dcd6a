"""The entry point :func:`aico`: AICO (``alpha = 0``) or R-AICO (``alpha > 0``, thesis §3.5, Algorithm 1).

Algorithm 1: the dynamics and the task messages are linearized along the whole trajectory at once at
the start of an iteration, the sweeps (:class:`raico.planning.aico.sweeps.Sweeps`) give the controller, which
is rolled out on the true planning dynamics (``dynamics.step``) for the next trajectory and the reported
cost; a step rule (:mod:`raico.planning.aico.steps`) accepts it and sets the next regularization.

Speed without changing a number (beyond rounding): the sweeps redo only what a relinearization changes,
relinearizing a step evaluates only the terms that cost it, and the task maps evaluated for the cost of a
rollout are reused by the next iteration's linearization at that trajectory (``ViaPoint``'s memo).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from raico.planning.aico.bounds import cost_curvature, distance_constraints, hard_constraints, own_costs
from raico.planning.aico.options import AICOOptions
from raico.planning.aico.steps import AICOStep, RobustStep
from raico.planning.aico.sweeps import NumericalError, Sweeps, bounded_rollout
from raico.planning.aico.truncated import TruncatedSites, truncated_ranges
from raico.planning.costs import hard_inequalities
from raico.planning.driver import Iterate, Status, cost_change_within, drive
from raico.planning.problem import Bounds, Callback, Problem, Result, bounds_status, single_threaded_blas
from raico.plants.dynamics import rollout

DISTANCE_STATUS_TOL = 1e-3   # m: a plan closer than a hard collision term's margin by more is out-of-bounds


def aico(problem: Problem, options: AICOOptions | None = None, *,
         X_init: np.ndarray | None = None, U_init: np.ndarray | None = None,
         callback: Callback | None = None) -> Result:
    """Plan with AICO (``alpha = 0``) or R-AICO (``alpha > 0``).

    Args:
        problem: the planning problem (needs a positive-definite control cost).
        options: ``AICOOptions`` (defaults if ``None``).
        X_init: initial trajectory ``(T+1, n_x)`` to linearize at (default: ``x0`` at every
            step, thesis §3.4; if only ``U_init`` is given, its rollout).
        U_init: initial controls ``(T, n_u)`` (default zeros).
        callback: called after each iteration with ``(record, X, U)``.

    Returns:
        ``Result``; a run whose cost becomes non-finite or explodes, or whose messages
        fail numerically, ends with status ``"diverged"`` (no exception).
    """
    opts = options or AICOOptions()
    with single_threaded_blas():
        b = problem.bounds
        hard = hard_inequalities(problem.state_terms)   # kept as constraints: their penalty leaves the cost
        objective = dataclasses.replace(problem, state_terms=[t for t in problem.state_terms
                                                              if not any(t is h for h in hard)]) if hard else problem
        if b is None or not b.has_controls:
            res = _aico(objective, opts, X_init, U_init, callback, hard=hard)
            if opts.control_box == "boxddp" and b is not None and b.has_torques:
                res.message += " (control_box boxddp: the torques of acceleration controls are no box on them, " \
                               "kept by the augmented Lagrangian)"
        elif opts.control_box == "boxddp":   # the box inside the backward pass; every rollout clips into it
            res = _aico(objective, opts, X_init, U_init, callback, hard=hard, box=(b.u_lower, b.u_upper))
        else:   # the efforts are constraints of the iterations, unclipped; the plan's rollout clips them
            inner = dataclasses.replace(objective, bounds=dataclasses.replace(b, u_lower=None, u_upper=None))
            res = _aico(inner, opts, X_init, U_init, callback, efforts=b, hard=hard)
            if res.status is not Status.DIVERGED:
                X, U, o, O = bounded_rollout(problem, res.o, res.O)
                if np.all(np.isfinite(X)):   # else the unclipped plan stays, its status says out-of-bounds
                    res.X, res.U, res.o, res.O = X, U, o, O
                    if res.history:
                        res.history[-1] = dataclasses.replace(res.history[-1], cost=objective.cost(X, U))
        if b is not None:
            bounds_status(problem, res)
        if hard:
            distance_status(problem, hard, res)
        return res


def distance_status(problem: Problem, hard: list, res: Result) -> None:
    """Status ``out-of-bounds`` (and by how much) for a plan whose distances fall below a hard collision term's
    bound (its margin; from a start inside it, :class:`raico.planning.constraints.DistanceConstraint`'s) by more
    than ``DISTANCE_STATUS_TOL`` (m); a diverged plan keeps its status."""
    if res.status is Status.DIVERGED or not np.all(np.isfinite(res.X)):
        return
    for c in distance_constraints(problem, hard):
        G = c.values(res.X, res.U)
        t, p = np.unravel_index(int(np.argmax(G)), G.shape)
        if G[t, p] > DISTANCE_STATUS_TOL:
            a, b = (n.removeprefix("robot:") for n in c.term.taskmap.pairs[p])
            res.status = Status.OUT_OF_BOUNDS
            res.message = (f"the plan comes {1e3 * G[t, p]:.3g} mm inside the margin of '{c.name}' ({a} | {b} at "
                           f"step {t}) ({res.message})")
            return


def _aico(problem: Problem, opts: AICOOptions, X_init, U_init, callback, efforts: Bounds | None = None,
          hard: list | None = None, box: tuple[np.ndarray, np.ndarray] | None = None) -> Result:
    T, n_u = problem.T, problem.n_u
    U = np.zeros((T, n_u)) if U_init is None else np.array(U_init, dtype=float)
    if U.shape != (T, n_u):
        raise ValueError(f"U_init has shape {U.shape}, expected {(T, n_u)}")
    X0_roll = open_loop_rollout(problem, U)
    initial_cost = problem.cost(X0_roll, U)   # the problem's own sum (the compiled one rounds otherwise)
    if X_init is None:
        X = np.tile(problem.x0, (T + 1, 1)) if U_init is None else X0_roll
    else:
        X = np.array(X_init, dtype=float)
        if X.shape != (T + 1, problem.n_x) or not np.all(np.isfinite(X)):
            raise ValueError(f"X_init must be finite with shape {(T + 1, problem.n_x)}")
    check_control_cost(problem)
    start = Iterate(X, U, U.copy(), np.zeros((T, n_u, problem.n_x)))
    step: RobustStep | AICOStep
    al = hard_constraints(problem, X, U, efforts, hard)
    if opts.ranges == "ep":   # the ranges as truncated-Gaussian (EP) messages, the rest an augmented Lagrangian
        al = truncated_ranges(al, opts.ep_temperature, opts.ep_damping, opts.ep_temperature_min)
    if al is not None:
        callback, costs = own_costs(problem, al, callback)
    if opts.schedule == "robust":
        kappa = cost_curvature(problem, X, U)
        # one linearization per trial, at the current iterate (theta = inf): the step is then the minimizer of
        # the regularized model the acceptance test measures it against (a relinearization at the beliefs
        # inside the sweeps makes a step of other models, which that one often sees, rightly, raise the cost)
        sw = Sweeps(problem, dataclasses.replace(opts, theta=math.inf, process_noise=opts.process_noise / kappa,
                                                  start_variance=opts.start_variance / kappa))
        feasible = bool(np.all(np.isfinite(X0_roll))) and np.allclose(X, X0_roll, rtol=1e-12, atol=0.0)
        sw.al = al
        if isinstance(al, TruncatedSites):
            al.sweeps = sw
        start_merit = initial_cost + (al.value(X0_roll, U) if al is not None and feasible else 0.0)
        step = RobustStep(problem, sw, opts, kappa, start_merit if feasible else None)
    else:
        sw = Sweeps(problem, opts)
        sw.al = al
        if isinstance(al, TruncatedSites):
            al.sweeps = sw
        step = AICOStep(problem, sw, float(opts.alpha), opts.gamma, opts, initial_cost)
    sw.box = box
    test = cost_change_within
    if al is not None:     # no convergence outside the constraints
        def test(previous: float, cost: float, tol: float) -> bool:
            done = al.last_violation <= 1.0 and cost_change_within(previous, cost, tol)
            return done and (not isinstance(al, TruncatedSites) or al.anneal())   # EP: colder, until its floor
    out = drive(step, start, opts, initial_cost=initial_cost, callback=callback, test=test)
    if al is not None:     # the history reports the problem's own cost (the merit's constraint terms left out)
        out.history = [dataclasses.replace(h, cost=costs.get(h.iteration, h.cost)) for h in out.history]
        if isinstance(al, TruncatedSites):
            out.message += f" (ranges: {al.updates} EP updates, temperature {al.temperature:.3g})"
        elif any(y is not None for y in al.y):
            out.message += f" (constraints: {al.updates} multiplier updates, penalty {al.mu / al.mu0:.3g} x its start)"
    last = out.last_finite
    beliefs = None
    if out.status is not Status.DIVERGED:
        try:
            with np.errstate(all="ignore"):
                beliefs = sw.beliefs()
        except (NumericalError, ArithmeticError):
            beliefs = None
    return Result(X=last.X, U=last.U, o=last.o, O=last.O, status=out.status, history=out.history,
                  iterations=len(out.history), message=out.message, initial_cost=initial_cost,
                  beliefs=beliefs, solver="raico" if opts.alpha > 0 else "aico", X_initial=X0_roll)


def open_loop_rollout(problem: Problem, U: np.ndarray) -> np.ndarray:
    """States ``(T+1, n_x)`` of the controls ``U (T, n_u)`` from ``x0``: the numbers of
    :func:`raico.plants.dynamics.rollout`, the Python loop. On a compiled model (``FastAnalyticDynamics``) its
    controller rollout with zero feedback gives them up to the first state that is not finite (``u_t =
    U_t + 0`` exactly, the same step); the loop goes on from there (where ``0 x_t`` would be NaN), unless
    that state is all NaN: then so is every later one (semi-implicit Euler adds each coordinate's old value)."""
    from raico.plants.fast_analytic import FastAnalyticDynamics

    with np.errstate(all="ignore"):
        if not isinstance(problem.dynamics, FastAnalyticDynamics):
            return rollout(problem.dynamics, problem.x0, U)
        X, _ = problem.controller_rollout(U, np.zeros((problem.T, problem.n_u, problem.n_x)))
        bad = ~np.isfinite(X).all(axis=1)
        if bad.any():
            k = int(np.argmax(bad))     # rows 0..k are the loop's own (each stepped from a finite state)
            if np.isnan(X[k]).all():
                X[k + 1:] = np.nan
            else:
                X[k:] = rollout(problem.dynamics, X[k], U[k:])
        return X


def check_control_cost(problem: Problem) -> None:
    """AICO marginalizes the controls: their cost Hessian must be positive definite."""
    _, luu = problem.control_derivatives(np.zeros((1, problem.n_u)))
    if np.any(np.linalg.eigvalsh(luu[0]) <= 0):
        raise ValueError("AICO needs a positive-definite control cost (add a ControlCost "
                         "with weight > 0)")
