"""Hard bounds in AICO: the joint ranges, velocity and effort limits as an augmented Lagrangian
(:func:`hard_constraints`), and the cost's curvature, the unit of its penalty and of the robust
schedule's alpha (:func:`cost_curvature`)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from raico.planning.constraints import (
    AugmentedLagrangian,
    Constraint,
    ControlBox,
    DistanceConstraint,
    StateBox,
    TorqueBox,
)
from raico.planning.problem import RANGE_STATUS_TOL, Bounds, Callback, Problem

RANGE_TOL = 1e-4   # rad, rad/s: the constraints' target on a joint range's or velocity limit's violation
DISTANCE_TOL = 1e-4   # m: the collision constraints' target on a distance below its margin
AL_INNER_TOL = 1e-3   # the multipliers move where the merit fell by less than this (relative), or inside the limits
AL_MU0 = 100.0   # the augmented Lagrangian's first penalty, in units of the cost's curvature (cost_curvature)
AL_ENDGAME = 0.25   # the robust schedule's last quarter of its iteration budget puts feasibility first (endgame)


def in_endgame(it: int, iterations: int, al: AugmentedLagrangian, X: np.ndarray, U: np.ndarray) -> bool:
    """Whether iteration ``it`` (1-based) of a budget of ``iterations``, from the iterate ``X, U``, is in the
    augmented Lagrangian's endgame: in the budget's last ``AL_ENDGAME`` part (at least the last iteration) with
    the iterate beyond a limit by more than a plan's status allows (``RANGE_STATUS_TOL``, ten of the constraints'
    tolerances ``RANGE_TOL``). There the multipliers step after every accepted iteration and the penalty grows at
    once where the violation did not fall (:class:`raico.planning.constraints.AugmentedLagrangian`), so that the
    plan the budget ends on is not ``out-of-bounds``; an iterate within its status is left to the merit."""
    if it <= iterations - max(1, math.ceil(AL_ENDGAME * iterations)):
        return False
    return al.violation(X, U) > RANGE_STATUS_TOL / RANGE_TOL


def hard_constraints(problem: Problem, X: np.ndarray, U: np.ndarray, efforts: Bounds | None = None,
                     hard: list | None = None) -> AugmentedLagrangian | None:
    """The hard constraints of ``problem.bounds`` (joint ranges, from a start outside one as far as the velocity
    limits let it come back, :meth:`raico.planning.problem.Bounds.position_box`; joint velocity limits; for accelerations
    as controls the torques they ask for, :class:`raico.planning.constraints.TorqueBox`) and the effort
    limits of ``efforts`` as an augmented Lagrangian with the penalty ``AL_MU0 kappa`` (:func:`cost_curvature`
    at ``X, U``: invariant to the cost's scale; on the efforts ``AL_MU0`` times the control cost's mean
    curvature), or ``None`` (no constraint); ``hard``: the collision terms kept as constraints
    (:class:`raico.planning.constraints.DistanceConstraint`, their penalty not in ``problem``)."""
    b = problem.bounds
    has_u = efforts is not None and efforts.has_controls
    if not has_u and not hard and (b is None or not (b.has_positions or b.has_velocities or b.has_torques)):
        return None
    T, cons = problem.T, list[Constraint]()
    kappa = cost_curvature(problem, X, U)
    if b is not None and b.has_positions:
        dt = getattr(problem.dynamics, "dt", 1.0)
        lo, hi = b.position_box(problem.x0, float(dt) if isinstance(dt, (int, float)) and dt > 0 else 1.0, T)
        cons.append(StateBox("joint_range", b.q_index, lo, hi, RANGE_TOL))
    if b is not None and b.has_velocities:
        k = len(b.v_index)
        cons.append(StateBox("joint_velocity", b.v_index, np.broadcast_to(b.v_lower, (T + 1, k)),
                             np.broadcast_to(b.v_upper, (T + 1, k)), RANGE_TOL))
    cons.extend(distance_constraints(problem, hard or []))
    if b is not None and b.has_torques:   # accelerations as controls: the torques they ask for, in their limits
        box = TorqueBox("effort", b.tau_model, b.tau_limit, RANGE_TOL)
        # its penalty as the effort box's: the control cost's curvature, per acceleration that moves a row by
        # one (a joint's limit over its inertia at the start; the smallest of them), over kappa
        _, H = problem.control_derivatives(U)
        curv = float(np.trace(H, axis1=1, axis2=2).mean()) / problem.n_u   # per (rad/s^2)^2
        n = problem.n_u
        M = np.linalg.inv(b.tau_model.qddot_derivatives(problem.x0[:n], np.zeros(n), np.zeros(n))[3])
        acc = float(np.min(box.limit / np.maximum(np.abs(np.diag(M))[box.idx], 1e-12)))
        box.scale = curv * acc * acc / kappa
        cons.append(box)
    if has_u:
        idx = np.flatnonzero(np.isfinite(efforts.u_lower) | np.isfinite(efforts.u_upper))
        _, H = problem.control_derivatives(U)
        curv = float(np.trace(H, axis1=1, axis2=2).mean()) / problem.n_u   # per (control unit)^2
        scale = np.max(np.abs(np.where(np.isfinite(efforts.u_upper), efforts.u_upper, 0.0)), initial=1.0)
        cons.append(ControlBox("effort", idx, efforts.u_lower[idx], efforts.u_upper[idx],
                               np.full(len(idx), RANGE_TOL * scale), scale=curv / kappa))
    return AugmentedLagrangian(cons, T, AL_MU0 * kappa)


def distance_constraints(problem: Problem, hard: list) -> list[DistanceConstraint]:
    """The hard collision terms ``hard`` as constraints ``d >= margin`` from step 1, a start inside a margin
    given as long as the velocity limits of ``problem.bounds`` need to leave it (:class:`DistanceConstraint`)."""
    b, n_q = problem.bounds, problem.n_x // 2
    vmax = np.full(n_q, np.inf)
    if b is not None and b.has_velocities:
        vmax[np.asarray(b.v_index) - n_q] = np.maximum(np.abs(b.v_lower), np.abs(b.v_upper))
    dt = getattr(problem.dynamics, "dt", 1.0)
    dt = float(dt) if isinstance(dt, (int, float)) and dt > 0 else 1.0
    return [DistanceConstraint(t, n_q, problem.T, problem.x0[:n_q], dt, vmax, DISTANCE_TOL) for t in hard]


def own_costs(problem: Problem, al: AugmentedLagrangian, callback: Callback | None) -> tuple[Callback, dict[int, float]]:
    """A callback that records the problem's own cost of every iterate (the solver's is the merit) and passes
    it on to ``callback``, and the record it fills (iteration -> cost)."""
    costs: dict[int, float] = {}

    def cb(rec, X, U) -> None:  # noqa: ANN001
        extra = al.value(X, U)      # 0 where no constraint is active: the merit is the solver's own cost
        costs[rec.iteration] = c = rec.cost if extra == 0.0 else problem.cost(X, U)
        if callback is not None:
            callback(dataclasses.replace(rec, cost=c), X, U)
    return cb, costs


def cost_curvature(problem: Problem, X: np.ndarray, U: np.ndarray) -> float:
    """``kappa``: the mean diagonal of the state cost's Gauss-Newton Hessian along ``X (T+1, n)``
    (cost per (state unit)^2 and step), or of the control Hessian at ``U (T, m)`` if no state term
    costs anything; scales with the cost (the robust schedule's unit of alpha)."""
    problem.set_nominal(X, U)
    _, R = problem.state_derivatives(X)
    k = float(np.trace(R, axis1=1, axis2=2).mean()) / problem.n_x
    if not (math.isfinite(k) and k > 0):
        _, H = problem.control_derivatives(U)
        k = float(np.trace(H, axis1=1, axis2=2).mean()) / problem.n_u
    if not (math.isfinite(k) and k > 0):
        raise ValueError("the robust schedule needs a cost with positive curvature")
    return k
