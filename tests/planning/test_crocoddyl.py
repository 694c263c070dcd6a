"""The crocoddyl baseline builds raico's problems exactly: same rollouts, same costs.

Skipped with a stated reason where crocoddyl is not installed (the extra
``raico[baseline]``, which ``make install`` and so ``make test`` install; ``tests/test_install.py``
fails when it is missing).
"""

from __future__ import annotations

import numpy as np
import pytest

from raico.planning import crocoddyl as cm
from raico.plants.robots import shared_robot
from tests.tolerance import close

pytestmark = pytest.mark.skipif(not cm.AVAILABLE, reason=f"crocoddyl baseline: {cm.UNAVAILABLE_REASON}")


def _problem(plant: str, task: str, dynamics: str = "analytic", seed: int = 0):
    from raico.stages.plan.stage import PlanConfig, build_problem

    return build_problem(PlanConfig(plant=plant, task=task, dynamics=dynamics, seed=seed))[2]


CASES = [("arm5", "reach"), ("arm5", "reach-roll"), ("pendulum", "swing-up")]


@pytest.fixture(scope="module")
def built():
    out = {}
    for plant, task in CASES:
        p = _problem(plant, task)
        out[(plant, task)] = (p, cm.build(p))
    return out


def _trajectories(problem):
    """Zero-torque rollout, a random-torque rollout (control limits violated on the pendulum)
    and the infeasible 'x0 held' trajectory with random controls."""
    from raico.plants.dynamics import rollout

    rng = np.random.default_rng(3)
    T, m = problem.T, problem.n_u
    out = []
    for scale in (0.0, 4.0):
        U = scale * rng.standard_normal((T, m))
        if problem.n_u == 1:
            U = U * 5.0  # beyond the pendulum's +-10 N m
        out.append((rollout(problem.dynamics, problem.x0, U), U))
    out.append((np.tile(problem.x0, (T + 1, 1)), rng.standard_normal((T, m))))
    return out


@pytest.mark.numerics
@pytest.mark.parametrize("case", CASES, ids=lambda c: "-".join(c))
def test_rollouts_agree_with_raicos_analytic_model(built, case):
    problem, cp = built[case]
    for X, U in _trajectories(problem)[:2]:
        Xc = cp.rollout(U)
        assert np.max(np.abs(Xc - X)) <= 1e-9 * max(1.0, np.max(np.abs(X)))


@pytest.mark.numerics
@pytest.mark.parametrize("case", CASES, ids=lambda c: "-".join(c))
def test_costs_of_the_same_trajectory_agree(built, case):
    problem, cp = built[case]
    for X, U in _trajectories(problem):
        c = problem.cost(X, U)
        assert c > 0
        assert abs(cp.cost(X, U) - c) <= 1e-9 * c


@pytest.mark.numerics
@pytest.mark.parametrize("case", [("arm5", "reach"), ("pendulum", "swing-up")], ids=lambda c: "-".join(c))
def test_dynamics_derivatives_agree_with_raicos_linearization(built, case):
    """crocoddyl's Fx, Fu of a running node equal raico's A, B (the pendulum: through the damped
    actuation model)."""
    problem, cp = built[case]
    rng = np.random.default_rng(1)
    n = problem.n_u
    x = problem.x0 + np.concatenate([0.3 * rng.standard_normal(n), rng.standard_normal(n)])
    u = rng.standard_normal(n)
    model = cp.shooting.runningModels[0]
    d = model.createData()
    model.calc(d, x, u)
    model.calcDiff(d, x, u)
    A, _, B = problem.dynamics.linearize(x, u)
    assert np.allclose(np.reshape(d.Fx, A.shape), A, rtol=1e-9, atol=1e-9)
    assert close(np.reshape(d.Fu, B.shape), B)


@pytest.mark.numerics
def test_control_limit_term_is_active_in_the_compared_pendulum_trajectory(built):
    problem, _ = built[("pendulum", "swing-up")]
    X, U = _trajectories(problem)[1]
    assert problem.cost_terms(X, U)["control_limit"] > 1.0


@pytest.mark.numerics
def test_roll_residual_gradient_and_gauss_newton_hessian_match_raico(built):
    """At the via-point nodes (a running node at T/2, the terminal node) crocoddyl's cost
    derivatives equal raico's ``l_x`` and Gauss-Newton ``l_xx`` (running: dt * 2w/dt = w...)."""
    problem, cp = built[("arm5", "reach-roll")]
    rng = np.random.default_rng(0)
    x = problem.x0 + np.concatenate([0.3 * rng.standard_normal(5), rng.standard_normal(5)])
    u = rng.standard_normal(5)
    sp = cp.shooting
    for t in (problem.T // 2, problem.T):
        model = sp.runningModels[t] if t < problem.T else sp.terminalModel
        d = model.createData()
        if t < problem.T:
            model.calc(d, x, u)
            model.calcDiff(d, x, u)
        else:
            model.calc(d, x)
            model.calcDiff(d, x)
        lx, lxx = problem.point_state_derivatives(x, t)
        assert np.allclose(d.Lx, lx, rtol=1e-9, atol=1e-9 * np.abs(lx).max())
        assert np.allclose(d.Lxx, lxx, rtol=1e-9, atol=1e-9 * np.abs(lxx).max())


def test_what_crocoddyl_cannot_express_is_refused_with_the_reason():
    with pytest.raises(cm.NotExpressible, match="pseudo-dynamics"):
        cm.build(_problem("arm5", "reach", "pseudo"))
    with pytest.raises(cm.NotExpressible, match="welded on 'l_sole'"):
        cm.pinocchio_robot(shared_robot("nao"))


@pytest.mark.numerics
def test_fddp_returns_a_raico_result_whose_controller_reproduces_its_trajectory(built):
    from raico.planning.problem import controller_rollout
    from raico.planning.solvers import solve

    problem, _ = built[("arm5", "reach")]
    for name in ("fddp", "fddp-rollout"):
        r = solve(problem, name, {"iterations": 3})
        assert r.solver == name and r.iterations == 3 and r.status == "max-iterations"
        assert r.X.shape == (problem.T + 1, 10) and r.O.shape == (problem.T, 5, 10)
        X, U = controller_rollout(problem.dynamics, problem.x0, r.o, r.O)
        assert np.array_equal(X, r.X)
        el = [h.elapsed_s for h in r.history]
        assert all(b > a for a, b in zip(el, el[1:]))
        assert np.isclose(el[-1], sum(h.time_s for h in r.history))
        assert np.isclose(r.initial_cost, problem.cost(*_trajectories(problem)[0]), rtol=1e-9)
    # from the rollout start every iterate is feasible: its cost is the rollout's, and decreases
    assert np.all(np.diff(r.costs) < 0)
    assert np.isclose(r.costs[-1], problem.cost(r.X, r.U), rtol=1e-9)


def test_options_are_strict():
    from raico.planning.solvers import make_options

    with pytest.raises(ValueError, match="unknown FDDPOptions option"):
        make_options("fddp", {"alpha": 1.0})
    with pytest.raises(ValueError, match="starts from 'held'"):
        make_options("fddp", {"start": "rollout"})
    assert make_options("fddp-rollout", {}).start == "rollout"


def test_plan_stage_refuses_fddp_on_pseudo_dynamics_in_one_line():
    from raico.stages.plan.stage import PlanConfig, plan

    with pytest.raises(ValueError, match=r"^solver fddp: crocoddyl cannot express the pseudo-dynamics exactly"):
        plan(PlanConfig(plant="arm5", task="reach", dynamics="pseudo", solver="fddp", iterations=2))


@pytest.mark.numerics
def test_an_fddp_run_stopped_by_its_regularization_limit_says_so():
    """crocoddyl's FDDP also stops when no step is accepted and its regularization reaches reg_max
    (fig3.2d's roll task from the rollout start, seed 5: 23 of 100 iterations); the message says why."""
    from raico.planning.solvers import solve

    r = solve(_problem("arm5", "reach-roll", seed=5), "fddp-rollout", {"iterations": 100})
    assert r.status == "max-iterations" and r.iterations < 100
    assert f"stopped after {r.iterations} of 100 iterations: its regularization reached reg_max" in r.message
