"""The hard constraints' augmented Lagrangian (raico/planning/constraints.py): its gradient against finite
differences, its Gauss-Newton Hessian against the exact one where the active set holds, the per-step box of a
start outside a range, and the direct-transcription reference against the bounded LQ problem's QP."""

from __future__ import annotations

import numpy as np
import pytest

from raico.planning.constraints import AugmentedLagrangian, ControlBox, FunctionConstraint, StateBox, reachable_box
from raico.plants.numdiff import numdiff_jacobian
from tests.planning.test_aico_robust import bounded_lq, bounded_qp_optimum

T, N, M = 4, 3, 2


def _set(rng: np.random.Generator) -> tuple[AugmentedLagrangian, np.ndarray, np.ndarray]:
    """A state box, a control box and a nonlinear ``g(x) = 0.5 - |x|^2`` (a distance-like constraint) with
    random multipliers; the point ``X (T+1, N)``, ``U (T, M)`` puts some rows of each inside, some outside."""
    lo, hi = np.full((T + 1, 2), -0.3), np.full((T + 1, 2), 0.3)

    def dist(X, U):
        G = (0.5 - np.sum(X * X, axis=1))[:, None]
        return G, (-2.0 * X)[:, None, :], None
    cons = [StateBox("range", [0, 2], lo, hi, 1e-4),
            ControlBox("effort", [0, 1], np.array([-0.5, -0.2]), np.array([0.5, 0.2]), np.full(2, 1e-4), scale=3.0),
            FunctionConstraint("distance", dist, np.array([1e-3]))]
    al = AugmentedLagrangian(cons, T, mu=7.0)
    X, U = rng.normal(scale=0.5, size=(T + 1, N)), rng.normal(scale=0.5, size=(T, M))
    al.y = [np.abs(rng.normal(size=(T + 1, 4))) * (rng.random((T + 1, 4)) < 0.5),
            np.abs(rng.normal(size=(T + 1, 4))) * (rng.random((T + 1, 4)) < 0.5), None]
    return al, X, U


def _central(f, Z: np.ndarray, h: float = 1e-6) -> dict:
    """Central differences of ``f`` at ``Z`` along each entry: ``{idx: (f(Z + h e) - f(Z - h e)) / 2h}``."""
    out = {}
    for idx in np.ndindex(Z.shape):
        Zp, Zm = Z.copy(), Z.copy()
        Zp[idx] += h
        Zm[idx] -= h
        out[idx] = (f(Zp) - f(Zm)) / (2 * h)
    return out


def test_the_merit_gradient_matches_finite_differences():
    """``l_x``, ``l_u`` of :meth:`AugmentedLagrangian.model` are the gradient of :meth:`value` (a sum of
    piecewise quadratics, C1: central differences with step 1e-6 have error O(1e-12 / 1e-6) away from kinks;
    tolerance 1e-5)."""
    rng = np.random.default_rng(3)
    al, X, U = _set(rng)
    lx, _, lu, _ = al.model(X, U)
    for g, f in ((lx, lambda Z: al.value(Z, U)), (lu, lambda Z: al.value(X, Z))):
        fd = np.array(list(_central(f, X if g is lx else U).values())).reshape(g.shape)
        assert np.allclose(g, fd, atol=1e-5), np.abs(g - fd).max()


def test_the_box_hessian_is_exact_where_the_active_set_holds():
    """On the boxes (linear rows) the Gauss-Newton Hessian is the exact one: differences of the gradient
    with step 1e-7 (no kink crossed at this point) give it to 1e-6."""
    rng = np.random.default_rng(5)
    al, X, U = _set(rng)
    al.constraints = al.constraints[:2]
    al.y = al.y[:2]
    _, lxx, _, luu = al.model(X, U)
    h = 1e-7
    for t in range(1, T):
        for i in range(N):
            Xp = X.copy()
            Xp[t, i] += h
            d = (al.model(Xp, U)[0][t] - al.model(X, U)[0][t]) / h
            assert np.allclose(d, lxx[t, :, i], atol=1e-6)
    for t in range(T):
        for i in range(M):
            Up = U.copy()
            Up[t, i] += h
            d = (al.model(X, Up)[2][t] - al.model(X, U)[2][t]) / h
            assert np.allclose(d, luu[t, :, i], atol=1e-6)


def test_nothing_active_adds_nothing():
    """Rows far inside and no multipliers: no model, a merit term of exactly 0."""
    lo, hi = np.full((T + 1, 1), -10.0), np.full((T + 1, 1), 10.0)
    al = AugmentedLagrangian([StateBox("range", [1], lo, hi, 1e-4)], T, mu=1e3)
    X, U = np.full((T + 1, N), 0.1), np.zeros((T, M))
    assert al.model(X, U) is None and al.value(X, U) == 0.0 and al.violation(X, U) == 0.0


def test_reachable_box_follows_the_velocity_limit():
    """A joint 1 rad below its range with velocity limit 2 rad/s at dt = 0.1: inside from the step where ``(t -
    1) dt vmax`` reaches 1 rad (t = 6); a joint inside keeps its range; no limit: the range from step 1."""
    lo, hi = np.array([0.0, -1.0, 0.0]), np.array([1.0, 1.0, 1.0])
    q0 = np.array([-1.0, 0.0, 3.0])
    L, H = reachable_box(lo, hi, q0, np.array([2.0, 2.0, np.inf]), 0.1, 8)
    assert np.allclose(L[:, 0], [-1.0, -1.0, -0.8, -0.6, -0.4, -0.2, 0.0, 0.0, 0.0])
    assert np.all(L[:, 1] == -1.0) and np.all(H[:, 1] == 1.0)
    assert np.all(H[1:, 2] == 1.0) and H[0, 2] == 3.0


@pytest.mark.parametrize("solver", ["ipopt", "snopt"])
def test_direct_transcription_matches_the_bounded_qp(solver):
    """The direct-transcription reference on the bounded LQ problem reaches the QP's optimum (SLSQP, ftol
    1e-10) to 1e-6 relative (IPOPT's tol 1e-8 on a cost of order 1e3), with dynamics defects at rounding."""
    from raico.planning.transcription import transcribe

    _, pb = bounded_lq(T=12)
    t = transcribe(pb, np.tile(pb.x0, (pb.T + 1, 1)), np.zeros((pb.T, pb.n_u)), solver=solver)
    assert t.success and t.defect <= 1e-9, t.message
    assert t.cost == pytest.approx(bounded_qp_optimum(pb), rel=1e-6)


# crocoddyl's Kinova from its own start (raico/problems/crocoddyl/kinova_reach.toml, joint 3 1.9 rad below its range,
# velocity limit 0.63 rad/s): the best feasible cost known, from raico.planning.transcription (SNOPT from x0 held,
# kSolutionFound, dynamics defect 1e-12, every bound kept; 485 s on a shared 2-core machine, too slow for a test)
KINOVA_BEST_FEASIBLE = 13.8886


def test_kinova_from_its_own_start_is_feasible_and_within_1_1x_of_the_best_feasible():
    """The robust schedule with the hard bounds: every bound kept (status not out-of-bounds), the message says the
    start was outside, the cost at most 1.1x the direct transcription's (and no lower than it by more than its
    stopping tolerance allows: a lower cost would be a plan outside the bounds)."""
    from pathlib import Path

    from raico.planning.aico import AICOOptions, aico
    from raico.planning.problem import Status
    from raico.stages.plan.stage import PlanConfig, build_problem

    root = Path(__file__).resolve().parents[2]
    cfg = PlanConfig(problem=str(root / "raico/problems/crocoddyl/kinova_reach.toml"), dynamics="analytic", q0_std=0.0,
                     solver="raico", alpha=1.0, alpha_schedule="robust", bounds="hard").normalized()
    pb = build_problem(cfg)[2]
    res = aico(pb, AICOOptions(iterations=300, alpha=1.0, schedule="robust"))
    assert res.status is not Status.OUT_OF_BOUNDS and res.status is not Status.DIVERGED, res.message
    assert "the start is outside a joint range" in res.message
    assert KINOVA_BEST_FEASIBLE * (1 - 1e-3) <= res.cost <= 1.1 * KINOVA_BEST_FEASIBLE, res.cost


@pytest.mark.numerics
@pytest.mark.compiled
def test_the_torque_rows_derivatives_match_finite_differences():
    """:class:`TorqueBox` (the torques ``M(q) u + h(q, v)`` of accelerations ``u``, in fractions of the effort
    limit): the Jacobians it adds (``lam = 1`` on every row: ``l_x = sum_c G_x``) against central differences
    of its values (step 1e-6 on a smooth map: error O(1e-12), tolerance 1e-6 of the rows' scale)."""
    from raico.planning.constraints import TorqueBox
    from raico.plants.dynamics_registry import make_dynamics
    from raico.plants.robots import shared_robot

    robot = shared_robot("arm5")
    model = make_dynamics("analytic", robot, 0.01)
    n, steps = robot.n_q, 3
    rng = np.random.default_rng(11)
    X = np.concatenate([rng.normal(scale=0.7, size=(steps + 1, n)), rng.normal(size=(steps + 1, n))], axis=1)
    U = rng.normal(scale=3.0, size=(steps, n))
    limit = np.full(n, 2.0)
    limit[1] = np.inf
    box = TorqueBox("effort", model, limit, 1e-4)
    k = 2 * len(box.idx)
    lx, lxx = np.zeros((steps + 1, 2 * n)), np.zeros((steps + 1, 2 * n, 2 * n))
    lu, luu = np.zeros((steps, n)), np.zeros((steps, n, n))
    lam = np.ones((steps + 1, k))
    box.add_derivatives(X, U, lam, 1.0, lx, lxx, lu, luu)

    def rows(Xa, Ua):   # the sum of every finite row per step: its gradient is l_x, l_u above
        return np.where(np.isfinite(G := box.values(Xa, Ua)), G, 0.0).sum(axis=1)
    for Z, g in ((X, lx), (U, lu)):
        d = _central(lambda W, Z=Z: rows(W, U) if Z is X else rows(X, W), Z)
        fd = np.array([d[idx][idx[0]] for idx in np.ndindex(Z.shape)]).reshape(Z.shape)
        scale = max(1.0, float(np.abs(g).max()))
        assert np.allclose(g, fd, atol=1e-6 * scale, rtol=0.0), np.abs(g - fd).max()
    # the two rows of a joint are +-tau / limit - 1: their gradients cancel in the sum, so check one row
    one = np.zeros_like(lam)
    one[:, 0] = 1.0
    lx1, lu1 = np.zeros_like(lx), np.zeros_like(lu)
    box.add_derivatives(X, U, one, 1.0, lx1, np.zeros_like(lxx), lu1, np.zeros_like(luu))
    for t in range(steps):
        f = lambda z, t=t: box.values(np.vstack([X[:t], z[None, :], X[t + 1:]]), U)[t, :1]  # noqa: E731
        fd = numdiff_jacobian(f, X[t])[0]
        assert np.allclose(lx1[t], fd, atol=1e-6 * max(1.0, np.abs(fd).max()), rtol=0.0)
        tau = model.inverse_dynamics(X[t, :n], X[t, n:], U[t])
        assert np.isclose(box.values(X, U)[t, 0], tau[box.idx[0]] / limit[box.idx[0]] - 1.0, rtol=1e-9, atol=1e-9)


def test_pseudo_dynamics_bounds_carry_the_torques_of_a_fixed_base_robot_only():
    """For acceleration controls the hard bounds bound the torques of the accelerations (a welded robot),
    not those of a robot on its soles (its welded model's torques are not its motors')."""
    from raico.plants.robots import shared_robot
    from raico.stages.plan.stage import hard_bounds

    arm = hard_bounds(shared_robot("pendulum"), "acceleration", 0.002)
    assert arm is not None and arm.has_torques and not arm.has_controls
    assert hard_bounds(shared_robot("pendulum"), "acceleration") is None or not hard_bounds(
        shared_robot("pendulum"), "acceleration").has_torques
    nao = hard_bounds(shared_robot("nao"), "acceleration", 0.01)
    assert nao is None or not nao.has_torques
