"""The direct-transcription reference (raico/pipeline/experiments/transcription.py) on a bounded LQ problem whose feasible
optimum an exact convex QP gives (Clarabel, an interior-point QP solver, through Drake), from a guess that is
neither feasible nor optimal; and its refusals."""

from __future__ import annotations

import numpy as np
import pytest

from raico.pipeline.experiments.transcription import cache_key, judge, refusal, solve
from raico.planning.problem import Bounds, Problem
from tests.planning.test_solvers_lq import make_lq

T = 12


def bounded_lq() -> Problem:
    """A random LQ problem (4 states, 2 controls, T = 12) with the first two state coordinates and both
    controls boxed tighter than the unconstrained optimum goes (checked in the test)."""
    pb = make_lq(seed=3, T=T)
    b = Bounds(u_lower=np.full(2, -0.6), u_upper=np.full(2, 0.6), q_index=np.array([0, 1]),
               q_lower=np.array([-1.0, -0.8]), q_upper=np.array([1.0, 0.8]))
    pb.x0 = np.clip(pb.x0, -0.5, 0.5)
    return Problem(pb.dynamics, pb.x0, pb.T, pb.state_terms, pb.control_terms, bounds=b)


def exact_qp(pb: Problem, bounded: bool = True) -> tuple[np.ndarray, np.ndarray, float]:
    """The QP's optimum ``X, U`` and cost: the terms' exact quadratic forms (``1/2 z^T R z - r^T z`` plus
    the constant that makes them the cost), the affine dynamics, the bounds from step 1, by Clarabel."""
    from pydrake.solvers import ClarabelSolver, MathematicalProgram

    n, m, dyn = pb.n_x, pb.n_u, pb.dynamics
    prog = MathematicalProgram()
    X = prog.NewContinuousVariables(T + 1, n)
    U = prog.NewContinuousVariables(T, m)
    R, r = pb.quadratize_states(np.zeros((T + 1, n)))
    H, h = pb.quadratize_controls(np.zeros((T, m)))
    for t in range(T + 1):
        prog.AddQuadraticCost(R[t], -r[t], X[t], is_convex=True)
    for t in range(T):
        prog.AddQuadraticCost(H[t], -h[t], U[t], is_convex=True)
        prog.AddLinearEqualityConstraint(np.hstack([dyn.A, dyn.B, -np.eye(n)]), -dyn.a,
                                         np.concatenate([X[t], U[t], X[t + 1]]))
    prog.AddBoundingBoxConstraint(pb.x0, pb.x0, X[0])
    b = pb.bounds
    if bounded:
        for t in range(1, T + 1):
            prog.AddBoundingBoxConstraint(b.q_lower, b.q_upper, X[t, b.q_index])
        for t in range(T):
            prog.AddBoundingBoxConstraint(b.u_lower, b.u_upper, U[t])
        if b.has_velocities:
            for t in range(1, T + 1):
                prog.AddBoundingBoxConstraint(b.v_lower, b.v_upper, X[t, b.v_index])
    res = ClarabelSolver().Solve(prog)
    assert res.is_success()
    Xs, Us = res.GetSolution(X), res.GetSolution(U)
    return Xs, Us, pb.cost(Xs, Us)


@pytest.mark.parametrize("solver", ["snopt", "ipopt"])
def test_reference_reaches_the_bounded_qp_optimum(solver):
    pb = bounded_lq()
    X_qp, U_qp, c_qp = exact_qp(pb)
    _, _, c_free = exact_qp(pb, bounded=False)
    assert c_qp > c_free * (1 + 1e-3)          # the bounds are active: the feasible optimum costs more
    U0 = np.zeros((T, pb.n_u))                  # guess: the zero controls, the states held at the start
    X0 = np.repeat(pb.x0[None, :], T + 1, axis=0)
    out = solve(pb, X0, U0, solver=solver)
    assert out.feasible, (out.status, out.defect, out.bound_excess)
    # both solvers stop at a KKT point to their tolerances (1e-6 optimality, quasi-Newton): the strictly
    # convex QP's optimum is unique, the cost within 1e-5 relative and the plan within 1e-3
    assert out.cost == pytest.approx(c_qp, rel=1e-5)
    np.testing.assert_allclose(out.U, U_qp, atol=1e-3)
    np.testing.assert_allclose(out.X, X_qp, atol=1e-3)


def test_judge_measures_defect_and_bounds():
    pb = bounded_lq()
    X_qp, U_qp, _ = exact_qp(pb)
    assert judge(pb, X_qp, U_qp, "x", "qp", 0.0).feasible
    bad = U_qp.copy()
    bad[3, 0] = 0.7                              # 0.1 over the controls' box; the states no longer follow
    out = judge(pb, X_qp, bad, "x", "qp", 0.0)
    assert not out.feasible and out.bound_excess == pytest.approx(0.1) and out.defect > 1e-3


def test_refusals():
    pb = bounded_lq()
    assert refusal(pb) == ""
    assert "joints" in refusal(pb, max_joints=1)
    assert "T = 12" in refusal(pb, max_steps=10)
    outside = Problem(pb.dynamics, np.r_[1.2, pb.x0[1:]], pb.T, pb.state_terms, pb.control_terms, bounds=pb.bounds)
    assert "outside a joint range" in refusal(outside)


def velocity_bounded_lq(limit: float = 0.5) -> Problem:
    """:func:`bounded_lq` with its last two state coordinates taken as joint velocities, limited to
    ``+-limit`` (rad/s) from step 1."""
    import dataclasses

    pb = bounded_lq()
    b = dataclasses.replace(pb.bounds, v_index=np.array([2, 3]), v_lower=np.full(2, -limit),
                            v_upper=np.full(2, limit))
    return Problem(pb.dynamics, np.clip(pb.x0, -limit, limit), pb.T, pb.state_terms, pb.control_terms, bounds=b)


@pytest.mark.numerics
@pytest.mark.parametrize("solver", ["snopt", "ipopt"])
def test_reference_keeps_the_velocity_limits_at_the_qp_optimum(solver):
    pb = velocity_bounded_lq()
    X_qp, U_qp, c_qp = exact_qp(pb)
    X_free, U_free, _ = exact_qp(velocity_bounded_lq(limit=1e3))
    assert pb.bounds.velocity_violation(X_free) > 0.05   # without them the optimum goes faster: they bind
    U0 = np.zeros((T, pb.n_u))
    X0 = np.repeat(pb.x0[None, :], T + 1, axis=0)
    out = solve(pb, X0, U0, solver=solver)
    assert out.feasible, (out.status, out.defect, out.bound_excess, out.velocity_excess)
    assert out.velocity_excess <= 1e-5 and out.record()["velocity_excess"] == out.velocity_excess
    assert out.cost == pytest.approx(c_qp, rel=1e-5)   # as the QP test above: KKT tolerances 1e-6
    np.testing.assert_allclose(out.X, X_qp, atol=1e-3)


def test_judge_counts_a_velocity_limit():
    pb = velocity_bounded_lq()
    X_free, U_free, _ = exact_qp(velocity_bounded_lq(limit=1e3))
    out = judge(pb, X_free, U_free, "x", "qp", 0.0)
    assert not out.feasible and out.velocity_excess == pytest.approx(pb.bounds.velocity_violation(X_free))


def test_the_cache_key_changes_with_the_limits_and_the_start():
    pb, pv = bounded_lq(), velocity_bounded_lq()
    key = cache_key(pb, "k" * 16, "snopt", 300)
    assert key.startswith("k" * 16 + "-snopt-300-") and key == cache_key(bounded_lq(), "k" * 16, "snopt", 300)
    assert cache_key(pv, "k" * 16, "snopt", 300) != key
    none = Problem(pb.dynamics, pb.x0, pb.T, pb.state_terms, pb.control_terms)
    moved = Problem(pb.dynamics, pb.x0 + 0.1, pb.T, pb.state_terms, pb.control_terms, bounds=pb.bounds)
    assert len({key, cache_key(none, "k" * 16, "snopt", 300), cache_key(moved, "k" * 16, "snopt", 300),
                cache_key(pb, "k" * 16, "ipopt", 300), cache_key(pb, "k" * 16, "snopt", 100)}) == 5


class LinearTorques:
    """A torque model linear in ``(q, v, a)``: ``tau = M a + K q + D v + c`` (``M`` symmetric positive definite), so
    that bounded torques are linear constraints of the QP; ``qddot_derivatives`` as an analytic model's."""

    def __init__(self, rng: np.random.Generator, n: int = 2):
        L = rng.normal(size=(n, n))
        self.M = L @ L.T + n * np.eye(n)
        self.K, self.D, self.c = rng.normal(size=(n, n)), rng.normal(scale=0.3, size=(n, n)), rng.normal(size=n)

    def inverse_dynamics(self, q, v, a):
        return self.M @ a + self.K @ q + self.D @ v + self.c

    def qddot_derivatives(self, q, v, tau):
        Minv = np.linalg.inv(self.M)
        return Minv @ (tau - self.K @ q - self.D @ v - self.c), -Minv @ self.K, -Minv @ self.D, Minv


def torque_bounded_lq(limit: float | None = None) -> tuple[Problem, LinearTorques]:
    """:func:`bounded_lq`'s dynamics and costs with its controls taken as accelerations whose torques
    (:class:`LinearTorques`) joint 0 keeps within ``+-limit`` (joint 1 unlimited; None: no limit)."""
    pb = bounded_lq()
    model = LinearTorques(np.random.default_rng(5))
    lim = np.array([np.inf if limit is None else limit, np.inf])
    b = Bounds(tau_model=model, tau_limit=lim)
    return Problem(pb.dynamics, pb.x0, pb.T, pb.state_terms, pb.control_terms, bounds=b), model


def torque_qp(pb: Problem, model: LinearTorques) -> tuple[np.ndarray, np.ndarray, float]:
    """The QP's optimum with joint 0's torque ``M a + K q + D v + c`` within its limit at steps 0..T-1 (Clarabel)."""
    from pydrake.solvers import ClarabelSolver, MathematicalProgram

    n, m, dyn = pb.n_x, pb.n_u, pb.dynamics
    prog = MathematicalProgram()
    X, U = prog.NewContinuousVariables(T + 1, n), prog.NewContinuousVariables(T, m)
    R, r = pb.quadratize_states(np.zeros((T + 1, n)))
    H, h = pb.quadratize_controls(np.zeros((T, m)))
    for t in range(T + 1):
        prog.AddQuadraticCost(R[t], -r[t], X[t], is_convex=True)
    lim = pb.bounds.tau_limit[0]
    row = np.concatenate([model.K[0], model.D[0], model.M[0]])
    for t in range(T):
        prog.AddQuadraticCost(H[t], -h[t], U[t], is_convex=True)
        prog.AddLinearEqualityConstraint(np.hstack([dyn.A, dyn.B, -np.eye(n)]), -dyn.a,
                                         np.concatenate([X[t], U[t], X[t + 1]]))
        if np.isfinite(lim):
            prog.AddLinearConstraint(row[None, :], [-lim - model.c[0]], [lim - model.c[0]],
                                     np.concatenate([X[t], U[t]]))
    prog.AddBoundingBoxConstraint(pb.x0, pb.x0, X[0])
    res = ClarabelSolver().Solve(prog)
    assert res.is_success()
    Xs, Us = res.GetSolution(X), res.GetSolution(U)
    return Xs, Us, pb.cost(Xs, Us)


@pytest.mark.numerics
@pytest.mark.parametrize("solver", ["snopt", "ipopt"])
def test_reference_bounds_the_torques_of_acceleration_controls_at_the_qp_optimum(solver):
    """Accelerations as controls, the torques they ask for bounded (a linear torque model: the exact QP by
    Clarabel): the reference reaches the QP's optimum with joint 0's torque inside its limit, where the
    unbounded optimum asks for 1.5x it."""
    free, model = torque_bounded_lq()
    X_free, U_free, c_free = torque_qp(free, model)
    peak = float(np.abs([model.inverse_dynamics(x[:2], x[2:], u)[0] for x, u in zip(X_free[:-1], U_free)]).max())
    pb, _ = torque_bounded_lq(limit=peak / 1.5)
    X_qp, U_qp, c_qp = torque_qp(pb, model)
    assert c_qp > c_free * (1 + 1e-3) and pb.bounds.torque_violation(X_free, U_free) > 0.1 * peak
    out = solve(pb, np.repeat(pb.x0[None, :], T + 1, axis=0), np.zeros((T, pb.n_u)), solver=solver)
    assert out.feasible and out.torque_excess <= 1e-5, (out.status, out.defect, out.torque_excess)
    assert out.record()["torque_excess"] == out.torque_excess
    assert out.cost == pytest.approx(c_qp, rel=1e-5)   # as the QP tests above: KKT tolerances 1e-6
    np.testing.assert_allclose(out.X, X_qp, atol=1e-3)
    assert not judge(pb, X_free, U_free, "x", "qp", 0.0).feasible   # the unbounded optimum breaks the limit


def test_the_cache_key_changes_where_the_torques_of_accelerations_are_transcribed(monkeypatch):
    """A reference of a problem with torque-bounded accelerations, transcribed before they were bounded (format 2),
    is not reused; a problem without them keeps its key (its transcription is unchanged)."""
    from raico.pipeline.experiments import transcription

    pb, _ = torque_bounded_lq(limit=1.0)
    assert transcription.key_format(pb) == transcription.FORMAT_TORQUES
    assert transcription.key_format(bounded_lq()) == transcription.FORMAT
    key, plain = cache_key(pb, "k" * 16, "snopt", 300), cache_key(bounded_lq(), "k" * 16, "snopt", 300)
    monkeypatch.setattr(transcription, "key_format", lambda problem: transcription.FORMAT)
    assert cache_key(pb, "k" * 16, "snopt", 300) != key
    assert cache_key(bounded_lq(), "k" * 16, "snopt", 300) == plain
