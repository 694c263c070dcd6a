"""Cost terms: the Gauss-Newton model and task message, inactive steps, control
limits, the problem's sums. Every term class's gradient and Hessian against finite
differences: ``tests/plants/test_derivatives.py`` (``COST_TERM_EXAMPLES``)."""

from __future__ import annotations

import numpy as np
import pytest

from raico.planning.costs import ControlCost, ControlLimit, StateTarget, ViaPoint
from raico.planning.problem import Problem
from raico.plants.dynamics import PseudoDynamics
from raico.plants.numdiff import check_cost_term, check_taskmap, numdiff_jacobian
from tests.tolerance import assert_close
from tests.toys import PlanarArm

pytestmark = pytest.mark.numerics   # compares floating-point results (make test-portable)

RNG = np.random.default_rng(0)
N_Q = 3
N_X = 2 * N_Q
ARM = PlanarArm([0.5, 0.4, 0.3])


def test_planar_arm_jacobian_matches_fd():
    """The toy task map of the solver tests (not a registered example)."""
    check_taskmap(ARM, RNG.standard_normal((2, N_Q)), atol=1e-8).assert_passed()


def _state_terms():
    return [
        ViaPoint(ARM, [0.3, 0.9], times=[2, 4], weight=1e4, precision=[1.0, 3.0], name="via"),
        ViaPoint(ARM, [0.1, -0.2], times=None, weight=7.0, name="via_all"),
        StateTarget(RNG.standard_normal(N_X), times=[1, 3], weight=2.0,
                    precision=RNG.uniform(0.5, 2, N_X), name="target"),
    ]


@pytest.mark.parametrize("term", _state_terms(), ids=lambda t: t.name)
def test_state_term_derivatives_on_the_toy_arm_and_zero_when_inactive(term):
    X = RNG.standard_normal((6, N_X))
    idx = np.arange(6)
    check_cost_term(lambda Z: term.value(Z, idx), lambda Z: term.derivatives(Z, idx), X).assert_passed()
    lx, lxx = term.derivatives(X)
    assert lx.shape == (6, N_X) and lxx.shape == (6, N_X, N_X)
    inactive = ~term.active(idx)
    want = {"via": [False, False, True, False, True, False], "via_all": [True] * 6,
            "target": [False, True, False, True, False, False]}[term.name]
    assert (~inactive).tolist() == want
    assert not lx[inactive].any() and not lxx[inactive].any()
    assert np.all(np.abs(lx[~inactive]).sum(1) > 0)  # active steps do contribute


def test_via_point_gauss_newton_hessian_and_message():
    """``l_xx = 2 w J^T C J`` (J by finite differences), exact Hessian at a zero residual, and
    the message ``R = 2 w J^T C J``, ``r = 2 w J^T C (x* - phi(q0) + J q0)`` on the q block."""
    w, Cd = 1e4, np.array([1.0, 3.0])
    x = RNG.standard_normal(N_X)
    q = x[:N_Q]
    target = np.array([0.3, 0.9])
    term = ViaPoint(ARM, target, times=[0], weight=w, precision=Cd)
    J = numdiff_jacobian(lambda z: ARM.value_and_jacobian(z)[0], q)
    _, lxx = term.derivatives(x[None, :], [0])
    GN = 2 * w * J.T @ np.diag(Cd) @ J
    assert np.allclose(lxx[0][:N_Q, :N_Q], GN, rtol=1e-6, atol=1e-4)
    assert not lxx[0][N_Q:].any() and not lxx[0][:, N_Q:].any()
    R, r = term.quadratize(x[None, :], [0])
    phi0 = ARM.value_and_jacobian(q)[0]
    assert np.allclose(R[0][:N_Q, :N_Q], GN, rtol=1e-6, atol=1e-4)
    r_expected = 2 * w * J.T @ np.diag(Cd) @ (target - phi0 + J @ q)
    assert np.allclose(r[0][:N_Q], r_expected, rtol=1e-6, atol=1e-4)
    assert not r[0][N_Q:].any()
    # at a zero residual the Gauss-Newton Hessian is the exact Hessian
    zero = ViaPoint(ARM, phi0, times=[0], weight=w, precision=Cd)
    H_fd = numdiff_jacobian(lambda z: zero.derivatives(z[None, :], [0])[0][0], x, eps=1e-5)
    assert np.allclose(zero.derivatives(x[None, :], [0])[1][0], H_fd, rtol=1e-5, atol=1e-3)


def _control_terms():
    return [
        ControlCost(1e-2, name="control"),
        ControlCost(0.5, target=[0.3, -1.0], name="control_target"),
        ControlLimit([-1.0, -2.0], [1.0, 0.5], weight=1e3, name="limit"),
    ]


def _control_closed_form(name, U):
    """``l_u``, ``l_uu`` of the terms of ``_control_terms`` by hand: ``w |u - target|^2`` and
    ``w |u - clip(u, lower, upper)|^2``."""
    eye = np.broadcast_to(np.eye(2), (len(U), 2, 2))
    if name == "control":
        return 2 * 1e-2 * U, 2 * 1e-2 * eye
    if name == "control_target":
        return 2 * 0.5 * (U - [0.3, -1.0]), 2 * 0.5 * eye
    lo, hi = np.array([-1.0, -2.0]), np.array([1.0, 0.5])
    outside = (U < lo) | (U > hi)
    return 2e3 * (U - np.clip(U, lo, hi)), 2e3 * outside[:, :, None] * eye


@pytest.mark.parametrize("term", _control_terms(), ids=lambda t: t.name)
def test_control_term_quadratize_matches_derivatives(term):
    U = np.array([[0.2, 0.1], [1.7, -3.0], [-1.4, 0.9], [0.0, 0.0]])   # inside / outside
    lu, luu = term.derivatives(U)
    lu_want, luu_want = _control_closed_form(term.name, U)
    assert_close(lu, lu_want, scale=1.0)
    assert_close(luu, luu_want, scale=1.0)
    H, h = term.quadratize(U)
    assert_close(H, luu_want, scale=1.0)   # exact for these terms (up to rounding)
    assert np.allclose(np.einsum("kij,kj->ki", H, U) - h, lu)      # gradient of the model


def test_control_limit_values():
    lim = ControlLimit(-1.0, 2.0, weight=10.0)
    U = np.array([[0.0], [3.0], [-1.5]])
    assert np.allclose(lim.value(U), [0.0, 10.0, 2.5])
    H, h = lim.quadratize(U)
    assert np.allclose(H[:, 0, 0], [0.0, 20.0, 20.0])
    assert np.allclose(h[:, 0], [0.0, 40.0, -20.0])          # 2 w * (violated limit)


def test_problem_sums_terms_and_zero_weight_switches_off():
    T = 5
    dyn = PseudoDynamics(N_Q, 0.01)
    terms = _state_terms()
    pb = Problem(dyn, np.zeros(N_X), T, terms, [ControlCost(1e-2)])
    X = RNG.standard_normal((T + 1, N_X))
    U = RNG.standard_normal((T, N_Q))
    by_term = pb.cost_terms(X, U)
    assert set(by_term) == {"via", "via_all", "target", "control"}
    assert pb.cost(X, U) == pytest.approx(sum(by_term.values()))
    assert by_term["control"] == pytest.approx(1e-2 * np.sum(U * U))
    lx, _ = pb.state_derivatives(X)
    lx2 = sum(t.derivatives(X)[0] for t in terms)
    assert np.allclose(lx, lx2)
    assert pb.without("via").cost(X, U) == pytest.approx(pb.cost(X, U) - by_term["via"])
    terms[0].weight = 0.0
    assert pb.cost_terms(X, U)["via"] == 0.0
    with pytest.raises(ValueError, match="unique"):
        Problem(dyn, np.zeros(N_X), T, [terms[0], terms[0]], [])
    with pytest.raises(ValueError, match="times"):
        Problem(dyn, np.zeros(N_X), 3, [terms[0]], [])       # via-point at step 4 > T
