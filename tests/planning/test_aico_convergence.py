"""R-AICO's robust schedule near the optimum: the cost's cross term ``l_ux`` kept by a change of controls
(:mod:`raico.planning.aico.cross`), checked on an LQ problem whose exact optimum is known and against finite
differences, and the fall of lambda after good steps (:func:`raico.planning.aico.steps.lambda_after`) on
synthetic ratios."""

from __future__ import annotations

import numpy as np
import pytest

from raico.planning.aico import AICOOptions, aico
from raico.planning.aico.steps import FALL_MAX, VERY_GOOD, lambda_after
from raico.planning.costs import JointTerm
from raico.planning.problem import Problem
from tests.planning.test_solvers_lq import exact_solution, make_lq
from tests.tolerance import REL

pytestmark = pytest.mark.compiled   # reaches a C kernel: run under the sanitizers too


class LinearControlTarget(JointTerm):
    """``c_t = w |u_t - G x_t - g0|^2`` at ``t = 0..T-1``: the control toward a target linear in the state (the
    control toward gravity with a linear ``g``), exactly quadratic, its cross term ``l_ux = -2 w G``."""

    def __init__(self, G: np.ndarray, g0: np.ndarray, weight: float, T: int, name: str = "linear_target"):
        self.G, self.g0, self.weight, self.T, self.name = G, g0, weight, T, name
        self.times = np.arange(T)

    def joint_value(self, X, U):
        r = np.atleast_2d(U) - np.atleast_2d(X) @ self.G.T - self.g0
        return self.weight * np.einsum("ki,ki->k", r, r)

    def add_derivatives(self, X, idx, lx, lxx):
        m = self.active(np.asarray(idx))
        if self._U is None or not m.any():
            return
        r = self._U[np.asarray(idx)[m]] - X[m] @ self.G.T - self.g0
        lx[m] += -2.0 * self.weight * r @ self.G
        lxx[m] += 2.0 * self.weight * self.G.T @ self.G

    def add_control_derivatives(self, U, lu, luu):
        luu += 2.0 * self.weight * np.eye(U.shape[1])
        if self._X is not None and len(U) == len(self._X):
            lu += 2.0 * self.weight * (U - self._X @ self.G.T - self.g0)

    def add_cross_derivatives(self, X, lux):
        lux += -2.0 * self.weight * self.G


def lq_with_cross_term(seed: int = 3) -> Problem:
    """``make_lq(seed, running=5)`` plus a :class:`LinearControlTarget` of weight 0.5."""
    pb = make_lq(seed=seed, running=5.0)
    rng = np.random.default_rng(seed + 100)
    term = LinearControlTarget(0.8 * rng.standard_normal((pb.n_u, pb.n_x)), 0.3 * rng.standard_normal(pb.n_u),
                               0.5, pb.T)
    return Problem(pb.dynamics, pb.x0, pb.T, pb.state_terms, pb.control_terms, [term])


def exact_solution_with_cross(pb: Problem) -> tuple[np.ndarray, np.ndarray]:
    """The QP's optimum with the joint term's cross blocks ``l_ux``: ``exact_solution``'s KKT system with
    them put in (the terms are exactly quadratic)."""
    n, m, T = pb.n_x, pb.n_u, pb.T
    Z = (np.zeros((T + 1, n)), np.zeros((T, m)))
    pb.set_nominal(*Z)
    L = np.zeros((T, m, n))
    for term in pb.joint_terms:
        term.add_cross_derivatives(Z[0][:T], L)
    return exact_solution(pb, L)


@pytest.mark.numerics
def test_exact_kkt_of_the_cross_term_problem_is_its_minimum():
    """The reference: the optimum of the KKT system with the cross blocks costs less than the one without
    (``exact_solution`` drops them), and its gradient in the controls through the dynamics vanishes."""
    pb = lq_with_cross_term()
    X, U = exact_solution_with_cross(pb)
    X0, U0 = exact_solution(pb)
    assert pb.cost(X, U) < pb.cost(X0, U0)
    rng = np.random.default_rng(0)
    for _ in range(3):     # a feasible perturbation (the dynamics rolled out) raises the cost
        dU = 1e-3 * rng.standard_normal(U.shape)
        Xp = [pb.x0]
        for t in range(pb.T):
            Xp.append(pb.dynamics.A @ Xp[-1] + pb.dynamics.a + pb.dynamics.B @ (U[t] + dU[t]))
        assert pb.cost(np.array(Xp), U + dU) > pb.cost(X, U)


def iterations_to_optimum(pb: Problem, X: np.ndarray, **kw) -> int | None:
    """The first iteration of the robust schedule (``kw``: its options) within 1e-6 of ``X``, or ``None``."""
    its: list[np.ndarray] = []
    aico(pb, AICOOptions(**{"iterations": 30, "alpha": 1.0, "schedule": "robust", "tol_rel": 0.0, **kw}),
         callback=lambda rec, Xi, Ui: its.append(Xi.copy()))
    return next((i + 1 for i, Xi in enumerate(its) if np.abs(Xi - X).max() <= 1e-6 * np.abs(X).max()), None)


@pytest.mark.numerics
@pytest.mark.parametrize("fall", ["nielsen", "accelerated"])
def test_robust_schedule_with_the_cross_term_reaches_the_exact_lq_optimum(fall):
    """With ``cross_terms`` the robust schedule's model is the problem itself: the exact optimum (with the
    cross term) to 1e-6 of the trajectory and 1e-9 of the cost, in fewer iterations than without it (the
    gradient is exact either way; the Hessian without ``l_ux`` makes the convergence linear)."""
    pb = lq_with_cross_term()
    X, U = exact_solution_with_cross(pb)
    res = aico(pb, AICOOptions(iterations=60, alpha=1.0, schedule="robust", lambda_fall=fall, tol_rel=0.0))
    assert np.abs(res.X - X).max() <= 1e-6 * np.abs(X).max()
    assert res.cost == pytest.approx(pb.cost(X, U), rel=REL)
    on = iterations_to_optimum(pb, X, lambda_fall=fall)
    off = iterations_to_optimum(pb, X, lambda_fall=fall, cross_terms=False)
    assert on is not None and (off is None or on < off), (on, off)


@pytest.mark.numerics
def test_accelerated_fall_reaches_the_lq_optimum_in_fewer_iterations():
    """On the LQ problem (model exact, every ratio 1) the accelerated fall reaches the optimum to 1e-6 in
    fewer iterations than Nielsen's rule (lambda 1, /10, /100, /1000 instead of /10 per step)."""
    pb = lq_with_cross_term()
    X, _ = exact_solution_with_cross(pb)
    hits = {fall: iterations_to_optimum(pb, X, lambda_fall=fall) for fall in ("nielsen", "accelerated")}
    assert hits["accelerated"] is not None and hits["nielsen"] is not None
    assert hits["accelerated"] < hits["nielsen"], hits


@pytest.mark.numerics
def test_control_toward_gravity_cross_derivative_against_finite_differences():
    """``ControlGravity.add_cross_derivatives`` (``l_ux = -2 w C G``) against central differences of its
    ``l_u`` in the state, on arm5 at random states."""
    from raico.planning.costs import ControlGravity
    from raico.plants.numdiff import compare, numdiff_rows
    from raico.plants.robots import shared_robot

    robot = shared_robot("arm5")
    K = 6
    term = ControlGravity(robot, 0.3, K, precision=np.linspace(0.5, 2.0, robot.n_q))
    rng = np.random.default_rng(4)
    X = np.concatenate([robot.default_q, np.zeros(robot.n_q)]) + 0.3 * rng.standard_normal((K, 2 * robot.n_q))
    U = 2.0 * rng.standard_normal((K, robot.n_q))

    def lu(Xr):
        term.set_nominal(np.vstack([Xr, Xr[-1:]]), U)
        return term.control_derivatives(U)[0]

    fd = numdiff_rows(lu, X, 1e-6)
    L = np.zeros((K, robot.n_q, 2 * robot.n_q))
    term.add_cross_derivatives(X, L)
    check = compare("l_ux vs FD of l_u", L, fd, atol=1e-6, rtol=1e-6)
    assert check.passed, str(check)


def test_lambda_after_nielsen_on_synthetic_ratios():
    """Nielsen's rule: ``lambda max(1/lm_factor, 1 - (2 min(rho, 1) - 1)^3)``; no streak is kept."""
    o = AICOOptions(alpha=1.0, schedule="robust", lambda_fall="nielsen")
    assert lambda_after(1.0, 1.0, 0, o) == (pytest.approx(0.1), 0)          # capped at /lm_factor
    assert lambda_after(1.0, 1.7, 5, o) == (pytest.approx(0.1), 0)
    assert lambda_after(1.0, 0.5, 0, o)[0] == pytest.approx(1.0)            # 1 - 0^3
    assert lambda_after(1.0, 0.75, 0, o)[0] == pytest.approx(1.0 - 0.5 ** 3)
    assert lambda_after(1.0, 0.2, 0, o)[0] == pytest.approx(1.0 + 0.6 ** 3)  # a poor step: lambda grows
    assert lambda_after(1e-9, 1.0, 0, o)[0] == o.lambda_min                  # within [lambda_min, lambda_max]


def test_lambda_after_accelerated_on_synthetic_ratios():
    """The accelerated fall: very good steps in a row divide lambda by 10, 100, 1000, 1000, ...; a step
    below VERY_GOOD takes Nielsen's rule and ends the streak; lambda_min bounds it."""
    o = AICOOptions(alpha=1.0, schedule="robust", lambda_fall="accelerated")
    lam, streak, seen = 1e3, 0, []
    for rho in (1.0, 0.9, 1.6, VERY_GOOD, 1.0):
        new, streak = lambda_after(lam, rho, streak, o)
        seen.append(lam / new)
        lam = new
    assert seen == pytest.approx([10.0, 100.0, 1e3, 1e3, 1e3]) and FALL_MAX == 3 and streak == 5
    new, streak = lambda_after(1.0, 0.6, streak, o)      # good, not very good: Nielsen, the streak ends
    assert new == pytest.approx(1.0 - 0.2 ** 3) and streak == 0
    assert lambda_after(1.0, 1.0, streak, o) == (pytest.approx(0.1), 1)
    assert lambda_after(1e-8, 1.0, 2, o)[0] == o.lambda_min
    with pytest.raises(ValueError, match="lambda_fall"):
        AICOOptions(alpha=1.0, schedule="robust", lambda_fall="fast")
