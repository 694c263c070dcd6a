"""crocoddyl's side of underactuation: the cart-pole's motor on the cart only (an actuation model that selects
it), built exactly as raico's problem: same rollouts, costs and derivatives; FDDP's result in motor commands."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from raico.planning import crocoddyl as cm
from tests.tolerance import close

pytestmark = pytest.mark.skipif(not cm.AVAILABLE, reason=f"crocoddyl baseline: {cm.UNAVAILABLE_REASON}")

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """The shipped swing-up at 20 ms steps without substeps (crocoddyl steps its model once per node)."""
    from raico.stages.plan.stage import PlanConfig, build_problem

    text = (ROOT / "raico" / "problems" / "cartpole_swing-up.toml").read_text()
    text = text.replace("substeps = 10", "").replace("T = 40", "T = 60").replace("dt = 0.1", "dt = 0.02")
    path = tmp_path_factory.mktemp("cartpole") / "cartpole_fine.toml"
    path.write_text(text)
    problem = build_problem(PlanConfig(problem=str(path)))[2]
    return problem, cm.build(problem)


def test_rollouts_and_costs_agree(built):
    from raico.plants.dynamics import rollout

    problem, cp = built
    assert problem.n_u == 1 and cp.shooting.runningModels[0].nu == 1
    rng = np.random.default_rng(3)
    for scale in (0.0, 8.0):
        U = scale * rng.standard_normal((problem.T, 1))
        X = rollout(problem.dynamics, problem.x0, U)
        assert np.max(np.abs(cp.rollout(U) - X)) <= 1e-9 * max(1.0, np.max(np.abs(X)))
        c = problem.cost(X, U)
        assert abs(cp.cost(X, U) - c) <= 1e-9 * c


def test_dynamics_derivatives_agree(built):
    """crocoddyl's Fx, Fu (through the selecting, damped actuation) equal raico's A, B (n_x x 1)."""
    problem, cp = built
    x, u = np.array([0.2, 2.0, -0.5, 1.5]), np.array([4.0])
    model = cp.shooting.runningModels[0]
    d = model.createData()
    model.calc(d, x, u)
    model.calcDiff(d, x, u)
    A, _, B = problem.dynamics.linearize(x, u)
    assert np.allclose(np.reshape(d.Fx, A.shape), A, rtol=1e-9, atol=1e-9)
    assert B.shape == (4, 1) and close(np.reshape(d.Fu, B.shape), B)


def test_fddp_result_is_in_motor_commands(built):
    from raico.planning.problem import controller_rollout
    from raico.planning.solvers import solve

    problem, _ = built
    r = solve(problem, "fddp", {"iterations": 3})
    assert r.U.shape == (problem.T, 1) and r.O.shape == (problem.T, 1, 4)
    X, _ = controller_rollout(problem.dynamics, problem.x0, r.o, r.O)
    assert np.array_equal(X, r.X)
