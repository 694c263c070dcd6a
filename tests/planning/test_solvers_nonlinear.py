"""Solvers on a nonlinear problem, faults, and options.

Plant: a 3-link planar arm under the thesis's pseudo-dynamics (controls are joint
accelerations) with an end-effector via-point at mid-horizon and a return to the start
pose at the end (the thesis's reaching task, in the plane).
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from raico.planning.aico import AICOOptions, aico
from raico.planning.costs import ControlCost, ControlLimit, ViaPoint
from raico.planning.ilqg import ILQGOptions, ilqg
from raico.planning.problem import Problem
from raico.planning.solvers import SOLVERS, make_options, solve
from raico.plants.dynamics import PseudoDynamics
from tests.toys import PlanarArm

pytestmark = pytest.mark.compiled   # reaches a C kernel: run under the sanitizers too

T, DT, N_Q = 100, 0.02, 3




def make_arm_problem(dynamics=None, control_terms=None, taskmap=None) -> Problem:
    arm = taskmap or PlanarArm([0.5, 0.5, 0.5])
    x0 = np.zeros(2 * N_Q)
    x0[:N_Q] = [0.3, 0.4, 0.2]
    home = PlanarArm([0.5, 0.5, 0.5]).value_and_jacobian(x0[:N_Q])[0]
    terms = [ViaPoint(arm, [0.2, 1.2], [T // 2], weight=1e4, name="via"),
             ViaPoint(arm, home, [T], weight=1e4, name="home")]
    return Problem(dynamics or PseudoDynamics(N_Q, DT), x0, T, terms,
                   control_terms if control_terms is not None else [ControlCost(1e-2)])


@pytest.fixture(scope="module")
def arm_problem():
    return make_arm_problem()


@pytest.fixture(scope="module")
def ilqg_optimum(arm_problem):
    res = ilqg(arm_problem)
    assert res.status == "converged", res.message
    return res.cost


@pytest.mark.numerics
def test_first_step_shrinks_as_alpha_grows(arm_problem):
    X0 = np.tile(arm_problem.x0, (T + 1, 1))
    steps = [np.linalg.norm(aico(arm_problem, AICOOptions(iterations=1, alpha=a)).X - X0)
             for a in (0.0, 1.0, 10.0)]
    assert steps[0] > steps[1] > steps[2] > 0, steps


@pytest.mark.numerics
def test_raico_reduces_cost_below_5_percent_of_first_iteration(arm_problem, ilqg_optimum):
    res = aico(arm_problem, AICOOptions(iterations=60, alpha=10.0, gamma=1.0))
    costs = res.costs
    # alpha = 10 still moves at the end: the last relative change is far above tol_rel = 1e-9,
    # so the run uses its whole budget
    assert abs(costs[-1] - costs[-2]) > 1e3 * AICOOptions().tol_rel * abs(costs[-2])
    assert (res.status, res.iterations, res.message) == ("max-iterations", 60, "reached 60 iterations")
    assert costs[-1] < 0.05 * costs[0], costs
    assert costs[-1] < 1.2 * ilqg_optimum
    assert [h.step for h in res.history] == [10.0] * res.iterations
    # the reported cost is the cost of the returned (rolled-out) trajectory
    assert arm_problem.cost(res.X, res.U) == pytest.approx(costs[-1])


@pytest.mark.numerics
def test_raico_reaches_the_ilqg_optimum(arm_problem, ilqg_optimum):
    res = aico(arm_problem, AICOOptions(iterations=60, alpha=1.0))
    assert res.costs[-1] == pytest.approx(ilqg_optimum, rel=1e-3)
    via = arm_problem.term("via")
    phi = via.taskmap.value_and_jacobian(res.X[T // 2, :N_Q])[0]
    assert np.linalg.norm(phi - via.target) < 0.02                # metres
    # the controller is a feedback law: u_t = o_t + O_t x_t along the trajectory
    U = res.o + np.einsum("tij,tj->ti", res.O, res.X[:-1])
    assert np.allclose(U, res.U)


@pytest.mark.numerics
def test_alpha_schedule_and_warm_start(arm_problem):
    res = solve(arm_problem, "raico", {"iterations": 3, "alpha": 2.0, "gamma": 3.0})
    assert [h.step for h in res.history] == pytest.approx([2.0, 6.0, 18.0])
    assert res.solver == "raico" and res.iterations == 3
    warm = aico(arm_problem, AICOOptions(iterations=1, alpha=1.0), X_init=res.X, U_init=res.U)
    cold = aico(arm_problem, AICOOptions(iterations=1, alpha=1.0))
    assert warm.costs[0] < cold.costs[0]


@pytest.mark.numerics
def test_control_limits_are_respected_as_an_objective():
    limit = 2.0
    free = aico(make_arm_problem(), AICOOptions(iterations=15, alpha=1.0))
    assert np.abs(free.U).max() > 1.3 * limit                      # the limit is active
    pb = make_arm_problem(control_terms=[ControlCost(1e-2),
                                         ControlLimit(-limit, limit, weight=1e4)])
    raico_res = aico(pb, AICOOptions(iterations=15, alpha=1.0))
    ilqg_res = ilqg(pb)
    assert (raico_res.status, raico_res.iterations) == ("max-iterations", 15), raico_res.message
    assert ilqg_res.status == "converged", ilqg_res.message
    for res in (raico_res, ilqg_res):
        assert np.abs(res.U).max() < 1.05 * limit, res.solver
        # the limit term's share of the cost is what its hinge gives on the returned controls
        excess = np.maximum(np.abs(res.U) - limit, 0.0)
        assert pb.cost_terms(res.X, res.U)["control_limit"] == pytest.approx(1e4 * np.sum(excess ** 2))


# -- faults: a diverging run is a result, never an exception --------------------------------
class NaNDynamics(PseudoDynamics):
    """Linearizes like the pseudo-dynamics but its step returns NaN."""

    def step(self, x, u):
        return np.full(self.n_x, np.nan)


class MismatchedDynamics(PseudoDynamics):
    """Linearizes like the pseudo-dynamics but the true controls act 50 times stronger: the
    planned feedback makes the true closed loop explode (finite, astronomically large cost)."""

    def step(self, x, u):
        return super().step(x, 50.0 * u)


class NaNTaskMap(PlanarArm):
    def values_and_jacobians(self, Q):
        phi, J = super().values_and_jacobians(Q)
        return phi, J * np.nan


_NAN_COST = "iteration 1: cost inf not finite or above 1e+06 x initial cost inf"
DIVERGED_MESSAGES = {
    ("aico", "nan-step"): _NAN_COST,
    ("raico", "nan-step"): _NAN_COST,
    ("ilqg", "nan-step"): "initial rollout is not finite",
    ("aico", "nan-jacobian"): "iteration 1: NumericalError: non-finite linearization or task message",
    ("raico", "nan-jacobian"): "iteration 1: NumericalError: non-finite linearization or task message",
    ("ilqg", "nan-jacobian"): "iteration 1: FloatingPointError: non-finite derivatives",
}


@pytest.mark.numerics
@pytest.mark.parametrize("solver", ["aico", "raico", "ilqg"])
@pytest.mark.parametrize("case, make", [
    ("nan-step", lambda: make_arm_problem(dynamics=NaNDynamics(N_Q, DT))),
    ("nan-jacobian", lambda: make_arm_problem(taskmap=NaNTaskMap([0.5, 0.5, 0.5]))),
], ids=["nan-step", "nan-jacobian"])
def test_diverging_run_ends_with_status_diverged(solver, case, make):
    res = solve(make(), solver, {"iterations": 5})
    assert res.status == "diverged", (res.status, res.message)
    assert res.message == DIVERGED_MESSAGES[solver, case]
    assert len(res.history) == 1 and res.history[0].cost == np.inf
    assert res.X.shape == (T + 1, 2 * N_Q) and res.U.shape == (T, N_Q)
    assert res.O.shape == (T, N_Q, 2 * N_Q)


@pytest.mark.numerics
@pytest.mark.parametrize("solver", ["aico", "raico"])
def test_exploding_cost_ends_with_status_diverged(solver):
    pb = make_arm_problem(dynamics=MismatchedDynamics(N_Q, DT))
    res = solve(pb, solver, {"iterations": 5})
    assert res.status == "diverged", res.message
    assert len(res.history) == 1
    assert np.isfinite(res.history[0].cost)                     # finite, but exploded
    assert res.history[0].cost > 1e6 * res.initial_cost
    assert np.all(np.isfinite(res.X))                           # last good trajectory


class FailingLaterDynamics(PseudoDynamics):
    """The pseudo-dynamics until ``limit`` steps have been taken, NaN after: AICO's initial rollout
    and first ``k`` iterations' rollouts run, iteration ``k + 1`` diverges."""

    def __init__(self, n_q, dt, limit):
        super().__init__(n_q, dt)
        self.limit, self.calls = limit, 0

    def step(self, x, u):
        self.calls += 1
        return super().step(x, u) if self.calls <= self.limit else np.full(self.n_x, np.nan)


@pytest.mark.numerics
def test_iterates_of_a_diverging_run_are_finite_up_to_the_divergence():
    pb = make_arm_problem(dynamics=FailingLaterDynamics(N_Q, DT, limit=3 * T))
    res = solve(pb, "raico", {"iterations": 5})
    assert res.status == "diverged" and len(res.history) == 3, res.message
    Xi, steps = res.X_iterations, res.t_iterations
    assert Xi.shape == (4, len(steps), 2 * N_Q) and steps[0] == 0 and steps[-1] == T and T // 2 in steps
    assert np.all(np.isfinite(Xi[:3])) and np.all(np.isnan(Xi[3]))   # iteration 3 diverged: NaN
    np.testing.assert_allclose(Xi[2], res.X[steps], rtol=1e-6, atol=1e-6)  # the last finite iterate


@pytest.mark.numerics
def test_ilqg_stalls_instead_of_diverging_on_a_mismatched_model():
    pb = make_arm_problem(dynamics=MismatchedDynamics(N_Q, DT))
    res = ilqg(pb, ILQGOptions(iterations=100))
    assert res.status == "max-iterations" and "mu_max" in res.message
    assert res.cost == pytest.approx(res.initial_cost)          # no step was ever accepted
    assert [h.step for h in res.history] == [0.0] * len(res.history)
    # the stop is the one the message names: mu passed mu_max = 1e10 at the last iteration
    mus = [h.mu for h in res.history]
    assert mus[-1] > 1e10 >= mus[-2] and mus == sorted(mus), mus


# -- options ---------------------------------------------------------------------------
@pytest.mark.parametrize("cls", [AICOOptions, ILQGOptions])
def test_options_reject_unknown_keys(cls):
    with pytest.raises(ValueError, match="bogus") as err:
        cls.from_dict({"iterations": 3, "bogus": 1})
    assert "iterations" in str(err.value)                          # names the valid ones
    opts = cls.from_dict({"iterations": 3})
    assert opts.iterations == 3
    with pytest.raises(dataclasses.FrozenInstanceError, match="cannot assign to field 'iterations'"):
        opts.iterations = 4


@pytest.mark.parametrize("cls, bad, message", [
    (AICOOptions, {"alpha": -1.0}, "option alpha must be >= 0.0, got -1.0"),
    (AICOOptions, {"gamma": 0.0}, "option gamma must be > 0.0, got 0.0"),
    (AICOOptions, {"iterations": 0}, "option iterations must be >= 1, got 0"),
    (AICOOptions, {"iterations": 2.5}, "option iterations must be an integer, got 2.5"),
    (AICOOptions, {"process_noise": 0.0}, "option process_noise must be > 0.0, got 0.0"),
    (AICOOptions, {"belief_rate": 1.5}, "option belief_rate must be <= 1.0, got 1.5"),
    (AICOOptions, {"theta": -0.1}, "option theta must be > 0.0, got -0.1"),
    (AICOOptions, {"max_repeats": -1}, "option max_repeats must be >= 0, got -1"),
    (AICOOptions, {"alpha": float("nan")}, "option alpha must not be NaN"),
    (AICOOptions, {"alpha": float("inf")}, "options alpha and gamma must be finite"),
    (ILQGOptions, {"delta0": 1.0}, "option delta0 must be > 1.0, got 1.0"),
    (ILQGOptions, {"mu0": -1.0}, "option mu0 must be >= 0.0, got -1.0"),
    (ILQGOptions, {"step_sizes": [2.0]}, "option step_sizes must be a non-empty list in (0, 1], got (2.0,)"),
    (ILQGOptions, {"step_sizes": []}, "option step_sizes must be a non-empty list in (0, 1], got ()"),
    (ILQGOptions, {"mu_max": 1e-9}, "option mu_max must be > 1e-06, got 1e-09"),
    (ILQGOptions, {"tol_rel": -1.0}, "option tol_rel must be >= 0.0, got -1.0"),
])
def test_options_validate_ranges(cls, bad, message):
    with pytest.raises(ValueError, match=f"^{re.escape(message)}$"):
        cls.from_dict(bad)


def test_solver_registry(arm_problem):
    from raico.planning.crocoddyl import AVAILABLE  # the crocoddyl baseline registers where installed

    baseline = {"fddp", "fddp-rollout", "fddp-rollout-accept-any", "fddp-rollout-ilqg-schedule",
                "boxfddp"} if AVAILABLE else set()
    assert set(SOLVERS) == {"aico", "raico", "ilqg"} | baseline
    assert make_options("raico").alpha == 1.0 and make_options("aico").alpha == 0.0
    assert make_options("ilqg", {"mu0": 0.5}).mu0 == 0.5
    assert make_options("ilqg").step_sizes == pytest.approx(tuple(10 ** np.linspace(0, -3, 11)))
    with pytest.raises(ValueError, match="unknown solver"):
        solve(arm_problem, "ddp", {})
    with pytest.raises(ValueError, match="bogus"):
        solve(arm_problem, "raico", {"bogus": 1})
    with pytest.raises(ValueError, match="raico"):
        solve(arm_problem, "aico", {"alpha": 1.0})
    with pytest.raises(ValueError, match="aico"):
        solve(arm_problem, "raico", {"alpha": 0.0})
    with pytest.raises(TypeError, match="ILQGOptions"):
        solve(arm_problem, "aico", ILQGOptions())
    res = solve(arm_problem, "ilqg", {"iterations": 2})
    assert res.solver == "ilqg" and res.iterations == 2 and res.status == "max-iterations"
    assert all(h.time_s >= 0 and h.elapsed_s >= h.time_s for h in res.history)


def test_aico_needs_a_control_cost():
    with pytest.raises(ValueError, match="control cost"):
        aico(make_arm_problem(control_terms=[]), AICOOptions(iterations=1))
