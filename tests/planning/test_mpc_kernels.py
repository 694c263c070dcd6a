"""The MPC tick's compiled parts (raico/planning/aico/shift.py: ShiftSweeps, FiniteBoxAL's kernel, the rollout
into buffers) against the numpy code they replace: the same numbers bit for bit; the kernels' shape range."""

from __future__ import annotations

import ctypes
import math
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from raico.planning import kernels
from raico.planning.aico import AICOOptions
from raico.planning.aico import shift as shift_mod
from raico.planning.aico.sweeps import NumericalError, Sweeps
from raico.planning.constraints import AugmentedLagrangian, ControlBox, StateBox
from raico.planning.costs import ControlCost, StateTarget
from raico.planning.mpc import MPC
from raico.planning.problem import Bounds, Problem
from raico.plants.dynamics import LinearDynamics
from raico.plants.fast_analytic import FastAnalyticDynamics
from raico.plants.robots import shared_robot

pytestmark = [pytest.mark.compiled, pytest.mark.numerics]


def _need_kernels():
    if kernels.library() is None or kernels.box_library() is None:
        pytest.skip("no compiled kernels")


def _arm5(T: int, tight: bool = True, effort: float = 1.2) -> Problem:
    """arm5 (compiled dynamics) driven to a far state target under joint ranges, velocity and effort limits
    tight enough to be active (``effort``: the effort limit, 1.2 saturates the controls)."""
    robot = shared_robot("arm5")
    dyn = FastAnalyticDynamics(robot, 0.01)
    n = robot.n_q
    x0 = np.concatenate([robot.default_q, np.zeros(n)])
    target = x0.copy()
    target[:n] += 1.2
    lim = 0.4 if tight else 10.0
    bounds = Bounds(u_lower=np.full(n, -effort), u_upper=np.full(n, effort),
                    q_index=np.arange(n), q_lower=x0[:n] - lim, q_upper=x0[:n] + lim,
                    v_index=np.arange(n, 2 * n), v_lower=np.full(n, -2.0 * lim), v_upper=np.full(n, 2.0 * lim))
    return Problem(dyn, x0, T, [StateTarget(target, weight=10.0, name="far")], [ControlCost(1e-3)], [], bounds)


def _run(pb: Problem, ticks: int, theta: float) -> dict[str, np.ndarray]:
    mpc = MPC(pb, 12, "raico", {"alpha": 1.0, "theta": theta}, ticks=ticks, keep_predictions=True)
    mpc.prepare(pb.x0, 8)
    x, xs = pb.x0.copy(), []
    for _ in range(ticks):
        u, _, _ = mpc.tick(x)
        x = pb.dynamics.step(x, u)
        xs.append(x)
    ws = mpc._ws
    return {"x": np.array(xs), "X": ws.X.copy(), "O": ws.O.copy(), "cost": mpc.log.cost[:ticks].copy(),
            "viol": mpc.log.violation[:ticks].copy(), "pred": mpc.log.predicted[:ticks].copy(),
            "y": np.concatenate([np.zeros(0) if y is None else y.ravel() for y in ws.al.y]), "mu": np.array(ws.al.mu)}


@pytest.mark.slow
@pytest.mark.parametrize("theta", [math.inf, 0.1])
def test_the_compiled_tick_is_the_numpy_tick_bit_for_bit(theta, monkeypatch):
    """ShiftSweeps, the boxes' kernel and the rollout into buffers against the workspace on plain Sweeps, the
    numpy boxes and Problem.bounded_rollout: every tick's state, cost, violation, prediction, the multipliers."""
    _need_kernels()
    pb = _arm5(40)
    fast = _run(pb, 25, theta)
    assert fast["y"].any() and np.isfinite(fast["x"]).all()   # the constraints were active
    monkeypatch.setattr(shift_mod, "ShiftSweeps", Sweeps)
    monkeypatch.setattr(kernels, "box_library", lambda: None)
    monkeypatch.setattr(shift_mod.ShiftedAICO, "_fast_rollout", lambda self: None)
    ref = _run(_arm5(40), 25, theta)
    for k in ref:
        assert np.array_equal(fast[k], ref[k]), k


def _boxes(T: int, n: int, m: int, rng) -> list:
    q = rng.permutation(n)[: max(1, n // 2)]
    v = np.setdiff1d(np.arange(n), q)[: max(0, n // 3)]
    lo, hi = np.full((T + 1, len(q)), -0.3), np.full((T + 1, len(q)), 0.3)
    hi[:, ::2] = np.inf
    cons = [StateBox("q", q, lo, hi, 1e-4)]
    if len(v):
        cons.append(StateBox("v", v, np.full((T + 1, len(v)), -0.5), np.full((T + 1, len(v)), 0.2), 1e-4))
    iu = rng.permutation(m)[: max(1, m - 1)]
    ulo, uhi = np.full(len(iu), -1.0), np.full(len(iu), 0.8)
    ulo[0] = -np.inf
    cons.append(ControlBox("u", iu, ulo, uhi, np.full(len(iu), 1e-3), 0.5))
    return cons


@pytest.mark.parametrize("T, n, m", [(1, 1, 1), (2, 3, 1), (5, 4, 2), (7, 6, 9), (30, 14, 7), (2, 16, 17),
                                     (3, 33, 32), (1, 32, 1)])
def test_the_boxes_kernel_is_the_general_lagrangian_bit_for_bit(T, n, m):
    """FiniteBoxAL's compiled multipliers' step, violation and model (added in place) against the general
    AugmentedLagrangian on finite iterates with active rows on every box, over shapes (``k = 0`` boxes too)."""
    _need_kernels()
    rng = np.random.default_rng(T * 100 + n * 10 + m)
    cons = _boxes(T, n, m, rng)
    fast = shift_mod._finite_boxes(AugmentedLagrangian(cons, T, 10.0))
    general = AugmentedLagrangian(cons, T, 10.0)
    for _ in range(3):
        X, U = rng.normal(size=(T + 1, n)), 2.0 * rng.normal(size=(T, m))
        with np.errstate(over="ignore"):   # the general code's rows without a bound are -1.8e308, not -inf
            ref = general.model(X, U)
            lx, RA = rng.normal(size=(T + 1, n)), rng.normal(size=(T + 1, n, n + 1))
            H, h = rng.normal(size=(T, m, m)), rng.normal(size=(T, m))
            want = (lx.copy(), RA.copy(), H.copy(), h.copy())
            active = fast.model_into(X, U, lx, RA, H, h)
            assert active is (ref is not None)
            if ref is not None:
                want[0][...] += ref[0]
                want[1][:, :, :n] += ref[1]
                want[2][...] = want[2] + ref[3]
                want[3][...] = want[3] + np.einsum("tij,tj->ti", ref[3], U) - ref[2]
            for got, w in zip((lx, RA, H, h), want):
                assert np.array_equal(got, w)
            assert fast.violation(X, U) == general.violation(X, U)
            general.update(X, U)
            fast.update(X, U)
        assert fast.mu == general.mu and fast.last_violation == general.last_violation
        for a, b in zip(fast.y, general.y):
            assert (a is None) == (b is None) and (a is None or np.array_equal(a, b))
    assert any(y is not None for y in fast.y)


def test_the_boxes_kernel_takes_only_boxes_on_distinct_columns():
    _need_kernels()
    rng = np.random.default_rng(0)
    T, n, m = 4, 4, 2
    twice = [StateBox("a", [0, 1], np.zeros((T + 1, 2)), np.ones((T + 1, 2)), 1e-4),
             StateBox("b", [1], np.zeros((T + 1, 1)), np.ones((T + 1, 1)), 1e-4)]
    al = shift_mod._finite_boxes(AugmentedLagrangian(twice, T, 1.0))
    X, U = rng.normal(size=(T + 1, n)), rng.normal(size=(T, m))
    assert al._compiled(X, U) is None                    # column 1 in two boxes: the general code
    assert al.model_into(X, U, np.zeros((T + 1, n)), np.zeros((T + 1, n, n + 1)), np.zeros((T, m, m)),
                         np.zeros((T, m))) is None
    ok = shift_mod._finite_boxes(AugmentedLagrangian(twice[:1], T, 1.0))
    assert ok._compiled(X, U) is not None
    X[2, 3] = np.nan
    assert ok._compiled(X, U) is None                    # a non-finite iterate: the general code


def _lti_sweeps(T: int, n: int, m: int, rng) -> Sweeps:
    A = np.eye(n) + 0.1 * rng.normal(size=(n, n))
    B = rng.normal(size=(n, m))
    pb = Problem(LinearDynamics(A, np.zeros(n), B), rng.normal(size=n), T, [StateTarget(np.zeros(n))],
                 [ControlCost(1.0)])
    sw = shift_mod.ShiftSweeps(pb, AICOOptions(theta=math.inf))
    X, U = rng.normal(size=(T + 1, n)), rng.normal(size=(T, m))
    sw.linearize_all(X, U, X, 0.5)
    return sw


@pytest.mark.parametrize("T, n, m", [(1, 1, 1), (3, 2, 5), (6, 5, 2), (4, 9, 9), (2, 16, 17), (2, 33, 32),
                                     (1, 32, 1)])
def test_sweep_linearize_checks_every_control_hessian(T, n, m):
    """``sweep_linearize``'s checks over shapes (m > n too): a control Hessian not positive definite at step t
    (err_info t), a non-finite h, a shared H (stride 0) checked once."""
    _need_kernels()
    rng = np.random.default_rng(T + n + m)
    sw = _lti_sweeps(T, n, m, rng)
    lib = kernels.library()
    sw._run_linearize(lib, 0)                       # positive definite, finite: passes
    t = T - 1
    sw._Hb[t] = -np.eye(m)
    with pytest.raises(NumericalError, match="not positive definite"):
        sw._run_linearize(lib, 0)
    assert sw._kstate[0].err_info == t
    sw._Hb[t] = np.eye(m)
    sw._hb[0, m - 1] = np.inf
    with pytest.raises(NumericalError, match="non-finite"):
        sw._run_linearize(lib, 0)
    sw._hb[0, m - 1] = 0.0
    st = sw._kernel_state(lib)
    st.H_s = 0                                        # one shared H: only step 0's is read
    sw._Hb[1:] = np.nan if T > 1 else sw._Hb[1:]
    assert lib.sweep_linearize(ctypes.byref(st), 0) == 0


@pytest.mark.parametrize("T", [1, 2, 9])
def test_sweep_linearize_dynamics_are_the_batch_linearization(T):
    """The dynamics at every step in one call: the model's batch linearization (``linearize_trajectory``)
    packed into ``C``, bit for bit; ``blk`` zeroed."""
    _need_kernels()
    pb = _arm5(T, tight=False)
    sw = shift_mod.ShiftSweeps(pb, AICOOptions(theta=math.inf))
    rng = np.random.default_rng(T)
    n, m = pb.n_x, pb.n_u
    X = pb.x0 + 0.3 * rng.normal(size=(T + 1, n))
    U = rng.normal(size=(T, m))
    sw.linearize_all(X, U, X, 1.0)
    A, a, B = pb.dynamics.linearize_trajectory(X[:-1], U)
    assert np.array_equal(sw.C[:, :n, :m], B) and np.array_equal(sw.C[:, :n, m:m + n], A)
    assert np.array_equal(sw.C[:, :n, m + n], -a) and not sw._kernel_work(kernels.library())[0].any()
    X[T // 2, 0] = np.inf                            # a non-finite point: ERR_LIN
    with pytest.raises(NumericalError), np.errstate(all="ignore"):
        sw.linearize_all(X, U, X, 1.0)


def test_task_rows_into_given_arrays():
    _need_kernels()
    pb = _arm5(6, tight=False)
    ct = kernels.compile_task_set(pb)
    assert ct is not None
    rng = np.random.default_rng(3)
    X = pb.x0 + 0.2 * rng.normal(size=(7, pb.n_x))
    steps = np.arange(7)
    (lx, lxx), c = kernels.task_rows(ct, 6, X, steps, costs=True)
    out = (np.empty_like(lx), np.empty_like(lxx), np.empty_like(c))
    kernels.task_rows(ct, 6, X, steps, costs=True, out=out)
    assert all(np.array_equal(a, b) for a, b in zip(out, (lx, lxx, c)))
    with pytest.raises(ValueError, match="shape"):
        kernels.task_rows(ct, 6, X, steps, costs=True, out=(lx[:3], lxx, c))
    with pytest.raises(ValueError, match="contiguous"):
        kernels.task_rows(ct, 6, X, steps, costs=True, out=(np.asfortranarray(lx), lxx, c))


def test_all_finite():
    _need_kernels()
    lib = kernels.library()
    for k in (0, 1, 7):
        a = np.ones(k)
        assert lib.all_finite(a.ctypes.data, k) == 1
        for bad in (np.nan, np.inf, -np.inf):
            if k:
                b = a.copy()
                b[k - 1] = bad
                assert lib.all_finite(b.ctypes.data, k) == 0


@pytest.mark.slow
def test_a_compiled_tick_allocates_less_than_a_few_trajectories():
    """tracemalloc over ticks of the compiled workspace on the xArm7's reach (its joint range active, no
    control clipped: a clipped rollout runs the Python loop of ``Problem.bounded_rollout``): a tick's peak of
    temporaries stays below four trajectories ``X`` (the numpy assembly of the task messages into strided
    views, the tick's record of the bounds' excess; the former code's peak was above 60 of them)."""
    _need_kernels()
    from raico.stages.plan.stage import PlanConfig, build_problem

    path = Path(__file__).resolve().parents[2] / "raico" / "problems" / "examples" / "xarm7_reach.toml"
    pb = build_problem(PlanConfig(problem=str(path), dynamics="analytic", q0_std=0.0))[2]
    mpc = MPC(pb, 50, "raico", {"alpha": 1.0, "theta": math.inf}, ticks=pb.T)
    mpc.prepare(pb.x0, 50)
    x = pb.x0.copy()
    for _ in range(10):                         # warm-up: buffers, addresses, numpy's caches
        u, _, _ = mpc.tick(x)
        x = pb.dynamics.step(x, u)
    peaks = []
    tracemalloc.start()
    try:
        for _ in range(20):
            tracemalloc.reset_peak()
            before = tracemalloc.get_traced_memory()[0]
            u, _, _ = mpc.tick(x)
            peaks.append(tracemalloc.get_traced_memory()[1] - before)
            x = pb.dynamics.step(x, u)
    finally:
        tracemalloc.stop()
    assert any(y is not None for y in mpc._ws.al.y)          # the boxes were active
    assert max(peaks) < 4 * mpc.X.nbytes, (max(peaks), mpc.X.nbytes)
