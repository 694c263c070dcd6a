"""The model file plus a residual GP, compiled (``raico.plants.learned.ResidualKernel``, ``residual_step.c``): one
control step of ``k`` substeps, its linearization and rollout equal to the Python path (``ResidualDynamics`` inside
``SubstepDynamics``), the linearization against central differences, the batched window linearization against the
per-step one; the sweeps and the MPC take the compiled path."""

import numpy as np
import pytest

from tests.tolerance import REL, assert_close, bound


def tol(n_ops: float, cond: float) -> float:
    """The rounding bound of two routes, never below ``REL``."""
    return max(REL, bound(n_ops, cond))


def residual(k: int, n_points: int = 40, plant: str = "arm5"):
    from raico.plants.dynamics import SubstepDynamics
    from raico.plants.learned import RESIDUAL_KEY, build_learned, example_params
    from raico.plants.robots import shared_robot

    robot = shared_robot(plant)
    params = {**example_params(robot, n_points=n_points), RESIDUAL_KEY: np.array(1.0)}
    inner = build_learned(robot, 0.01 / k, params)
    return robot, inner, SubstepDynamics(inner, k)


def points(robot, n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    q = robot.default_q + 0.3 * rng.standard_normal((n, robot.n_q))
    return np.hstack([q, rng.standard_normal((n, robot.n_q))]), rng.standard_normal((n, robot.n_q))


@pytest.mark.numerics
@pytest.mark.compiled
@pytest.mark.parametrize("k", [1, 5])
def test_the_compiled_step_and_linearization_equal_the_python_ones(k):
    """``res_linearize`` and ``res_step`` of k substeps equal ``SubstepDynamics(ResidualDynamics)``'s Python path
    (its ``linearize`` chaining the base's compiled linearization and the GP's mean and gradient)."""
    from raico.plants.dynamics import SubstepDynamics

    robot, inner, dyn = residual(k)
    kern = inner.substep_kernel(k)
    assert kern is not None and dyn.c_linearizer() is not None
    X, U = points(robot, 6)
    for x, u in zip(X, U):
        A, a, B = kern.linearize(x, u)
        A0, a0, B0 = SubstepDynamics.linearize(dyn, x, u)      # the Python chain over the inner models
        if k == 1:
            A0, a0, B0 = type(inner).linearize(inner, x, u)
        n_ops = 40 * k * (2 * robot.n_q)
        assert_close(A, A0, rel=tol(n_ops, 10.0))
        assert_close(B, B0, rel=tol(n_ops, 10.0))
        assert_close(a, a0, rel=tol(n_ops, 10.0), scale=float(np.abs(A0 @ x).max()))
        x1 = x
        for _ in range(k):
            x1 = type(inner).step(inner, x1, u)                # SemiImplicitEuler with base qddot + GP mean
        assert_close(kern.step(x, u), x1, rel=tol(n_ops, 10.0))
        assert_close(A @ x + a + B @ u, x1, rel=tol(n_ops, 10.0))


@pytest.mark.numerics
@pytest.mark.compiled
@pytest.mark.parametrize("plant, n_points, k", [("pendulum", 1, 1), ("cartpole", 40, 3), ("nao", 1, 1), ("nao", 40, 2)])
def test_the_kernel_over_the_corners_of_its_shapes(plant, n_points, k):
    """The corners of ``residual_step.c``'s shapes (run under ASan/UBSan by ``make test-sanitize``): one joint and
    one training point, a prismatic joint, the largest plant (25 joints: 75 GP inputs, 25 outputs) with one and 40
    points; its step, linearization and controller rollout against the Python path."""
    robot, inner, dyn = residual(k, n_points, plant)
    kern = inner.substep_kernel(k)
    assert kern is not None
    X, U = points(robot, 2, seed=1)
    n_ops = max(n_points, 1) * k * 3 * robot.n_q
    for x, u in zip(X, U):
        x1 = x
        for _ in range(k):
            x1 = type(inner).step(inner, x1, u)
        assert_close(kern.step(x, u), x1, rel=tol(n_ops, 10.0))
        A, a, B = kern.linearize(x, u)
        assert A.shape == (2 * robot.n_q, 2 * robot.n_q) and B.shape == (2 * robot.n_q, robot.n_q)
        assert_close(A @ x + a + B @ u, x1, rel=tol(n_ops, 10.0))
    T, n, m = 3, 2 * robot.n_q, robot.n_q
    rng = np.random.default_rng(4)
    o, O = 0.1 * rng.standard_normal((T, m)), 0.01 * rng.standard_normal((T, m, n))
    Xr, Ur = dyn.controller_rollout(X[0], o, O)
    X0, U0 = _python_rollout(dyn, X[0], o, O)
    assert_close(Xr, X0, rel=tol(n_ops * T, 100.0))
    assert_close(Ur, U0, rel=tol(n_ops * T, 100.0))


@pytest.mark.numerics
@pytest.mark.compiled
def test_the_compiled_linearization_by_finite_differences():
    """``A``, ``B`` of the compiled five substeps against central differences of its own step."""
    from raico.plants.numdiff import numdiff_jacobian

    robot, inner, dyn = residual(5)
    kern = inner.substep_kernel(5)
    X, U = points(robot, 3, seed=1)
    for x, u in zip(X, U):
        A, _, B = kern.linearize(x, u)
        A_fd = numdiff_jacobian(lambda z, u=u: kern.step(z, u), x)
        B_fd = numdiff_jacobian(lambda w, x=x: kern.step(x, w), u)
        assert_close(A, A_fd, rel=1e-6, scale=float(np.abs(A).max()))
        assert_close(B, B_fd, rel=1e-6, scale=float(np.abs(B).max()))


@pytest.mark.numerics
@pytest.mark.compiled
def test_the_compiled_rollout_equals_stepping_in_python_and_nan_propagates():
    """``SubstepDynamics.controller_rollout`` (compiled) equals the Python loop; a NaN state gives NaN after it."""
    robot, inner, dyn = residual(5)
    T, n, m = 12, 2 * robot.n_q, robot.n_q
    rng = np.random.default_rng(2)
    x0 = points(robot, 1)[0][0]
    o, O = rng.standard_normal((T, m)), 0.1 * rng.standard_normal((T, m, n))
    X, U = dyn.controller_rollout(x0, o, O)
    X0, U0 = _python_rollout(dyn, x0, o, O)
    assert_close(X, X0, rel=tol(40 * 5 * T * n, 100.0))
    assert_close(U, U0, rel=tol(40 * 5 * T * n, 100.0))
    x_bad = x0.copy()
    x_bad[0] = np.nan
    Xn, _ = dyn.controller_rollout(x_bad, o, O)
    assert np.isnan(Xn[1:]).all()


def _python_rollout(dyn, x0, o, O):
    """The reference loop with the inner model's Python step (no compiled kernel)."""
    inner = dyn.inner
    T = o.shape[0]
    X, U = np.empty((T + 1, x0.size)), np.empty(o.shape)
    X[0] = x0
    for t in range(T):
        U[t] = o[t] + O[t] @ X[t]
        x = X[t]
        for _ in range(dyn.k):
            x = type(inner).step(inner, x, U[t])
        X[t + 1] = x
    return X, U


@pytest.mark.numerics
def test_the_batched_window_linearization_equals_the_per_step_one():
    """``ResidualDynamics.linearize_trajectory`` (the base's batch and one GP call for all steps, no step of its
    own) equals ``linearize`` step by step, and its ``A``, ``B`` the central differences of the step."""
    from raico.plants.numdiff import numdiff_jacobian

    robot, inner, _ = residual(1)
    X, U = points(robot, 8, seed=3)
    A, a, B = inner.linearize_trajectory(X, U)
    for t, (x, u) in enumerate(zip(X, U)):
        A0, a0, B0 = inner.linearize(x, u)
        assert_close(A[t], A0, rel=tol(200, 10.0))
        assert_close(B[t], B0, rel=tol(200, 10.0))
        assert_close(a[t], a0, rel=tol(200, 10.0), scale=float(np.abs(A0 @ x).max()))
    x, u = X[0], U[0]
    assert_close(A[0], numdiff_jacobian(lambda z: inner.step(z, u), x), rel=1e-6, scale=float(np.abs(A[0]).max()))
    assert_close(B[0], numdiff_jacobian(lambda w: inner.step(x, w), u), rel=1e-6, scale=float(np.abs(B[0]).max()))


@pytest.mark.numerics
@pytest.mark.compiled
def test_a_gp_whose_arrays_were_replaced_refreshes_its_kernel_in_place():
    """After an update of the GP (its arrays replaced) the kernel is the same object at the same context address
    (a sweep kernel holding it stays valid) and steps with the new GP: the Python step's numbers."""
    robot, inner, _ = residual(1)
    k1 = inner.substep_kernel(1)
    addr = k1.linearizer()[1]
    x, u = points(robot, 1, seed=5)[0][0], points(robot, 1, seed=5)[1][0]
    before = k1.step(x, u)
    rng = np.random.default_rng(4)
    Xn = np.hstack([points(robot, 3)[0], rng.standard_normal((3, robot.n_q))])
    inner.model = inner.model.update(Xn, 10.0 * rng.standard_normal((3, robot.n_q)))
    k2 = inner.substep_kernel(1)
    assert k2 is k1 and k2.linearizer()[1] == addr
    after = k2.step(x, u)
    assert not np.array_equal(before, after)
    assert_close(after, type(inner).step(inner, x, u), rel=tol(400, 10.0))


@pytest.mark.numerics
@pytest.mark.compiled
def test_the_learned_mpc_takes_the_compiled_path_and_its_windows_equal_the_python_ones():
    """R-AICO's MPC on the model file plus the residual GP (5 substeps, the uncertainty term in the window): with
    the compiled kernel (the sweeps' relinearizations and the rollouts in C) its windows over a few ticks equal
    those of the Python path (``ResidualDynamics.compiled = False``)."""
    from raico.planning.costs import ControlCost, StateTarget, Uncertainty
    from raico.planning.mpc import MPC
    from raico.planning.problem import Problem
    from raico.plants.learned import ResidualDynamics

    robot, inner, dyn = residual(5)
    n = robot.n_q
    x0 = np.concatenate([robot.default_q, np.zeros(n)])
    target = np.concatenate([robot.default_q + 0.2, np.zeros(n)])
    T, H = 12, 6

    def windows(compiled: bool) -> np.ndarray:
        saved = ResidualDynamics.compiled
        ResidualDynamics.compiled = compiled
        try:
            assert (dyn.c_linearizer() is not None) == compiled
            p = Problem(dyn, x0, T, [StateTarget(target, times=[T], weight=100.0, name="reach")],
                        [ControlCost(1e-3)], [Uncertainty(dyn, 0.0, 1e-2, T, units="standardized")])
            mpc = MPC(p, H, "raico", iterations=1)
            mpc.prepare(x0, 3)
            out, x = [], x0
            for _ in range(4):
                u, _, _ = mpc.tick(x)
                out.append(mpc.X.copy())
                x = dyn.step(x, u)
            return np.array(out)
        finally:
            ResidualDynamics.compiled = saved

    fast, slow = windows(True), windows(False)
    assert np.all(np.isfinite(slow))
    assert_close(fast, slow, rel=tol(4 * 4 * 40 * 5 * H * 2 * n, 100.0))


def sparse_residual(k: int, n_points: int = 40, inducing: int = 20):
    """``residual(k)`` whose GP is a sparse one (FITC, fixed inducing inputs) on the same data and hyperparameters."""
    from raico.plants.gp import SparseGPModel

    robot, inner, dyn = residual(k, n_points)
    g = inner.model
    inner.model = SparseGPModel(g.X, g.Y, g.ell, g.sf2, g.sn2, inducing=inducing, x_mean=g.x_mean, x_std=g.x_std,
                                y_mean=g.y_mean, y_std=g.y_std, noise_floor=g.noise_floor)
    return robot, inner, dyn


@pytest.mark.numerics
@pytest.mark.compiled
def test_the_online_update_feeds_the_executed_steps_to_the_mpcs_model():
    """``OnlineResidual`` every 3 planning steps: the executed steps' samples join the sparse GP in rank-k updates
    (6 points after 7 observed states), the compiled window model reads the new posterior (its step the Python
    one), the GP's mean at the samples moves towards their targets; refused without a sparse GP or with K < 1."""
    from raico.planning.costs import ControlCost, StateTarget
    from raico.planning.mpc import MPC, OnlineResidual
    from raico.planning.problem import Problem

    robot, inner, dyn = sparse_residual(5)
    n = robot.n_q
    x0 = np.concatenate([robot.default_q, np.zeros(n)])
    p = Problem(dyn, x0, 12, [StateTarget(np.concatenate([robot.default_q + 0.2, np.zeros(n)]), times=[12],
                                          weight=100.0, name="reach")], [ControlCost(1e-3)])
    mpc = MPC(p, 6, "raico", iterations=1)
    mpc.prepare(x0, 3)
    with pytest.raises(ValueError, match="integer >= 1"):
        OnlineResidual(mpc, 0)
    online = OnlineResidual(mpc, 3)
    bias = 0.5 * np.ones(n)    # the plant: the model's step plus a constant acceleration it does not know

    def plant(x, u):
        x1 = dyn.step(x, u)
        return x1 + np.concatenate([dyn.dt ** 2 * bias, dyn.dt * bias])

    N0, x = inner.model.N, x0
    samples = []
    for _ in range(7):
        u = mpc.tick(x)[0].copy()
        online.observe(x, u)
        samples.append(np.concatenate([x, u]))
        x = plant(x, u)
    assert online.updates == 2 and online.points == 6 and inner.model.N == N0 + 6
    Z = np.array(samples[:6])
    kern = inner.substep_kernel(5)
    assert_close(kern.step(Z[0, :2 * n], Z[0, 2 * n:]), dyn.step(Z[0, :2 * n], Z[0, 2 * n:]), rel=tol(40 * 5 * 2 * n, 10.0))
    target = inner.model.Y[-6:]      # the samples' targets, as fed
    fresh = sparse_residual(5)[1].model
    assert np.abs(inner.model.predict_mean(Z) - target).max() < np.abs(fresh.predict_mean(Z) - target).max()
    _, plain, pdyn = residual(5)
    with pytest.raises(ValueError, match="sparse"):
        OnlineResidual(MPC(Problem(pdyn, x0, 12, [], [ControlCost(1e-3)]), 6, "raico"), 3)
