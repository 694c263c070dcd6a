"""The controls' box in AICO's backward pass (BoxDDP's box QP, :mod:`raico.planning.aico.boxqp`): the box QP
against the exact QP (every active set's KKT point enumerated) on random small boxes, the clamped controller's
gains and message against the box QP and the value they stand for, and a bounded LQ problem whose optimum the
KKT system of its active set gives, certified by its multipliers' signs."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from raico.planning.aico import AICOOptions, aico
from raico.planning.aico.boxqp import applies, box_qp, boxed_step
from raico.planning.problem import Bounds, Status
from raico.planning.solvers import SOLVERS
from tests.planning.test_solvers_lq import N_U, exact_solution, make_lq
from tests.tolerance import REL, assert_close, bound, cond_of


def exact_box_qp(M: np.ndarray, q: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``argmin 1/2 u^T M u + q^T u`` over the box by enumeration: each row at its lower bound, its upper bound
    or free, the free rows from their equations; the one point inside the box whose gradient pushes every
    bound row outward (the KKT point, unique for ``M`` positive definite)."""
    m = len(q)
    for a in itertools.product((0, 1, 2), repeat=m):
        s = np.array(a)
        u = np.where(s == 0, lo, np.where(s == 1, hi, 0.0))
        f = s == 2
        if f.any():
            u[f] = np.linalg.solve(M[np.ix_(f, f)], -(q[f] + M[np.ix_(f, ~f)] @ u[~f]))
        g = q + M @ u
        tol = REL * (1.0 + np.abs(q).max() + np.abs(M).max())   # the floor of tests/tolerance.py
        if np.all(u >= lo - tol) and np.all(u <= hi + tol) and np.all(g[s == 0] >= -tol) and np.all(g[s == 1] <= tol):
            return u
    raise AssertionError("no KKT point")


def random_qp(rng: np.random.Generator, m: int, spread: float = 3.0):
    A = rng.standard_normal((m, m))
    M = A @ A.T + 0.1 * np.eye(m)
    return M, spread * rng.standard_normal(m), -rng.uniform(0.0, 1.0, m), rng.uniform(0.0, 1.0, m)


@pytest.mark.numerics
@pytest.mark.parametrize("seed", range(40))
def test_box_qp_is_the_exact_qp_optimum(seed):
    """Random boxes of 1 to 5 controls: the projected Newton solution is the enumerated KKT point."""
    rng = np.random.default_rng(seed)
    M, q, lo, hi = random_qp(rng, int(rng.integers(1, 6)))
    u, free, _ = box_qp(M, q, lo, hi)
    want = exact_box_qp(M, q, lo, hi)
    assert_close(u, want, rel=max(REL, bound(len(q) ** 2, cond_of(M))), scale=float(np.abs(want).max()) + 1.0)
    assert np.all((u >= lo) & (u <= hi))
    assert np.all(free[(u > lo) & (u < hi)])      # a row inside its box is free


@pytest.mark.numerics
def test_box_qp_all_clamped_and_none_clamped():
    """A tiny box the unbounded minimizer leaves in every row: every row clamped at the side its gradient
    pushes to; a wide box: no row clamped and the solution is ``-M^-1 q``."""
    rng = np.random.default_rng(7)
    M, q, _, _ = random_qp(rng, 4)
    u_free = -np.linalg.solve(M, q)
    u, free, _ = box_qp(M, q, np.full(4, -1e-6), np.full(4, 1e-6))
    want = exact_box_qp(M, q, np.full(4, -1e-6), np.full(4, 1e-6))
    assert not free.any() and np.array_equal(u, want) and np.all(np.abs(u) == 1e-6)
    u, free, _ = box_qp(M, q, np.full(4, -1e6), np.full(4, 1e6))
    assert free.all()
    assert_close(u, u_free, rel=max(REL, bound(4, cond_of(M))))


@pytest.mark.numerics
@pytest.mark.parametrize("seed", range(10))
def test_clamped_controller_is_the_box_qp_near_its_point_and_its_message_is_its_value(seed):
    """``boxed_step``'s controller ``k + G x`` is the box QP's solution at ``x_bar`` and, where the active set
    holds, at points near it (the free rows' gains exact, the clamped rows' zero); its message is the
    quadratic ``1/2 x^T V^-1 x - x^T V^-1 v`` of the cost with that controller, up to a constant (checked by
    its exact second differences and its gradient at 0: the cost is quadratic in ``x``)."""
    rng = np.random.default_rng(100 + seed)
    m, n = 3, 4
    M, _, lo, hi = random_qp(rng, m)
    F, g, x_bar = rng.standard_normal((m, n)), 4.0 * rng.standard_normal(m), rng.standard_normal(n)
    W = rng.standard_normal((n, n))
    AVA, AVm = W @ W.T, rng.standard_normal(n)
    out = boxed_step(M, F, g, lo, hi, x_bar, None, AVA, AVm)
    u_bar, free, _ = box_qp(M, F @ x_bar - g, lo, hi)
    if out is None:      # the unbounded controller inside the box: then the box QP is it
        assert free.all()
        return
    k, G, Vinv, Vv = out
    tol = max(REL, bound(4 * (m + n), cond_of(M)))
    assert_close(k + G @ x_bar, u_bar, rel=tol, scale=1.0)
    assert np.all(G[~free] == 0.0)
    for _ in range(3):
        x = x_bar + 1e-6 * rng.standard_normal(n)
        u, f2, _ = box_qp(M, F @ x - g, lo, hi)
        if np.array_equal(f2, free):
            assert_close(k + G @ x, u, rel=tol, scale=1.0)

    def J(x):
        u = k + G @ x
        return 0.5 * u @ M @ u - u @ (g - F @ x) + 0.5 * x @ AVA @ x - x @ AVm
    E = np.eye(n)
    hess = np.array([[J(E[i] + E[j]) - J(E[i]) - J(E[j]) + J(0 * E[0]) for j in range(n)] for i in range(n)])
    grad0 = np.array([(J(E[i]) - J(-E[i])) / 2.0 for i in range(n)])
    scale = float(np.abs(AVA).max() + np.abs(M).max() * (1 + np.abs(G).max()) ** 2 + np.abs(F).max())
    assert_close(Vinv, hess, rel=tol, scale=scale)
    assert_close(-Vv, grad0, rel=tol, scale=scale * (1 + np.abs(k).max()) + np.abs(g).max())


def bounded_lq(T: int = 12):
    """``make_lq(seed=2, running=5)`` with both controls within +-0.8 (as efforts), which its unconstrained
    optimum leaves (up to 5.4), and nothing else bounded."""
    pb = make_lq(seed=2, running=5.0, T=T)
    b = Bounds(u_lower=np.full(N_U, -0.8), u_upper=np.full(N_U, 0.8))
    return pb, dataclasses.replace(pb, bounds=b)


def active_set_optimum(pb, at_lo: np.ndarray, at_hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The QP of ``pb`` (the LQ terms, the dynamics) with the controls ``at_lo``/``at_hi`` (``(T, m)`` masks) held
    at their bounds, by its KKT system: ``X``, ``U`` and the multipliers of the held controls (their sign says
    whether the point is the optimum of the box-constrained QP)."""
    n, m, T, dyn, b = pb.n_x, pb.n_u, pb.T, pb.dynamics, pb.bounds
    R, r = pb.quadratize_states(np.zeros((T + 1, n)))
    H, h = pb.quadratize_controls(np.zeros((T, m)))
    off, nz = (T + 1) * n, (T + 1) * n + T * m
    Hq, g = np.zeros((nz, nz)), np.zeros(nz)
    for t in range(T + 1):
        Hq[t * n:(t + 1) * n, t * n:(t + 1) * n], g[t * n:(t + 1) * n] = R[t], r[t]
    for t in range(T):
        s = slice(off + t * m, off + (t + 1) * m)
        Hq[s, s], g[s] = H[t], h[t]
    rows, rhs = [], []
    e = np.eye(n)
    row = np.zeros((n, nz))
    row[:, :n] = e
    rows.append(row), rhs.append(pb.x0)
    for t in range(T):
        row = np.zeros((n, nz))
        row[:, (t + 1) * n:(t + 2) * n], row[:, t * n:(t + 1) * n] = e, -dyn.A
        row[:, off + t * m:off + (t + 1) * m] = -dyn.B
        rows.append(row), rhs.append(dyn.a)
    held = np.flatnonzero((at_lo | at_hi).reshape(-1))
    Ch = np.zeros((len(held), nz))
    Ch[np.arange(len(held)), off + held] = 1.0
    C = np.vstack([*rows, Ch])
    d = np.concatenate([*rhs, np.where(at_lo, b.u_lower, b.u_upper).reshape(-1)[held]])
    kkt = np.block([[Hq, C.T], [C, np.zeros((len(C), len(C)))]])
    z = np.linalg.solve(kkt, np.concatenate([g, d]))
    # stationarity Hq z - g + C^T nu = 0: a held control's nu is minus its cost's gradient, which must push
    # it outward (at a lower bound nu <= 0 here: -grad <= 0; at an upper bound nu >= 0)
    nu = z[nz + (T + 1) * n:]
    return z[:off].reshape(T + 1, n), z[off:nz].reshape(T, m), np.where(at_lo.reshape(-1)[held], -nu, nu)


@pytest.mark.numerics
@pytest.mark.compiled
@pytest.mark.parametrize("schedule, alpha", [("robust", 1.0), ("fixed", 1.0), ("adaptive", 1.0), ("fixed", 0.0)])
def test_boxddp_reaches_the_bounded_lq_optimum(schedule, alpha):
    """On the LQ problem with controls boxed, R-AICO (and plain AICO, ``alpha = 0``, relinearizing inside its
    sweeps) with the box in its backward pass converges to the bounded
    QP's optimum: the KKT point of the plan's active set, certified by every held control's multiplier sign,
    has the plan's cost to the rounding of that system and its states and controls to 1e-5 (the stopping rule's
    reach); every control within its box, no multiplier in the message (no augmented Lagrangian)."""
    free, pb = bounded_lq()
    u_out = pb.bounds.violation(*exact_solution(free))[1]
    assert u_out > 1.0
    res = aico(pb, AICOOptions(iterations=60, alpha=alpha, schedule=schedule, control_box="boxddp", tol_rel=1e-12))
    assert res.status is Status.CONVERGED and "multiplier" not in res.message, res.message
    lo, hi = pb.bounds.u_lower, pb.bounds.u_upper
    assert np.all((res.U >= lo) & (res.U <= hi))
    at_lo, at_hi = res.U == lo, res.U == hi
    assert at_lo.any() and at_hi.any() and not (at_lo | at_hi).all()
    X, U, push = active_set_optimum(pb, at_lo, at_hi)
    assert np.all(push >= 0.0), push
    R, _ = pb.quadratize_states(np.zeros((pb.T + 1, pb.n_x)))
    tol = max(REL, bound(pb.T * (pb.n_x + pb.n_u), cond_of(R[-1] + np.eye(pb.n_x), pb.dynamics.A)))
    assert pb.cost(res.X, res.U) == pytest.approx(pb.cost(X, U), rel=tol)
    # the plan stops on its cost's change, which near the optimum is quadratic in the distance to it: the
    # states and controls agree to about the square root of that (the unbounded LQ tests' 1e-6)
    assert np.abs(res.U - U).max() <= 1e-5 * np.abs(U).max() and np.abs(res.X - X).max() <= 1e-5 * np.abs(X).max()


@pytest.mark.numerics
@pytest.mark.compiled
def test_boxddp_with_a_box_never_active_gives_the_unbounded_iterates():
    """A box far beyond the unbounded plan's controls: the backward pass never clamps and the iterates are the
    unbounded run's (the sweeps in Python against compiled: equal to rounding)."""
    free, _ = bounded_lq()
    b = Bounds(u_lower=np.full(N_U, -1e3), u_upper=np.full(N_U, 1e3))
    runs = [aico(p, AICOOptions(iterations=15, alpha=1.0, schedule="robust", control_box="boxddp"))
            for p in (free, dataclasses.replace(free, bounds=b))]
    assert runs[0].iterations == runs[1].iterations
    assert_close(runs[1].X, runs[0].X, rel=max(REL, bound(free.T * free.n_x * 15)))


@pytest.mark.compiled
def test_the_capability_and_the_option_say_where_the_box_applies():
    """Only solvers declaring ``control_box_methods`` take it; it applies to a box on the controls, not to the
    torques of accelerations as controls (their limit is no box); unknown methods are refused."""
    free, pb = bounded_lq()
    assert applies(pb) and not applies(free)
    assert not applies(dataclasses.replace(free, bounds=Bounds(q_index=np.array([0]), q_lower=np.array([-1.0]),
                                                                 q_upper=np.array([1.0]))))
    takers = [s for s in SOLVERS.values() if "boxddp" in s.caps.control_box_methods]
    assert takers and all(s.caps.control_box for s in takers)
    with pytest.raises(ValueError, match="control_box must be one of"):
        AICOOptions(control_box="box")
    assert math.isfinite(aico(pb, AICOOptions(iterations=3, alpha=1.0, schedule="robust",
                                              control_box="boxddp")).cost)
