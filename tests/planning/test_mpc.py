"""The receding-horizon controller (raico.planning.mpc): shift warm start, receding end, pushes, budgets."""

from __future__ import annotations

import copy
import gc
import math
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from raico.planning.aico import AICOOptions, aico
from raico.planning.aico.shift import FiniteBoxAL, shift_rows
from raico.planning.constraints import AugmentedLagrangian, ControlBox, StateBox
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


@pytest.mark.numerics
@pytest.mark.parametrize("theta", [0.1, math.inf])   # relinearized in the sweeps (shifted beliefs read) or not
def test_shifted_warm_start_plus_one_iteration_is_the_cold_solve_lq(theta):
    pb, H = make_lq(seed=3, T=30), 20
    opts = AICOOptions(process_noise=1e-9, theta=theta)
    mpc = MPC(pb, H, "aico", opts)
    assert mpc._ws is not None              # the shifted workspace, one for all ticks
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


def test_shift_rows_moves_every_row_and_repeats_the_last():
    a = np.arange(24.0).reshape(4, 3, 2)
    scratch = np.empty(a.size)
    shift_rows(a, scratch)
    assert np.array_equal(a[:3], np.arange(6.0, 24.0).reshape(3, 3, 2)) and np.array_equal(a[3], a[2])
    b = np.arange(5.0)
    shift_rows(b, scratch, stop=4)             # the backward message's end (row 4) untouched
    assert list(b) == [1.0, 2.0, 3.0, 3.0, 4.0]


def test_the_workspace_shifts_messages_controller_and_multipliers():
    pb = _arm()
    mpc = MPC(pb, H, "raico", {"alpha": 1.0})
    mpc.prepare(pb.x0, 5)
    ws = mpc._ws
    VA, SA, O = ws.sw.VA.copy(), ws.sw.SA.copy(), ws.O.copy()
    ws.shift()
    assert np.array_equal(ws.sw.VA[:H - 1], VA[1:H]) and not ws.sw.VA[H].any()
    assert np.array_equal(ws.sw.SA[:H], SA[1:]) and np.array_equal(ws.O[:H - 1], O[1:])


@pytest.mark.numerics
def test_finite_box_lagrangian_is_the_general_one_on_finite_iterates():
    rng = np.random.default_rng(1)
    T, n, m = 6, 4, 2
    lo, hi = np.full((T + 1, 2), -0.3), np.full((T + 1, 2), 0.3)
    hi[:, 1] = np.inf
    cons = [StateBox("q", [0, 1], lo, hi, 1e-4),
            ControlBox("u", np.array([0, 1]), np.array([-1.0, -np.inf]), np.array([1.0, 2.0]), np.full(2, 1e-4), 0.5)]
    general, fast = AugmentedLagrangian(cons, T, 10.0), FiniteBoxAL(cons, T, 10.0)
    X, U = rng.normal(size=(T + 1, n)), 2.0 * rng.normal(size=(T, m))
    with np.errstate(over="ignore"):     # the general code's rows without a bound are -1.8e308, not -inf
        for al in (general, fast):
            al.update(X, U)
        X2, U2 = X + 0.1 * rng.normal(size=X.shape), U + 0.1 * rng.normal(size=U.shape)
        assert fast.violation(X2, U2) == general.violation(X2, U2)
        assert close(fast.value(X2, U2), general.value(X2, U2))
        for a, b in zip(fast.model(X2, U2), general.model(X2, U2)):
            assert close(a, b)


def test_a_tick_allocates_only_temporaries_and_retains_nothing():
    """tracemalloc over ticks: what a tick leaves allocated does not grow with the ticks (beyond numpy's own
    bounded caches of small buffers, a few bytes a tick), and its peak (the linearization's and task rows'
    temporaries) stays below the workspace's message arrays."""
    pb = _arm()
    mpc = MPC(pb, H, "raico", {"alpha": 1.0, "theta": math.inf}, ticks=400)
    mpc.prepare(pb.x0, 5)
    x = pb.x0.copy()

    def run(ticks: int) -> list[int]:
        nonlocal x
        peaks = []
        for _ in range(ticks):
            tracemalloc.reset_peak()
            before = tracemalloc.get_traced_memory()[0]
            u, _, _ = mpc.tick(x)
            peaks.append(tracemalloc.get_traced_memory()[1] - before)
            x = pb.dynamics.step(x, u)
        return peaks

    tracemalloc.start()
    try:
        run(100)                                   # warm-up: numpy's small-buffer caches fill
        gc.collect()
        start = tracemalloc.get_traced_memory()[0]
        peaks = run(200)
        gc.collect()
        retained = tracemalloc.get_traced_memory()[0] - start
    finally:
        tracemalloc.stop()
    sw = mpc._ws.sw
    messages = sum(a.nbytes for a in (sw.SA, sw.VA, sw.RA, sw.Z))
    assert max(peaks) < messages, (max(peaks), messages)
    assert max(peaks[-50:]) <= 1.5 * max(peaks[:50]) + 1024      # the peak does not grow with the ticks
    # no array of the window is kept: a tick leaves less than a quarter of its trajectory X (the ~100 bytes a
    # tick measured are the bookkeeping of numpy's and scipy's caches: weak references, sets, small blocks)
    assert retained < 200 * mpc.X.nbytes / 4, retained


@pytest.mark.numerics
@pytest.mark.parametrize("name, short", [
    ("xarm7_reach", (("T = 100", "T = 16"),)),
    ("xarm7_track", (("T = 200", "T = 16"), ("from = 10, to = 199", "from = 2, to = 16")))])
def test_fddp_window_moved_by_circular_append_is_the_window_problem(tmp_path, name, short):
    """crocoddyl's window, moved node by node (circularAppend of the nodes built before the loop, the terminal
    node replaced), costs what the raico window of each tick costs, through the problem's end entering the
    window; a moving target (a term per step) too."""
    from raico.planning import crocoddyl as cm

    if not cm.AVAILABLE:
        pytest.skip(f"crocoddyl baseline: {cm.UNAVAILABLE_REASON}")
    from raico.stages.plan.stage import PlanConfig, build_problem

    src = (Path(__file__).resolve().parents[2] / f"raico/problems/examples/{name}.toml").read_text()
    for a, b in short:
        src = src.replace(a, b)
    path = tmp_path / "short.toml"
    path.write_text(src)
    pb = build_problem(PlanConfig(problem=str(path), dynamics="analytic", q0_std=0.0))[2]
    mpc = MPC(pb, 6, "fddp")
    rng = np.random.default_rng(2)
    for _ in range(pb.T):
        x = pb.x0 + 0.01 * rng.standard_normal(pb.n_x)
        mpc.tick(x)
        cp, _ = mpc._fddp_window()
        X = x + 0.05 * rng.standard_normal((mpc.H + 1, pb.n_x))
        U = rng.standard_normal((mpc.H, pb.n_u))
        assert close(cp.shooting.calc(cp.to_pin(X), cp.controls_to_pin(U)), mpc.window.cost(X, U))


def test_fddp_loop_builds_no_crocoddyl_model(tmp_path, monkeypatch):
    """Every node the FDDP window appends or puts at its end is built with the controller: a loop through
    the problem's end with a moving target (a new set of terms each tick) builds no crocoddyl model."""
    from raico.planning import crocoddyl as cm

    if not cm.AVAILABLE:
        pytest.skip(f"crocoddyl baseline: {cm.UNAVAILABLE_REASON}")
    from raico.planning.crocoddyl import solve as cs
    from raico.stages.plan.stage import PlanConfig, build_problem

    src = (Path(__file__).resolve().parents[2] / "raico/problems/examples/xarm7_track.toml").read_text()
    path = tmp_path / "short.toml"
    path.write_text(src.replace("T = 200", "T = 12").replace("from = 10, to = 199", "from = 1, to = 12"))
    pb = build_problem(PlanConfig(problem=str(path), dynamics="analytic", q0_std=0.0))[2]
    mpc = MPC(pb, 5, "fddp")

    def refused(*a, **k):
        raise AssertionError("a crocoddyl model built inside the loop")
    for name in ("build", "node_models"):
        monkeypatch.setattr(cs, name, refused)
    monkeypatch.setattr(cs._Nodes, "model", refused)
    x = pb.x0.copy()
    for _ in range(pb.T):
        u, _, _ = mpc.tick(x)
        x = pb.dynamics.step(x, u)
    assert mpc.log.n == pb.T
