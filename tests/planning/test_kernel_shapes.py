"""Every compiled kernel over the corners of the shapes it accepts, against its numpy path or the
problem's exact answer, and every shape it does not accept refused with ``ValueError`` before the call.

Corners: one state, one control, more controls than states, T = 1 and 2, a long T, the largest plant
(the Nao); for the GP one training point, one input dimension, the largest compiled input dimension
and more inducing points than data. Property-based tests (hypothesis) draw further shapes for the
kernels with free sizes (iLQG's backward pass, the dense algebra of the sweeps). ``make test-sanitize``
runs this file with every kernel built under AddressSanitizer and UBSan, so a read or write past a
buffer at any of these shapes fails the run, not only a wrong number.
"""

from __future__ import annotations

import ctypes
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from raico.planning import kernels
from raico.planning.aico import AICOOptions, aico
from raico.planning.aico.sweeps import Sweeps
from raico.planning.costs import ControlCost, StateTarget, ViaPoint
from raico.planning.ilqg import ILQGOptions, ilqg, lq_backward
from raico.planning.problem import Problem, controller_rollout
from raico.plants.codegen import c_backend, rbd
from raico.plants.fast_analytic import FastAnalyticDynamics, TreeAnalyticDynamics
from raico.plants.gp import GPModel, SparseGPModel
from raico.plants.learned import LearnedDynamics
from raico.plants.robots import PLANTS, shared_robot
from raico.plants.taskmaps import FramePoints
from tests.planning.test_kernels import _assert_same, _dense_lib, _padded, _plan_problem
from tests.planning.test_solvers_lq import exact_solution, make_lq
from tests.tolerance import REL, assert_close, close

pytestmark = pytest.mark.compiled

HYPOTHESIS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@pytest.fixture(autouse=True)
def _compiled():
    if not c_backend.enabled():
        pytest.fail(f"compiled kernels unavailable ({c_backend.why_unavailable()}): these tests are about them")


def _close(got, ref, tol=REL):
    """Max abs difference relative to the reference's scale (at least 1); ``REL`` where the two routes
    agree up to rounding (FMA, vector widths: ``tests/tolerance.py``)."""
    return close(got, ref, rel=tol, scale=1.0)


# -- every solver on random LQ problems of every shape: the exact optimum --------------------------
# (n states, m controls, T steps): one state, one control, more controls than states (the shape of
# the heap overflow once found: 2 states, 5 controls, T = 100), T = 1 and 2, a long T
LQ_SHAPES = [(1, 1, 1), (1, 1, 2), (2, 1, 2), (1, 4, 6), (2, 5, 100), (3, 7, 12), (5, 10, 20), (6, 2, 25),
             (10, 5, 5), (1, 1, 300), (4, 2, 400)]


@pytest.fixture(scope="module", params=LQ_SHAPES, ids=[f"n{n}-m{m}-T{T}" for n, m, T in LQ_SHAPES])
def lq_case(request):
    n, m, T = request.param
    pb = make_lq(seed=n * 100 + m * 10 + T, n=n, m=m, T=T)
    return pb, *exact_solution(pb)


@pytest.mark.numerics
def test_ilqg_solves_every_shape_exactly(lq_case):
    pb, X, U = lq_case
    res = ilqg(pb, ILQGOptions(tol_rel=1e-13, tol_grad=1e-10))
    assert res.status == "converged", res.message
    assert _close(res.X, X, 1e-8) and _close(res.U, U, 1e-8)


@pytest.mark.numerics
def test_aico_solves_every_shape_exactly_in_one_iteration(lq_case):
    pb, X, U = lq_case
    res = aico(pb, AICOOptions(iterations=1, alpha=0.0, process_noise=1e-9))
    assert _close(res.beliefs, X, 1e-5) and _close(res.X, X, 1e-5) and _close(res.U, U, 1e-5)


@pytest.mark.numerics
@pytest.mark.parametrize("n,m,T", LQ_SHAPES, ids=[f"n{n}-m{m}-T{T}" for n, m, T in LQ_SHAPES])
def test_raico_converges_to_the_exact_solution_on_every_shape(n, m, T):
    """As the solver tests' R-AICO check (a running state cost, alpha = 1, the default process noise,
    whose floor bounds the error near 1e-5)."""
    pb = make_lq(seed=n * 100 + m * 10 + T, running=5.0, n=n, m=m, T=T)
    X, U = exact_solution(pb)
    res = aico(pb, AICOOptions(iterations=150, alpha=1.0, gamma=1.0, tol_rel=0.0))
    assert res.iterations > 1
    assert _close(res.X, X, 2e-5) and _close(res.U, U, 2e-5)
    assert res.cost == pytest.approx(pb.cost(X, U), rel=1e-7)


@pytest.mark.numerics
@pytest.mark.parametrize("n,m,T", [(1, 1, 1), (2, 5, 30), (1, 3, 2), (7, 2, 9)])
def test_compiled_sweeps_equal_numpy_sweeps_on_every_shape(n, m, T, monkeypatch):
    """The C sweeps against Sweeps's numpy code (the LTI route, and with a relinearization forced
    by a finite theta on the time-varying route through Python dynamics)."""
    out = {}
    for compiled in (True, False):
        monkeypatch.setattr(Sweeps, "compiled", compiled)
        out[compiled] = aico(make_lq(seed=3, running=1.0, n=n, m=m, T=T),
                             AICOOptions(alpha=1.0, iterations=3, tol_rel=0.0, theta=0.05))
    _assert_same(out[True], out[False])


class _SemiImplicitToy:
    """``qddot = -k sin(S q) - c v + G u`` (``n_q`` joints, ``n_u`` controls, ``G`` random), semi-implicit
    Euler as ``raico.plants.dynamics``: a time-varying ``C`` of the block form the sweep kernel exploits."""

    def __init__(self, n_q: int, n_u: int, dt: float = 0.02, seed: int = 0):
        rng = np.random.default_rng(seed)
        self.n_q, self.n_x, self.n_u, self.dt = n_q, 2 * n_q, n_u, dt
        self.S = np.eye(n_q) + 0.5 * np.eye(n_q, k=-1)
        self.G = rng.standard_normal((n_q, n_u)) / np.sqrt(n_u)
        self.k, self.c = 3.0, 0.5

    def step(self, x, u):
        n, dt = self.n_q, self.dt
        v1 = x[n:] + dt * (-self.k * np.sin(self.S @ x[:n]) - self.c * x[n:] + self.G @ u)
        return np.concatenate([x[:n] + dt * v1, v1])

    def linearize(self, x, u):
        n, dt = self.n_q, self.dt
        Fq = -self.k * np.cos(self.S @ x[:n])[:, None] * self.S
        dv = np.hstack([dt * Fq, (1.0 - dt * self.c) * np.eye(n)])
        A = np.vstack([np.hstack([np.eye(n), np.zeros((n, n))]) + dt * dv, dv])
        B = np.vstack([dt * (dt * self.G), dt * self.G])
        return A, self.step(x, u) - A @ x - B @ u, B

    def linearize_trajectory(self, X, U):
        parts = [self.linearize(x, u) for x, u in zip(X, U)]
        return tuple(np.stack([p[i] for p in parts]) for i in range(3))


# (joints, controls, T): one joint, one control, more controls than joints, the 4-row tiles' edges, 32 joints
BLOCK_SHAPES = [(1, 1, 1), (1, 3, 2), (2, 1, 5), (3, 7, 4), (5, 2, 9), (4, 4, 20), (9, 5, 6), (13, 13, 3),
                (32, 32, 3)]


@pytest.mark.numerics
@pytest.mark.parametrize("nq,nu,T", BLOCK_SHAPES, ids=[f"nq{a}-nu{b}-T{c}" for a, b, c in BLOCK_SHAPES])
def test_block_form_sweeps_on_every_shape(nq, nu, T, monkeypatch):
    """The semi-implicit Euler block form of the sweep kernel against Sweeps's numpy code (dense A, B)."""
    from tests.planning.test_kernels import _recording_block_steps

    def make():
        dyn = _SemiImplicitToy(nq, nu, seed=nq * 10 + nu)
        x0 = np.concatenate([np.linspace(0.2, 0.5, nq), np.zeros(nq)])
        goal = np.concatenate([np.full(nq, -0.3), np.zeros(nq)])
        return Problem(dyn, x0, T, [StateTarget(goal, [T], weight=1e3, name="goal"),
                                    StateTarget(np.zeros(2 * nq), None, weight=1.0, name="run")],
                       [ControlCost(1e-2)])

    counts = _recording_block_steps(monkeypatch)
    out = {}
    for compiled in (True, False):
        monkeypatch.setattr(Sweeps, "compiled", compiled)
        out[compiled] = aico(make(), AICOOptions(alpha=1.0, iterations=3, tol_rel=0.0, theta=0.01))
    _assert_same(out[True], out[False])
    assert counts and all(c > 0 for c in counts)
    assert sum(h.repeats for h in out[True].history) > 0    # the backward messages redone at a moved point


@pytest.mark.numerics
@pytest.mark.parametrize("n,m,T", [(1, 1, 1), (1, 1, 2), (2, 5, 100), (9, 3, 7), (3, 9, 1000)])
def test_lti_rollout_on_every_shape(n, m, T):
    """The sweep kernel's closed-loop rollout on an affine model against the reference Python loop."""
    pb = make_lq(seed=1, n=n, m=m, T=T)
    rng = np.random.default_rng(n + m + T)
    o, O = rng.standard_normal((T, m)), 0.05 * rng.standard_normal((T, m, n))
    Xc, Uc = pb.controller_rollout(o, O)
    Xp, Up = controller_rollout(pb.dynamics, pb.x0, o, O)
    assert _close(Xc, Xp) and _close(Uc, Up)
    with pytest.raises(ValueError, match="lti_rollout: O has shape"):
        pb.controller_rollout(o, O[:-1] if T > 1 else O[:, :, :0])


# -- iLQG's backward pass ------------------------------------------------------------------------
def _backward_args(rng, T: int, n: int, m: int):
    A = np.eye(n) + 0.05 * rng.normal(size=(T, n, n))
    B = 0.1 * rng.normal(size=(T, n, m))
    G, H = rng.normal(size=(T + 1, n, n)), rng.normal(size=(T, m, m))
    return (A, B, rng.normal(size=(T + 1, n)), G @ np.swapaxes(G, 1, 2) / n, rng.normal(size=(T, m)),
            H @ np.swapaxes(H, 1, 2) / m + 0.1 * np.eye(m))


def _backward_equal(args, mu: float) -> None:
    for got, ref in zip(lq_backward(*args, mu), lq_backward(*args, mu, compiled=False)):
        assert _close(got, ref)


@pytest.mark.numerics
@pytest.mark.parametrize("T,n,m", [(1, 1, 1), (2, 1, 1), (1, 1, 7), (2, 2, 5), (100, 2, 5), (7, 1, 24),
                                   (3, 24, 1), (5, 24, 40), (1000, 3, 2)])
def test_compiled_ilqg_backward_on_the_grid(T, n, m):
    rng = np.random.default_rng(T * 7 + n * 3 + m)
    for mu in (0.0, 0.7):
        _backward_equal(_backward_args(rng, T, n, m), mu)


@pytest.mark.numerics
@HYPOTHESIS
@given(T=st.integers(1, 30), n=st.integers(1, 24), m=st.integers(1, 30), mu=st.sampled_from([0.0, 0.3]),
       seed=st.integers(0, 2**31 - 1))
def test_compiled_ilqg_backward_on_drawn_shapes(T, n, m, mu, seed):
    _backward_equal(_backward_args(np.random.default_rng(seed), T, n, m), mu)


def test_ilqg_backward_refuses_wrong_shapes():
    args = list(_backward_args(np.random.default_rng(0), 4, 3, 2))
    for i, bad in ((0, args[0][:, :2]), (2, args[2][:-1]), (3, args[3][:, :, :2]), (4, args[4][:, :1]),
                   (5, args[5][:-1])):
        wrong = list(args)
        wrong[i] = bad
        with pytest.raises(ValueError, match="ilqg backward pass: .* has shape"):
            lq_backward(*wrong, 0.0)
    with pytest.raises(ValueError, match=r"T, n, m\) with T, n, m >= 1"):
        lq_backward(args[0][:0], args[1][:0], args[2][:1], args[3][:1], args[4][:0], args[5][:0], 0.0)


# -- the dense algebra of the sweeps (dense.c), on drawn shapes and leading dimensions --------------
@pytest.mark.numerics
@HYPOTHESIS
@given(a=st.integers(1, 40), r=st.integers(1, 40), c=st.integers(1, 40), extra=st.integers(0, 5),
       seed=st.integers(0, 2**31 - 1))
def test_dense_kernels_on_drawn_shapes(a, r, c, extra, seed):
    lib, rng = _dense_lib(), np.random.default_rng(seed)
    A, B, C0 = rng.standard_normal((a, r)), rng.standard_normal((r, c)), rng.standard_normal((a, c))
    Ab, Bb, Cb = _padded(A, extra), _padded(B, extra), _padded(C0, extra)
    lib.k_gemm_nn(a, r, c, 0.5, Ab.ctypes.data, Ab.shape[1], Bb.ctypes.data, Bb.shape[1], Cb.ctypes.data,
                  Cb.shape[1])
    np.testing.assert_allclose(Cb[:a, :c], C0 + 0.5 * A @ B, rtol=0, atol=1e-9 * r)
    assert (Cb[:a, c:] == 12345.0).all() and (Cb[a] == 12345.0).all()
    n = a
    G = rng.standard_normal((n, n))
    S = G.T @ G + 0.5 * np.eye(n)
    Sb = _padded(S, extra)
    assert lib.k_chol_u(n, Sb.ctypes.data, Sb.shape[1]) == 0
    R = np.triu(Sb[:n, :n])
    X = rng.standard_normal((n, c))
    Xb = _padded(X, extra)
    lib.k_solve_rt(n, Sb.ctypes.data, Sb.shape[1], Xb.ctypes.data, Xb.shape[1], c)
    ref = np.linalg.solve(R.T, X)
    np.testing.assert_allclose(Xb[:n, :c], ref, rtol=0, atol=1e-8 * max(np.abs(ref).max(), 1.0))
    assert (Xb[:n, c:] == 12345.0).all() and (Xb[n] == 12345.0).all()


# -- task messages (task_messages.c): its stack buffers' limits ------------------------------------
def _nao_points_problem(k: int):
    """The Nao's pseudo-dynamics balance problem with one more via point: ``k`` points on the torso."""
    base = _plan_problem("nao", "balance", "pseudo")
    robot = shared_robot("nao")
    tm = FramePoints(robot, "torso", points=np.linspace(-0.05, 0.05, 3 * k).reshape(k, 3), name=f"torso_{k}")
    via = ViaPoint(tm, np.zeros(tm.dim), times=[base.T], weight=10.0, name=f"torso_{k}")
    return Problem(base.dynamics, base.x0, base.T, [*base.state_terms, via], base.control_terms)


def _messages_equal(problem) -> None:
    fn, ctx, keep = kernels.compile_task_set(problem)
    evaluate = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p,
                                ctypes.c_void_p, ctypes.c_void_p)(fn)
    active = problem.active_state_terms()
    rng = np.random.default_rng(0)
    n = problem.n_x
    for t in (0, problem.T):
        x = problem.x0 + 0.1 * rng.standard_normal(n)
        lx, lxx = np.empty(n), np.empty((n, n))
        evaluate(ctx, t, x.ctypes.data, lx.ctypes.data, lxx.ctypes.data)
        g, G = problem.point_state_derivatives(x, t, active[t])
        assert_close(lx, g, scale=1.0)
        assert_close(lxx, G, scale=1.0)


@pytest.mark.numerics
def test_task_messages_at_the_largest_map_the_kernel_takes():
    """21 points (63 rows, the kernel's 64-row limit) on the largest plant: compiled, equal to Python."""
    _messages_equal(_nao_points_problem(21))


def test_task_messages_beyond_the_kernels_limits_use_python(monkeypatch):
    """22 points (66 rows) do not fit the kernel's buffers: no compiled messages (the Python ones run);
    nor does a robot with more positions than the kernel holds (the limit lowered below the Nao's 25)."""
    assert kernels.compile_task_set(_nao_points_problem(21)) is not None
    assert kernels.compile_task_set(_nao_points_problem(22)) is None
    monkeypatch.setattr(kernels, "TASK_MAX_POSITIONS", 24)
    assert kernels.compile_task_set(_nao_points_problem(1)) is None


# -- the GP point kernels (gp_point.c) -----------------------------------------------------------
# (N training points, d input dimensions, D outputs): one point, one input, the largest compiled d
GP_SHAPES = [(1, 1, 1), (1, 3, 1), (2, 1, 1), (3, 5, 2), (40, 7, 3), (6, 256, 2), (5, 30, 12)]


def _gp(N: int, d: int, D: int, seed: int = 0) -> GPModel:
    rng = np.random.default_rng(seed)
    X, Y = rng.standard_normal((N, d)), rng.standard_normal((N, D))
    return GPModel(X, Y, ell=rng.uniform(0.5, 2.0, (D, d)) * np.sqrt(d), sf2=rng.uniform(0.5, 2.0, D),
                   sn2=1e-2 * np.ones(D), x_mean=np.zeros(d), x_std=np.ones(d), y_mean=np.zeros(D),
                   y_std=np.ones(D))


@pytest.mark.numerics
@pytest.mark.parametrize("N,d,D", GP_SHAPES)
def test_gp_point_kernels_on_every_shape(N, d, D):
    model = _gp(N, d, D)
    Q = np.vstack([np.random.default_rng(1).standard_normal((3, d)), model.X[:1]])
    m_ref, g_ref = model.mean_with_gradients(Q)
    ref = model.predict_with_gradients(Q)
    for i, x in enumerate(Q):
        m, g = model.point_mean_with_gradients(x)
        assert _close(m, m_ref[i]) and _close(g, g_ref[i], 1e-9)
        for got, r in zip(model.point_predict_with_gradients(x), ref):
            assert _close(got, r[i], 1e-8)
    with pytest.raises(ValueError, match="a query has"):
        model.point_mean_with_gradients(np.zeros(d + 1))


@pytest.mark.numerics
def test_gp_point_beyond_the_compiled_input_size_uses_numpy():
    model = _gp(4, 257, 1)                      # d > 256: the kernel's stack buffers, numpy instead
    x = np.random.default_rng(2).standard_normal(257)
    m, g = model.point_mean_with_gradients(x)
    m_ref, g_ref = model.mean_with_gradients(x[None])
    assert np.array_equal(m, m_ref[0]) and np.array_equal(g, g_ref[0])


@pytest.mark.numerics
def test_sparse_gp_with_more_inducing_points_than_data():
    rng = np.random.default_rng(3)
    X, Y = rng.standard_normal((4, 3)), rng.standard_normal((4, 2))
    model = SparseGPModel(X, Y, ell=np.ones(3), sf2=np.ones(2), sn2=1e-2 * np.ones(2),
                          inducing=rng.standard_normal((9, 3)))
    assert model.Z.shape == (9, 3)
    Q = rng.standard_normal((3, 3))
    m_ref, g_ref = model.mean_with_gradients(Q)
    for i, x in enumerate(Q):
        m, g = model.point_mean_with_gradients(x)
        assert _close(m, m_ref[i]) and _close(g, g_ref[i], 1e-9)


# (N, n_q, n_u): the learned dynamics' rollout and relinearization at their corners
LEARNED_SHAPES = [(1, 1, 1), (2, 1, 3), (9, 3, 1), (12, 4, 4), (5, 100, 56)]


@pytest.mark.numerics
@pytest.mark.parametrize("N,nq,nu", LEARNED_SHAPES)
def test_learned_dynamics_kernels_on_every_shape(N, nq, nu):
    model = _gp(N, 2 * nq + nu, nq, seed=N)
    dyn = LearnedDynamics(model, n_q=nq, dt=0.01)
    rng = np.random.default_rng(4)
    fn, ctx, keep = dyn.c_linearizer()
    call = ctypes.CFUNCTYPE(ctypes.c_int, *[ctypes.c_void_p] * 6)(fn)
    x, u = 0.3 * rng.standard_normal(2 * nq), rng.standard_normal(nu)
    A, a, B = np.empty((2 * nq, 2 * nq)), np.empty(2 * nq), np.empty((2 * nq, nu))
    assert call(ctx, x.ctypes.data, u.ctypes.data, A.ctypes.data, a.ctypes.data, B.ctypes.data) == 0
    A2, a2, B2 = dyn.linearize(x, u)
    assert np.array_equal(A, A2) and np.array_equal(B, B2) and _close(a, a2)
    for T in (1, 2, 30):
        o, O = rng.standard_normal((T, nu)), 0.01 * rng.standard_normal((T, nu, 2 * nq))
        Xc, Uc = dyn.controller_rollout(x, o, O)
        Xp, Up = controller_rollout(dyn, x, o, O)
        assert _close(Xc, Xp) and _close(Uc, Up)
    with pytest.raises(ValueError, match="rollout expects"):
        model.controller_rollout(x, o, O[:, :, :-1], 0.01)


@pytest.mark.numerics
def test_learned_dynamics_keep_the_dense_sweep_products(monkeypatch):
    """A learned (GP) model is semi-implicit Euler too, but its sweeps keep the dense products and their
    rounding (the thesis's learning figures flip with rounding-level changes): no step takes the block form,
    and the compiled sweeps still equal the numpy sweeps."""
    from tests.planning.test_kernels import _recording_block_steps

    nq, T = 2, 12

    def make():
        dyn = LearnedDynamics(_gp(20, 3 * nq, nq, seed=7), n_q=nq, dt=0.02)
        goal = np.concatenate([np.full(nq, 0.4), np.zeros(nq)])
        return Problem(dyn, np.zeros(2 * nq), T, [StateTarget(goal, [T], weight=1e3, name="goal")], [ControlCost(1e-2)])

    counts = _recording_block_steps(monkeypatch)
    out = {}
    for compiled in (True, False):
        monkeypatch.setattr(Sweeps, "compiled", compiled)
        out[compiled] = aico(make(), AICOOptions(alpha=1.0, iterations=3, tol_rel=0.0, theta=0.01))
    _assert_same(out[True], out[False])
    assert counts and not any(counts)
    assert sum(h.repeats for h in out[True].history) > 0


# -- the plants' generated dynamics and tree kernels ----------------------------------------------
def _states(robot, K: int, seed: int):
    rng = np.random.default_rng(seed)
    n = robot.n_q
    X = np.concatenate([robot.default_q + 0.3 * rng.standard_normal((K, n)), rng.standard_normal((K, n))], 1)
    return X, rng.standard_normal((K, n))


def _dynamics(plant: str):
    robot = shared_robot(plant)
    return robot, (TreeAnalyticDynamics(robot, 0.01) if plant == "nao" else FastAnalyticDynamics(robot, 0.01))


@pytest.mark.numerics
@pytest.mark.parametrize("plant", PLANTS)
def test_compiled_dynamics_batches_at_every_length(plant):
    """Batched linearization and closed-loop rollout at T = 1, 2 and longer against the point calls
    (the Nao's tree route included), and wrong shapes refused."""
    robot, dyn = _dynamics(plant)
    c = dyn._compiled()
    assert c is not None
    n = robot.n_q
    for T in (1, 2, 17):
        X, U = _states(robot, T, seed=T)
        A, a, B = c.linearize_trajectory(X, U)
        for t in range(T):
            for got, ref in zip((A[t], a[t], B[t]), c.linearize(X[t], U[t])):
                assert np.array_equal(got, ref)
        O = 0.05 * np.random.default_rng(T).standard_normal((T, n, 2 * n))
        Xr, Ur = c.controller_rollout(X[0], U, O)
        x = X[0]
        for t in range(T):
            u = U[t] + O[t] @ x
            assert _close(Ur[t], u)
            x = c.step(x, u)
            assert _close(Xr[t + 1], x)
    X, U = _states(robot, 3, seed=0)
    with pytest.raises(ValueError, match="dyn_linearize_batch: U has shape"):
        c.linearize_trajectory(X, U[:2])
    with pytest.raises(ValueError, match="dyn_controller_rollout: O has shape"):
        c.controller_rollout(X[0], U, np.zeros((3, n, n)))


@pytest.mark.numerics
@pytest.mark.parametrize("plant", PLANTS)
def test_tree_kernels_at_every_shape(plant):
    """The tree kernels' batches at K = 1 and more, frames with 1 and many points, against the single
    calls; a body out of range or a wrong shape refused before the call."""
    robot = shared_robot(plant)
    k = rbd.tree_kernels(robot)
    rng = np.random.default_rng(5)
    R, p = np.eye(3), np.array([0.01, -0.02, 0.03])
    last = len(k.tree.names) - 1
    for K in (1, 4):
        Q = rng.uniform(-1.0, 1.0, (K, k.m))
        for npts in (1, 21):
            pts = rng.standard_normal((npts, 3))
            pos, J = k.frame_points_batch(Q, last, R, p, pts)
            for i in range(K):
                pos1, J1 = k.frame_points(Q[i], last, R, p, pts)
                assert np.array_equal(pos[i], pos1) and np.array_equal(J[i], J1)
        c, Jc = k.com_batch(Q)
        Rb, Jw = k.frame_rotation_batch(Q, last, R)
        for i in range(K):
            assert np.array_equal(c[i], k.com(Q[i])[0]) and np.array_equal(Jc[i], k.com(Q[i])[1])
            assert np.array_equal(Rb[i], k.frame_rotation(Q[i], last, R)[0])
            assert np.array_equal(Jw[i], k.frame_rotation(Q[i], last, R)[1])
    q = np.zeros(k.m)
    for call in (lambda: k.frame_points(q, last + 1, R, p, np.zeros((1, 3))),
                 lambda: k.frame_rotation(q, -1, R), lambda: k.frame_rotation_batch(q[None], last + 1, R)):
        with pytest.raises(ValueError, match="body index"):
            call()
    for call, what in ((lambda: k.com(q[:-1]), "tree_com: qp"), (lambda: k.mass_matrix(np.zeros(k.m + 1)), "qp"),
                       (lambda: k.frame_points(q, 0, R, p, np.zeros((2, 2))), "points"),
                       (lambda: k.frame_points(q, 0, R[:2], p, np.zeros((1, 3))), "R_BF"),
                       (lambda: k.inverse_dynamics(q, q, q[:-1]), "a has shape"),
                       (lambda: k.com_batch(np.zeros((2, k.m + 1))), "Qp")):
        with pytest.raises(ValueError, match=what):
            call()


# -- task messages (task_messages.c) over the range of robots and maps it accepts -------------------------
# (moving joints, branches, welded at a leaf): one joint; a branching tree with prismatic joints and welds;
# a re-rooted one; the largest tree the kernel's buffers take (64 positions: a posture map of 64 rows);
# one past it
TASK_TREES = [(1, 1, False), (9, 3, False), (9, 2, True), (33, 4, False), (64, 5, False)]


def _task_tree(n: int, branches: int, leaf: bool, tmp_path):
    from raico.plants.model_file import RobotSpec, load_model
    from tests.plants.test_tree_kernel_range import tree_urdf

    path = tmp_path / f"tree{n}.urdf"
    path.write_text(tree_urdf(n, branches, seed=n + branches))
    robot = load_model(RobotSpec(file=str(path), weld=f"l{n - 1}" if leaf else None, armature=0.01))
    robot.spec = replace(robot.spec, end_effectors=(("tool", "l0" if leaf else f"l{n - 1}"),))  # away from the root
    return robot


@pytest.mark.numerics
@pytest.mark.parametrize("n, branches, leaf", TASK_TREES, ids=[f"n{n}-b{b}{'-leaf' if l else ''}"
                                                                for n, b, l in TASK_TREES])
def test_task_messages_for_every_compiled_kind_over_the_range_of_robots(n, branches, leaf, tmp_path):
    """Every state-term example with a compiled counterpart, all in one task set, on trees of 1 to 64
    moving joints: compiled, and the messages equal the Python terms' at every step, relative to their scale;
    the control toward gravity too (its state part at random controls: the gravity torques' analytical
    Jacobian on the tree, mapped by P), and its costs without a gradient."""
    from raico.planning.costs import COST_TERM_EXAMPLES, ControlCost, ControlGravity, TaskInequality
    from raico.planning.problem import Problem
    from raico.planning.term_kinds import kind_of_map
    from raico.plants.dynamics_registry import make_dynamics
    from tests.planning.test_task_messages import _evaluator

    robot = _task_tree(n, branches, leaf, tmp_path)
    q0 = np.clip(robot.default_q + 0.2, robot.lower, robot.upper)
    terms = []
    for _, ex in sorted(COST_TERM_EXAMPLES.items()):
        if ex.kind != "state":
            continue
        term = ex.build(robot, q0)
        tm = getattr(term, "taskmap", None)
        if tm is None or (kind_of_map(tm) is not None and kind_of_map(tm).compile is not None):
            terms.append(term)
    assert any(type(t) is TaskInequality for t in terms) and len(terms) >= 8, [type(t).__name__ for t in terms]
    T = 4   # the examples' via-points lie at steps up to 4
    x0 = np.concatenate([robot.default_q, np.zeros(robot.n_q)])
    problem = Problem(make_dynamics("pseudo", robot, 0.01), x0, T, terms, [ControlCost(1e-2)])
    evaluate = _evaluator(problem)
    active = problem.active_state_terms()
    rng = np.random.default_rng(n)
    for s in (0.1, 1.0):
        x = np.concatenate([robot.default_q + s * rng.standard_normal(robot.n_q), rng.standard_normal(robot.n_q)])
        for t in range(T + 1):
            lx, lxx = evaluate(x, t)
            g, G = problem.point_state_derivatives(x, t, active[t])
            assert_close(lx, g, scale=1.0, err_msg=f"n={n} t={t}")
            assert_close(lxx, G, scale=1.0, err_msg=f"n={n} t={t}")
    grav = ControlGravity(robot, 0.3, T=T, precision=np.linspace(1.0, 2.0, robot.n_q), name="gravity")
    gravity = Problem(make_dynamics("analytic", robot, 0.01), x0, T, [], [ControlCost(1e-2)], joint_terms=[grav])
    compiled = kernels.compile_task_set(gravity)
    assert compiled is not None
    X = x0 + 0.3 * rng.standard_normal((T + 1, gravity.n_x))
    U = 2.0 * rng.standard_normal((T, gravity.n_u))
    gravity.set_nominal(X, U)
    kernels.set_task_controls(compiled, U)
    evaluate = _evaluator(gravity, compiled)
    for t in range(T):
        lx, lxx = evaluate(X[t], t)
        g, G = gravity.point_state_derivatives(X[t], t)
        assert_close(lx, g, err_msg=f"gravity n={n} t={t}")
        assert_close(lxx, G, err_msg=f"gravity n={n} t={t}")
    (lx, lxx), costs = kernels.task_rows(compiled, T, X, np.arange(T + 1), costs=True)
    assert_close(costs, np.r_[grav.joint_value(X[:-1], U), 0.0], err_msg=f"gravity n={n}")


def test_task_messages_beyond_64_positions_use_python(tmp_path):
    """65 moving joints exceed the kernel's position buffers: no compiled messages."""
    from raico.planning.costs import COST_TERM_EXAMPLES, ControlCost
    from raico.planning.problem import Problem
    from raico.plants.dynamics_registry import make_dynamics

    robot = _task_tree(65, 5, False, tmp_path)
    term = COST_TERM_EXAMPLES["via_joint_positions"].build(robot, robot.default_q)
    x0 = np.concatenate([robot.default_q, np.zeros(robot.n_q)])
    assert kernels.compile_task_set(Problem(make_dynamics("pseudo", robot, 0.01), x0, 4, [term],
                                            [ControlCost(1e-2)])) is None
