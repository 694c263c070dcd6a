"""Under receding-horizon control an execution's tracking is judged against the controller's own
predictions, not against the plan it may leave on purpose."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from raico.stages.evaluate.metrics import TRACKING_LOST, execution_metrics
from raico.stages.execute.fixed import mpc_aim
from raico.stages.plan.stage import PlanConfig, build_problem


@pytest.fixture(scope="module")
def arm5():
    robot, _, problem, _, _ = build_problem(PlanConfig(plant="arm5", task="reach"))
    return robot, problem


def _run(problem, robot, X, X_plan, X_track=None) -> dict:
    T = len(X) - 1
    n = robot.n_q
    return execution_metrics(problem, X, X_plan, np.zeros((T, n)), robot, 0.01, np.zeros((T, n), bool),
                             X_track=X_track)


def test_mpc_aim_takes_each_steps_first_tick_prediction() -> None:
    """``every`` ticks per planning step: sample k is the second state of the first tick of step k-1."""
    ticks, H, n_x, every = 6, 4, 2, 2
    pred = np.arange(ticks * (H + 1) * n_x, dtype=np.float32).reshape(ticks, H + 1, n_x)
    mpc = SimpleNamespace(log=SimpleNamespace(predicted=pred, n=5))    # the run stopped after 5 ticks
    X_plan = np.full((5, n_x), -1.0)
    aim = mpc_aim(mpc, X_plan, every)
    assert np.array_equal(aim[0], X_plan[0])
    assert np.array_equal(aim[1:4], pred[[0, 2, 4], 1])
    assert np.isnan(aim[4]).all()


def test_a_run_that_leaves_the_plan_on_its_controllers_aim_is_not_lost(arm5) -> None:
    robot, problem = arm5
    T, n = problem.T, robot.n_q
    X_plan = np.zeros((T + 1, 2 * n))
    X = X_plan.copy()
    X[100:, 0] = 2 * TRACKING_LOST           # leaves the plan from step 100
    assert _run(problem, robot, X, X_plan)["status"] == "tracking-lost"
    aim = X.copy()
    aim[100:, 0] += 0.1 * TRACKING_LOST       # the controller aimed there, nearly
    m = _run(problem, robot, X, X_plan, aim)
    assert m["status"] == "ok", m["reason"]
    assert m["max_tracking_error"] == pytest.approx(2 * TRACKING_LOST)    # against the plan, still reported
    aim[150:, 0] -= 3 * TRACKING_LOST        # ... until it aimed elsewhere
    m = _run(problem, robot, X, X_plan, aim)
    assert m["status"] == "tracking-lost" and m["failure_time"] == pytest.approx(1.5)
    assert "controller's prediction" in m["reason"]
