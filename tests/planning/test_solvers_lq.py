"""Acceptance tests of the solvers on linear-quadratic problems.

The reference is computed here, independently of the solvers: the equality-constrained
QP over (x_0..x_T, u_0..u_{T-1}) solved through its KKT system, and a textbook
time-varying Riccati recursion for the feedback gains.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from raico.planning.aico import AICOOptions, aico
from raico.planning.costs import ControlCost, StateTarget
from raico.planning.ilqg import ILQGOptions, ilqg
from raico.planning.problem import Problem, controller_rollout
from raico.plants.dynamics import LinearDynamics
from tests.tolerance import REL, close

pytestmark = pytest.mark.compiled   # reaches a C kernel: run under the sanitizers too

N_X, N_U, T = 4, 2, 30


def make_lq(seed: int = 0, running: float = 0.0, n: int = N_X, m: int = N_U, T: int = T) -> Problem:
    """Random LQ problem with ``n`` states, ``m`` controls and horizon ``T``: stable A with drift a,
    state targets at several times (diagonal and full precisions; at 8, 15 and 22 of 30 steps and
    at T, scaled with T), a control cost with a non-zero target (h != 0), and optionally a running
    state cost of weight ``running`` at every step."""
    rng = np.random.default_rng(seed)
    A = np.eye(n) + 0.2 * rng.standard_normal((n, n))
    A *= 0.98 / max(abs(np.linalg.eigvals(A)))
    B = 0.5 * rng.standard_normal((n, m))
    a = 0.05 * rng.standard_normal(n)
    G = rng.standard_normal((n, n))
    at = [max(1, round(T * k / 30)) for k in (8, 15, 22)]
    terms = [
        StateTarget(rng.standard_normal(n), times=[at[0]], weight=50.0, name="s8"),
        StateTarget(rng.standard_normal(n), times=sorted(set(at[1:])), weight=20.0,
                    precision=rng.uniform(0.5, 2.0, n), name="s15_22"),
        StateTarget(rng.standard_normal(n), times=[T], weight=100.0,
                    precision=G @ G.T / n + 0.1 * np.eye(n), name="sT"),
    ]
    if running:
        terms.append(StateTarget(np.zeros(n), times=None, weight=running, name="run"))
    controls = [ControlCost(0.1, target=0.3 * rng.standard_normal(m))]
    return Problem(LinearDynamics(A=A, a=a, B=B), rng.standard_normal(n), T, terms, controls)


def exact_solution(pb: Problem, L: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Optimal ``X (T+1, n)``, ``U (T, m)`` from the KKT system of the QP
    ``min sum 1/2 x^T R x - r^T x + 1/2 u^T H u - h^T u (+ u^T L x)`` s.t. ``x_0 = x0``,
    ``x_{t+1} = A x_t + a + B u_t`` (the terms are exactly quadratic; ``L (T, m, n)``: cross blocks)."""
    n, m, dyn, T = pb.n_x, pb.n_u, pb.dynamics, pb.T
    R, r = pb.quadratize_states(np.zeros((T + 1, n)))
    H, h = pb.quadratize_controls(np.zeros((T, m)))
    nz = (T + 1) * n + T * m
    off = (T + 1) * n
    Hq, g = np.zeros((nz, nz)), np.zeros(nz)
    for t in range(T + 1):
        Hq[t * n:(t + 1) * n, t * n:(t + 1) * n] = R[t]
        g[t * n:(t + 1) * n] = r[t]
    for t in range(T):
        s = slice(off + t * m, off + (t + 1) * m)
        Hq[s, s], g[s] = H[t], h[t]
        if L is not None:
            sx = slice(t * n, (t + 1) * n)
            Hq[s, sx], Hq[sx, s] = L[t], L[t].T
    Ceq, d = np.zeros(((T + 1) * n, nz)), np.zeros((T + 1) * n)
    Ceq[:n, :n], d[:n] = np.eye(n), pb.x0
    for t in range(T):
        rows = slice((t + 1) * n, (t + 2) * n)
        Ceq[rows, (t + 1) * n:(t + 2) * n] = np.eye(n)
        Ceq[rows, t * n:(t + 1) * n] = -dyn.A
        Ceq[rows, off + t * m:off + (t + 1) * m] = -dyn.B
        d[rows] = dyn.a
    kkt = np.block([[Hq, Ceq.T], [Ceq, np.zeros((Ceq.shape[0], Ceq.shape[0]))]])
    z = np.linalg.solve(kkt, np.concatenate([g, d]))
    return z[:off].reshape(T + 1, n), z[off:nz].reshape(T, m)


def riccati_gains(pb: Problem) -> np.ndarray:
    """Time-varying LQR gains ``K (T, m, n)`` (``u_t = k_t + K_t x_t``) by the Riccati recursion."""
    T = pb.T
    R, _ = pb.quadratize_states(np.zeros((T + 1, pb.n_x)))
    H, _ = pb.quadratize_controls(np.zeros((T, pb.n_u)))
    A, B = pb.dynamics.A, pb.dynamics.B
    V = R[T]
    K = np.zeros((T, pb.n_u, pb.n_x))
    for t in range(T - 1, -1, -1):
        K[t] = -np.linalg.solve(H[t] + B.T @ V @ B, B.T @ V @ A)
        V = R[t] + A.T @ V @ A + A.T @ V @ B @ K[t]
        V = 0.5 * (V + V.T)
    return K


@pytest.fixture(scope="module")
def lq():
    pb = make_lq()
    X, U = exact_solution(pb)
    return pb, X, U, riccati_gains(pb)


@pytest.mark.numerics
def test_reference_is_the_optimum(lq):
    """The oracle itself: feasible, and every perturbation of the controls costs more."""
    pb, X, U, K = lq
    assert np.allclose(controller_rollout(pb.dynamics, pb.x0, U, np.zeros((T, N_U, N_X)))[0], X)
    J = pb.cost(X, U)
    rng = np.random.default_rng(1)
    for _ in range(5):
        dU = 1e-3 * rng.standard_normal(U.shape)
        Xp, Up = controller_rollout(pb.dynamics, pb.x0, U + dU, np.zeros((T, N_U, N_X)))
        assert pb.cost(Xp, Up) > J
    # the gains really vary in time (a constant-gain bug could not pass the gain tests)
    assert np.max(np.abs(K - K[0])) > 1e-2


@pytest.mark.numerics
def test_ilqg_equals_exact_solution(lq):
    pb, X, U, K = lq
    res = ilqg(pb, ILQGOptions())                       # the default stopping rules
    assert res.status == "converged", res.message
    assert np.max(np.abs(res.X - X)) < 3e-8
    assert np.max(np.abs(res.U - U)) < 3e-8
    assert np.max(np.abs(res.O - K)) < 1e-8
    tight = ilqg(pb, ILQGOptions(tol_rel=1e-13, tol_grad=1e-10))
    assert close(tight.X, X, scale=1.0)
    assert close(tight.U, U, scale=1.0)
    # its controller reproduces the trajectory
    Xc, _ = controller_rollout(pb.dynamics, pb.x0, res.o, res.O)
    assert close(Xc, res.X, scale=1.0)
    assert res.history and all(h.cost >= res.cost - REL * abs(res.cost) for h in res.history)


@pytest.mark.numerics
def test_aico_equals_exact_solution_in_one_iteration(lq):
    pb, X, U, K = lq
    res = aico(pb, AICOOptions(iterations=1, alpha=0.0, process_noise=1e-9))
    assert res.iterations == 1 and res.status == "max-iterations"
    assert np.max(np.abs(res.beliefs - X)) < 1e-5      # belief means
    assert np.max(np.abs(res.O - K)) < 1e-5            # feedback gains (time-varying Riccati)
    assert np.max(np.abs(res.X - X)) < 1e-5            # controller rolled out
    assert np.max(np.abs(res.U - U)) < 1e-5
    assert res.cost == pytest.approx(pb.cost(X, U), rel=1e-7)


@pytest.mark.numerics
def test_aico_without_relinearization_is_the_same(lq):
    """theta = inf skips the forward sweep during iterations: same controller."""
    pb, X, _, _ = lq
    a = aico(pb, AICOOptions(iterations=1, process_noise=1e-9))
    b = aico(pb, AICOOptions(iterations=1, process_noise=1e-9, theta=float("inf")))
    assert close(a.O, b.O, scale=1.0)
    assert close(a.X, b.X, scale=1.0)
    assert np.max(np.abs(b.beliefs - X)) < 1e-5


@pytest.mark.numerics
def test_aico_gap_shrinks_with_process_noise(lq):
    pb, X, _, K = lq
    gaps = []
    for q in (1e-3, 1e-5, 1e-7, 1e-9):
        res = aico(pb, AICOOptions(iterations=1, process_noise=q))
        gaps.append((np.max(np.abs(res.O - K)), np.max(np.abs(res.X - X)),
                     np.max(np.abs(res.beliefs - X))))
    gaps = np.array(gaps)
    assert gaps[0].min() > 1e-4                         # Q really matters at 1e-3
    for i in range(1, len(gaps)):
        assert np.all(gaps[i, :2] < 0.05 * gaps[i - 1, :2]), gaps  # ~linear in Q
        assert gaps[i, 2] < gaps[i - 1, 2], gaps


@pytest.mark.numerics
@pytest.mark.parametrize("alpha", [1.0, 10.0])
def test_raico_converges_to_exact_solution(alpha):
    pb = make_lq(seed=2, running=5.0)
    X, U = exact_solution(pb)
    errs = []
    res = aico(pb, AICOOptions(iterations=150, alpha=alpha, gamma=1.0, tol_rel=0.0),
               callback=lambda rec, Xn, Un: errs.append(np.max(np.abs(Xn - X))))
    errs = np.array(errs)
    assert errs[0] > 1e-3                               # the first step is regularized
    assert np.all(np.diff(errs) <= 1e-8)                # steady approach (to the Q floor)
    assert errs[-1] < 1e-6
    assert res.cost == pytest.approx(pb.cost(X, U), rel=1e-8)
    assert np.max(np.abs(res.U - U)) < 1e-5


@pytest.mark.numerics
def test_larger_alpha_takes_smaller_first_step():
    pb = make_lq(seed=2, running=5.0)
    X0 = np.tile(pb.x0, (T + 1, 1))
    steps = [np.linalg.norm(aico(pb, AICOOptions(iterations=1, alpha=al)).X - X0)
             for al in (0.0, 1.0, 10.0, 100.0)]
    assert all(b < a for a, b in itertools.pairwise(steps)), steps


@pytest.mark.numerics
@pytest.mark.parametrize("scale", [1e-2, 1e2, 1e4, 3e5, 1e8, 1e11])
def test_vstar_all_regimes(scale):
    """``V* = (q I + P'^-1)^-1`` and ``V* m'`` in every branch (series and Cholesky)."""
    from raico.planning.aico.sweeps import Sweeps

    sw = Sweeps(make_lq(), AICOOptions(process_noise=1e-9))
    rng = np.random.default_rng(3)
    G = rng.standard_normal((N_X, N_X - 1))                  # singular P' is allowed
    P = scale * G @ G.T
    p = P @ rng.standard_normal(N_X)
    Pa = np.column_stack([P, p])
    out = sw._vstar(Pa)
    E = np.eye(N_X) + 1e-9 * P
    exact = np.linalg.solve(E, Pa)
    assert np.allclose(out, exact, rtol=1e-9, atol=1e-9 * np.abs(exact).max())


@pytest.mark.numerics
def test_adaptive_raico_converges_faster_on_lq():
    """Beyond the thesis: the adaptive schedule shrinks alpha after accepted steps, so on the LQ
    problem it reaches the exact solution to 1e-6 in far fewer iterations than the fixed alpha = 10."""
    pb = make_lq(seed=2, running=5.0)
    X, U = exact_solution(pb)

    def iterations_to(schedule: str) -> tuple[int | None, object]:
        errs = []
        res = aico(pb, AICOOptions(iterations=150, alpha=10.0, tol_rel=0.0, schedule=schedule),
                   callback=lambda rec, Xn, Un: errs.append(np.max(np.abs(Xn - X))))
        hit = [i + 1 for i, e in enumerate(errs) if e < 1e-6]
        return (hit[0] if hit else None), res

    fixed, _ = iterations_to("fixed")
    adaptive, res = iterations_to("adaptive")
    assert fixed is not None and adaptive is not None and adaptive * 3 <= fixed, (adaptive, fixed)
    assert res.cost == pytest.approx(pb.cost(X, U), rel=1e-8)
    steps = [h.step for h in res.history]
    assert steps[:3] == pytest.approx([10.0, 3.0, 0.9])  # shrinks by 0.3 per accepted step


@pytest.mark.numerics
def test_adaptive_schedule_rejects_a_step_that_raises_the_cost():
    """A trial that raises the cost is not taken: the iterate and its cost stay, alpha grows."""
    from raico.planning.aico.steps import AICOStep
    from raico.planning.aico.sweeps import Sweeps
    from raico.planning.driver import Iterate

    pb = make_lq(seed=2, running=5.0)
    opts = AICOOptions(alpha=1.0, schedule="adaptive")
    step = AICOStep(pb, Sweeps(pb, opts), 1.0, 1.0, opts, initial_cost=0.0)  # no trial can beat 0
    start = Iterate(np.tile(pb.x0, (T + 1, 1)), np.zeros((T, N_U)))
    s = step(1, start)
    assert s.iterate is start and s.cost == 0.0 and not s.moved and step.alpha == pytest.approx(4.0)
    with pytest.raises(ValueError, match="the adaptive schedule needs alpha > 0"):
        AICOOptions(alpha=0.0, schedule="adaptive")


@pytest.mark.numerics
def test_aico_with_a_controller_learning_rate_approaches_the_exact_solution():
    """Algorithm 1 line 18's learning rate: on an LQ problem plain AICO's new controller is the exact one
    at once; blended with the previous one at rate 0.5 the controller approaches it geometrically."""
    pb = make_lq(seed=2, running=5.0)
    X, U = exact_solution(pb)
    errs = []
    res = aico(pb, AICOOptions(iterations=60, controller_rate=0.5, tol_rel=0.0),
               callback=lambda rec, Xn, Un: errs.append(np.max(np.abs(Un - U))))
    errs = np.array(errs)
    # about half the way each iteration (the feedback gains blend too, so not exactly half)
    assert errs[0] > 1e-3 and 0.4 * errs[0] < errs[1] < 0.6 * errs[0] and np.all(np.diff(errs) <= REL * errs[0])
    assert errs[-1] < 1e-6
    assert res.cost == pytest.approx(pb.cost(X, U), rel=1e-8)
    with pytest.raises(ValueError, match="controller_rate"):
        AICOOptions(controller_rate=0.0).validate()


@pytest.mark.numerics
def test_compiled_ilqg_backward_equals_numpy():
    """raico/planning/ilqg_backward.c computes iLQG's backward pass as the numpy code does (to rounding),
    with and without regularization, and refuses a Q_uu that is not positive definite as numpy does."""
    from raico.planning.ilqg import NotPD, c_backward_lib, lq_backward

    if c_backward_lib() is None:
        pytest.skip("no C compiler (RAICO_NO_C or no gcc)")
    rng = np.random.default_rng(3)
    for T, n, m in ((40, 4, 2), (200, 10, 5), (30, 24, 12)):
        A = np.eye(n) + 0.05 * rng.normal(size=(T, n, n))
        B = 0.1 * rng.normal(size=(T, n, m))
        G, H = rng.normal(size=(T + 1, n, n)), rng.normal(size=(T, m, m))
        args = (A, B, rng.normal(size=(T + 1, n)), G @ np.swapaxes(G, 1, 2) / n, rng.normal(size=(T, m)),
                H @ np.swapaxes(H, 1, 2) / m + 0.1 * np.eye(m))
        for mu in (0.0, 0.5):
            for got, ref in zip(lq_backward(*args, mu), lq_backward(*args, mu, compiled=False)):
                assert np.allclose(got, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())
        bad = list(args)
        bad[5] = bad[5].copy()
        bad[5][T // 2] = -np.eye(m)
        for compiled in (True, False):
            with pytest.raises(NotPD):
                lq_backward(*bad, 0.0, compiled=compiled)


def test_the_solvers_blas_runs_on_one_thread_and_the_library_scan_is_kept():
    """``single_threaded_blas``: one BLAS thread inside, the previous counts after; the scan of the loaded
    libraries is made once and kept while no module is imported (then it is made again)."""
    import sys

    from threadpoolctl import threadpool_info

    from raico.planning import problem as pm

    before = {i["filepath"]: i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}
    with pm.single_threaded_blas():
        inside = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
        controller = pm._BLAS_CONTROLLER[0]
    assert inside and set(inside) == {1}
    assert {i["filepath"]: i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"} == before
    with pm.single_threaded_blas():
        assert pm._BLAS_CONTROLLER[0] is controller
    sys.modules["_a_module_imported_since"] = sys     # what an import that loads a BLAS changes
    try:
        with pm.single_threaded_blas():
            assert pm._BLAS_CONTROLLER[0] is not controller
    finally:
        del sys.modules["_a_module_imported_since"]
