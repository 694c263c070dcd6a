"""The receding-horizon controller (raico.planning.mpc): shift warm start, receding end, pushes, budgets."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from raico.planning.aico import AICOOptions, aico
from raico.planning.costs import ControlCost, ViaPoint
from raico.planning.mpc import MPC, simulate, window_times
from raico.planning.problem import Problem
from raico.plants.dynamics import PseudoDynamics
from tests.planning.test_solvers_lq import exact_solution, make_lq
from tests.tolerance import close
from tests.toys import PlanarArm

pytestmark = pytest.mark.compiled   # reaches a C kernel


def test_window_times_keep_absolute_times_and_the_receding_end():
    T, H = 30, 20
    assert window_times(None, T, H, 3) is None
    assert list(window_times(np.array([8]), T, H, 1)) == [7]
    assert list(window_times(np.array([8]), T, H, 9)) == []           # passed
    assert list(window_times(np.array([15, 22]), T, H, 1)) == [14]    # 22 is past the window's end
    assert list(window_times(np.array([30]), T, H, 0)) == [20]        # receding end
    assert list(window_times(np.array([30]), T, H, 15)) == [15]       # the problem's end inside
    assert list(window_times(np.array([0, 30]), T, H, 0)) == [0, 20]


def _cold_window(pb: Problem, H: int, k: int, x: np.ndarray) -> Problem:
    """The window problem at tick ``k`` built by hand from fresh copies of the terms."""
    terms = []
    for t in pb.state_terms:
        c = copy.copy(t)
        c._set_times(window_times(t.times, pb.T, H, k))
        terms.append(c)
    return Problem(pb.dynamics, x, H, terms, list(pb.control_terms))


def test_shifted_warm_start_plus_one_iteration_is_the_cold_solve_lq():
    pb, H = make_lq(seed=3, T=30), 20
    opts = AICOOptions(process_noise=1e-9)
    mpc = MPC(pb, H, "aico", opts)
    rng = np.random.default_rng(0)
    x = pb.x0.copy()
    for k in range(4):
        u, o, O = mpc.tick(x)
        cold = aico(_cold_window(pb, H, k, x), AICOOptions(iterations=5, process_noise=1e-9))
        # a warm start plus one iteration: the cold solve's controller, trajectory and first control
        assert mpc.log.iterations[k] == 1
        assert close(mpc.O, cold.O, scale=1.0) and close(mpc.o, cold.o, scale=1.0)
        assert close(mpc.X, cold.X, scale=1.0) and close(u, cold.U[0], scale=1.0)
        assert np.allclose(o + O @ x, u, rtol=0, atol=1e-9 * max(1.0, np.abs(u).max()))
        # and the window's exact optimum, up to AICO's process-noise floor (as the LQ tests bound it)
        Xe, Ue = exact_solution(_cold_window(pb, H, k, x))
        assert np.max(np.abs(mpc.U - Ue)) < 1e-5
        x = pb.dynamics.step(x, u) + 0.05 * rng.standard_normal(pb.n_x)   # a disturbance between ticks


T, DT, N_Q, H = 60, 0.02, 3, 25


def _arm() -> Problem:
    arm = PlanarArm([0.5, 0.5, 0.5])
    x0 = np.zeros(2 * N_Q)
    x0[:N_Q] = [0.3, 0.4, 0.2]
    return Problem(PseudoDynamics(N_Q, DT), x0, T, [ViaPoint(arm, [0.6, 1.0], [T], weight=1e4, name="reach")],
                   [ControlCost(1e-2)])


def _push(k: int) -> np.ndarray:
    """A push of joint 0's acceleration, 30 rad/s^2 for 3 steps from step 25 (a 1.8 rad/s kick)."""
    return np.array([30.0, 0.0, 0.0]) if 25 <= k < 28 else np.zeros(N_Q)


def _task_error(pb: Problem, x: np.ndarray) -> float:
    term = pb.state_terms[0]
    return float(np.linalg.norm(term.taskmap.value_and_jacobian(x[:N_Q])[0] - term.target))


def test_mpc_absorbs_a_push_the_open_loop_plan_cannot():
    pb = _arm()
    plan = aico(pb, AICOOptions(iterations=100, alpha=1.0))
    assert _task_error(pb, plan.X[-1]) < 5e-3          # the plan reaches the target

    def step(x, u, k):
        return pb.dynamics.step(x, u)

    # open loop: the plan's controls held, the push added
    x = pb.x0.copy()
    for k in range(T):
        x = step(x, plan.U[k] + _push(k), k)
    open_loop = _task_error(pb, x)
    mpc = MPC(pb, H, "raico", {"alpha": 1.0}, keep_predictions=True)
    mpc.prepare(pb.x0, 50)
    X, _ = simulate(mpc, step, pb.x0, T, push=_push)
    # the predicted horizon of each tick starts at the state it measured
    pred = mpc.log.arrays()["mpc_predicted"]
    assert pred.shape == (T, H + 1, 2 * N_Q)
    assert np.allclose(pred[:, 0], X[:-1], rtol=0, atol=1e-6)
    closed = _task_error(pb, X[-1])
    assert open_loop > 0.2, open_loop       # the kick moves the open-loop end far off the target
    assert closed < 0.2 * open_loop, (closed, open_loop)
    assert closed < 0.02, closed
    assert mpc.log.n == T and np.all(mpc.log.iterations[:T] == 1)


def test_a_tick_past_its_budget_is_recorded():
    pb = _arm()
    mpc = MPC(pb, H, "raico", {"alpha": 1.0}, iterations=3, budget=1e-9)   # no solve fits in 1 ns
    mpc.tick(pb.x0)
    assert mpc.log.over_budget[0] and mpc.log.iterations[0] == 1
    roomy = MPC(pb, H, "raico", {"alpha": 1.0}, iterations=3, budget=60.0)
    roomy.tick(pb.x0)
    assert not roomy.log.over_budget[0] and roomy.log.iterations[0] == 3


@pytest.mark.parametrize("kwargs, match", [
    ({"horizon": 61}, "horizon 61 must be"),
    ({"horizon": 0}, "horizon 0 must be"),
    ({"solver": "ilqg"}, "cannot warm-start"),
    ({"iterations": 0}, "iterations per tick"),
    ({"budget": -1.0}, "time budget"),
])
def test_bad_input(kwargs, match):
    args = {"horizon": H, **kwargs}
    with pytest.raises(ValueError, match=match):
        MPC(_arm(), **args)
