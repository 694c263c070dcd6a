"""R-AICO's robust schedule (Levenberg-Marquardt style, invariant to the cost's scale) on problems whose
answer is known: the exact LQ solution, the same iterates whatever the cost's scale, and the acceptance
rule on trials whose outcome is known."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from raico.planning.aico import AICOOptions, aico
from raico.planning.aico.bounds import cost_curvature
from raico.planning.aico.steps import RobustStep
from raico.planning.aico.sweeps import Sweeps
from raico.planning.driver import Iterate
from raico.planning.problem import Status
from tests.planning.test_solvers_lq import N_U, T, exact_solution, make_lq

pytestmark = pytest.mark.compiled   # reaches a C kernel: run under the sanitizers too


def scaled_lq(scale: float):
    """``make_lq(seed=2, running=5)`` with every term's weight multiplied by ``scale``."""
    pb = make_lq(seed=2, running=5.0)
    for term in pb.all_terms():
        term.weight *= scale
    return pb


def run(pb, **kw):
    iterates = []
    res = aico(pb, AICOOptions(**{"iterations": 40, "alpha": 1.0, "schedule": "robust", **kw}),
               callback=lambda rec, X, U: iterates.append((X.copy(), U.copy())))
    return res, iterates


@pytest.mark.numerics
@pytest.mark.parametrize("fall", ["accelerated", "nielsen"])
def test_robust_schedule_reaches_the_exact_lq_solution(fall):
    """From x0 held (no trajectory of the dynamics) the first trial is taken, then the model is exact: the
    exact solution to 1e-6 within 12 iterations (8 with the accelerated fall). Nielsen's rule lowers lambda
    by up to 10 per iteration; the accelerated fall by 10, 100, 1000 (the first trial judged by its ratio)."""
    pb = scaled_lq(1.0)
    X, U = exact_solution(pb)
    res, its = run(pb, tol_rel=0.0, iterations=20, lambda_fall=fall)
    errs = [np.abs(Xi - X).max() / np.abs(X).max() for Xi, _ in its]
    hit = next(i + 1 for i, e in enumerate(errs) if e < 1e-6)
    assert hit <= (8 if fall == "accelerated" else 12), errs
    assert res.cost == pytest.approx(pb.cost(X, U), rel=1e-9)
    lam = [h.mu for h in res.history]
    if fall == "nielsen":
        assert lam[0] == 1.0 and lam[2] == pytest.approx(0.1) and lam[3] == pytest.approx(0.01)  # rho = 1: /10
    else:
        assert lam[:4] == pytest.approx([1.0, 0.1, 1e-3, 1e-6])


@pytest.mark.numerics
@pytest.mark.parametrize("scale", [1e-3, 1e3])
def test_robust_schedule_iterates_do_not_depend_on_the_cost_scale(scale):
    """The same LQ problem with every weight times 1e-3 or 1e3: kappa scales with it, alpha = lambda kappa,
    the process noise and start variance per unit of kappa; the iterates are the same to rounding and the
    costs scale exactly, for as long as the cost falls by more than rounding (5 iterations here; then a
    step of relative size 1e-9 may be taken at one scale and not at the other, which the end test allows)."""
    ref, ref_its = run(scaled_lq(1.0), iterations=5, tol_rel=0.0)
    res, its = run(scaled_lq(scale), iterations=5, tol_rel=0.0)
    assert len(its) == len(ref_its) == 5
    for (X, U), (Xr, Ur) in zip(its, ref_its):
        assert np.abs(X - Xr).max() <= 1e-9 * np.abs(Xr).max()
        assert np.abs(U - Ur).max() <= 1e-9 * np.abs(Ur).max()
    assert [h.mu for h in res.history] == pytest.approx([h.mu for h in ref.history], rel=1e-9)
    costs, ref_costs = np.array([h.cost for h in res.history]), np.array([h.cost for h in ref.history])
    assert costs == pytest.approx(scale * ref_costs, rel=1e-9)
    end, end_ref = run(scaled_lq(scale))[0], run(scaled_lq(1.0))[0]
    assert np.abs(end.X - end_ref.X).max() <= 1e-7 * np.abs(end_ref.X).max()
    # the fixed schedule's absolute alpha is not scale-free: the same alpha gives other iterates
    f1 = aico(scaled_lq(1.0), AICOOptions(iterations=1, alpha=1.0)).X
    fs = aico(scaled_lq(scale), AICOOptions(iterations=1, alpha=1.0)).X
    assert np.abs(f1 - fs).max() > 1e-4 * np.abs(f1).max()


@pytest.mark.numerics
def test_cost_curvature_scales_with_the_cost():
    X = np.tile(make_lq(seed=2).x0, (T + 1, 1))
    U = np.zeros((T, N_U))
    k1, k2 = cost_curvature(scaled_lq(1.0), X, U), cost_curvature(scaled_lq(1e3), X, U)
    assert k1 > 0 and k2 == pytest.approx(1e3 * k1, rel=1e-9)


def _step(pb, start_cost, **kw):
    opts = AICOOptions(**{"alpha": 1.0, "schedule": "robust", **kw})
    return RobustStep(pb, Sweeps(pb, opts), opts, cost_curvature(pb, np.tile(pb.x0, (T + 1, 1)),
                                                                     np.zeros((T, N_U))), start_cost)


@pytest.mark.numerics
def test_robust_schedule_rejects_a_trial_that_raises_the_cost_and_stops_at_lambda_max():
    """A feasible iterate of cost 0 cannot be beaten: every trial is rejected, the iterate and its cost stay,
    lambda grows by 2, 4, 8, 10, 10 (Nielsen's doubling, capped at x10); rejected at lambda_max the run stops."""
    pb = make_lq(seed=2, running=5.0)
    step = _step(pb, 0.0, lambda_max=1e3)
    start = Iterate(np.tile(pb.x0, (T + 1, 1)), np.zeros((T, N_U)))
    lams = []
    for it in range(1, 10):
        s = step(it, start)
        assert s.iterate is start and s.cost == 0.0 and not s.moved
        lams.append(s.mu)
        if s.stop is not None:
            break
    assert lams == pytest.approx([1.0, 2.0, 8.0, 64.0, 640.0, 1e3])
    assert s.stop.status is Status.MAX_ITERATIONS and "lambda_max" in s.stop.message


@pytest.mark.numerics
def test_robust_schedule_grows_lambda_by_lm_factor_when_no_rollout_of_a_trial_is_finite(monkeypatch):
    """A trial whose rollouts (the full step and both shortened ones) all blow up gives no ratio of actual to
    predicted decrease: lambda grows by lm_factor at once, not by Nielsen's 2, 4, 8 meant for a measured rise
    (from a quasi-static start the first trials' rollouts can blow up: three rejections at lambda 1, 2, 8)."""
    import raico.planning.aico.steps as steps_module

    pb = make_lq(seed=2, running=5.0)
    U0 = np.zeros((T, N_U))
    X0 = pb.controller_rollout(U0, np.zeros((T, N_U, pb.n_x)))[0]
    step = _step(pb, pb.cost(X0, U0))
    start = Iterate(X0, U0, U0.copy(), np.zeros((T, N_U, pb.n_x)))

    def blow_up(problem, o, O):
        return np.full((T + 1, problem.n_x), np.inf), np.full((T, problem.n_u), np.inf), o, O

    monkeypatch.setattr(steps_module, "bounded_rollout", blow_up)
    lams = []
    for it in range(1, 4):
        s = step(it, start)
        assert s.iterate is start and not s.moved and s.stop is None
        lams.append(s.mu)
    assert lams == pytest.approx([1.0, 10.0, 100.0]) and step.lam == pytest.approx(1e3)


@pytest.mark.numerics
def test_robust_schedule_takes_the_first_trial_from_a_start_that_is_no_trajectory():
    """The stall this schedule fixes: from x0 held the reference is no trajectory's cost; the first finite
    trial is taken whatever it costs (the adaptive schedule compared it with the zero-control rollout's cost
    and, when that is lower than holding the start, rejected every trial)."""
    pb = make_lq(seed=2, running=5.0)
    step = _step(pb, None)
    start = Iterate(np.tile(pb.x0, (T + 1, 1)), np.zeros((T, N_U)))
    s = step(1, start)
    assert s.moved and s.iterate is not start and np.isfinite(s.cost)
    assert step.cur_cost == s.cost


@pytest.mark.numerics
def test_robust_trials_are_steps_of_the_regularized_model_at_the_current_iterate(monkeypatch):
    """A nonlinear cost (end-effector via-points of a planar arm) under linear dynamics (pseudo-dynamics),
    from the zero-control rollout: a trial is the minimizer of the quadratic model at the current iterate plus
    ``alpha ||x - x_cur||^2``, so the model predicts a decrease of at least ``alpha ||dX||^2`` along it (the
    rollout is the model's own trajectory here). Relinearizing at the beliefs inside the sweeps (theta) made
    steps of other models: with theta = 1e-3 half of the trials were ones the model rightly saw raise the cost
    and the run took twice the iterations. The schedule linearizes once per trial: theta changes nothing."""
    from tests.planning.test_solvers_nonlinear import N_Q, make_arm_problem
    from tests.planning.test_solvers_nonlinear import T as T_ARM

    seen = []
    predicted = RobustStep._predicted_decrease

    def record(self, cur, new):
        pred = predicted(self, cur, new)
        seen.append((pred, self.alpha * float(np.sum((new.X - cur.X) ** 2))))
        return pred

    monkeypatch.setattr(RobustStep, "_predicted_decrease", record)
    pb = make_arm_problem()
    runs = {}
    for theta in (0.1, 1e-3):
        seen.clear()
        runs[theta] = aico(pb, AICOOptions(iterations=30, alpha=1.0, schedule="robust", theta=theta),
                           U_init=np.zeros((T_ARM, N_Q)))
        # 13 iterations (the accelerated fall; Nielsen's rule: 11, its cost within 1e-4 two iterations later)
        assert runs[theta].status == Status.CONVERGED and runs[theta].iterations <= 13, runs[theta].message
        assert seen and all(pred >= reg for pred, reg in seen), seen
    assert np.array_equal(runs[0.1].X, runs[1e-3].X)


def test_robust_schedule_options_are_checked():
    with pytest.raises(ValueError, match="the robust schedule needs alpha > 0"):
        AICOOptions(alpha=0.0, schedule="robust")
    with pytest.raises(ValueError, match="schedule must be one of fixed, adaptive, robust"):
        AICOOptions(alpha=1.0, schedule="lm")
    with pytest.raises(ValueError, match="lm_factor"):
        AICOOptions(alpha=1.0, schedule="robust", lm_factor=1.0)


def bounded_lq(T: int = T):
    """The LQ problem with hard bounds its unconstrained optimum leaves: state coordinates 0 and 1 within
    [-0.3, 0.3] (as joint positions, from step 1 on) and both controls within +-0.8 (as efforts)."""
    import dataclasses

    from raico.planning.problem import Bounds

    pb = make_lq(seed=2, running=5.0, T=T)
    b = Bounds(u_lower=np.full(N_U, -0.8), u_upper=np.full(N_U, 0.8), q_index=np.array([0, 1]),
               q_lower=np.full(2, -0.3), q_upper=np.full(2, 0.3))
    return pb, dataclasses.replace(pb, bounds=b)


def bounded_qp_optimum(pb) -> float:
    """The bounded LQ problem's optimal cost, from scipy's SLSQP on the QP over ``z = (x_0..x_T, u_0..u_{T-1})``
    (``1/2 z^T H z - g^T z``, the dynamics as linear equalities, the bounds as a box; independent of the
    solvers)."""
    from scipy.linalg import block_diag
    from scipy.optimize import minimize

    T, n, m, dyn, b = pb.T, pb.n_x, pb.n_u, pb.dynamics, pb.bounds
    R, r = pb.quadratize_states(np.zeros((T + 1, n)))
    Hu, hu = pb.quadratize_controls(np.zeros((T, m)))
    Hq, g = block_diag(*R, *Hu), np.concatenate([*r, *hu])
    off = (T + 1) * n
    C = np.zeros(((T + 1) * n, off + T * m))
    d = np.concatenate([pb.x0, np.tile(dyn.a, T)])
    C[:n, :n] = np.eye(n)
    for t in range(T):
        rows = slice((t + 1) * n, (t + 2) * n)
        C[rows, (t + 1) * n:(t + 2) * n], C[rows, t * n:(t + 1) * n] = np.eye(n), -dyn.A
        C[rows, off + t * m:off + (t + 1) * m] = -dyn.B
    lo, hi = np.full(off + T * m, -np.inf), np.full(off + T * m, np.inf)
    for t in range(1, T + 1):
        lo[t * n + b.q_index], hi[t * n + b.q_index] = b.q_lower, b.q_upper
    lo[off:], hi[off:] = np.tile(b.u_lower, T), np.tile(b.u_upper, T)
    z0 = np.concatenate([np.tile(pb.x0, T + 1), np.zeros(T * m)])
    res = minimize(lambda z: 0.5 * z @ Hq @ z - g @ z, z0, jac=lambda z: Hq @ z - g, method="SLSQP",
                   constraints=[{"type": "eq", "fun": lambda z: C @ z - d, "jac": lambda z: C}],
                   bounds=list(zip(np.where(np.isfinite(lo), lo, None), np.where(np.isfinite(hi), hi, None))),
                   options={"maxiter": 1000, "ftol": 1e-10})
    assert res.success, res.message
    X, U = res.x[:off].reshape(T + 1, n), res.x[off:].reshape(T, m)
    assert max(pb.bounds.violation(X, U)) <= 1e-8 and np.abs(C @ res.x - d).max() <= 1e-8
    return pb.cost(X, U)


@pytest.mark.numerics
@pytest.mark.parametrize("schedule", ["robust", "fixed"])
def test_hard_bounds_hold_where_the_unconstrained_optimum_leaves_them(schedule):
    """The unconstrained optimum leaves the range and asks for more than the effort; with the bounds
    R-AICO's plan is inside the range to 1e-3 (1e-4 the augmented Lagrangian's target) and within the effort
    exactly (the last controller's controls clipped), its status is not out-of-bounds, and its cost is the
    bounded QP's optimum to 1e-4."""
    free, pb = bounded_lq(T=12)
    X, U = exact_solution(free)
    q_out, u_out = pb.bounds.violation(X, U)
    assert q_out > 0.1 and u_out > 0.1
    res = aico(pb, AICOOptions(iterations=120, alpha=1.0, schedule=schedule))
    q, u = pb.bounds.violation(res.X, res.U)
    assert q <= 1e-4 and u == 0.0, (q, u, res.message)
    assert res.status is Status.CONVERGED and np.all(np.abs(res.U) <= 0.8)
    assert pb.cost(res.X, res.U) == pytest.approx(bounded_qp_optimum(pb), rel=1e-4)
    assert res.cost == pb.cost(res.X, res.U)       # the history's last cost is the plan's
    # the stored controller gives the plan: clipped controls have their value as feedforward, no feedback
    assert np.allclose(res.o + np.einsum("tij,tj->ti", res.O, res.X[:-1]), res.U, atol=1e-9)


@pytest.mark.numerics
def test_a_plan_that_cannot_stay_inside_says_so():
    """A range the plan cannot keep (the start's state 0 is 0.18; the bound at 0.1 from step 1 on is beyond
    what one step of the bounded controls can do): status out-of-bounds with the amount."""
    import dataclasses

    free, pb = bounded_lq()
    x0 = pb.x0.copy()
    b = dataclasses.replace(pb.bounds, q_lower=np.array([x0[0] + 2.0, -10.0]), q_upper=np.array([x0[0] + 3.0, 10.0]))
    res = aico(dataclasses.replace(pb, bounds=b), AICOOptions(iterations=30, alpha=1.0, schedule="robust"))
    assert res.status is Status.OUT_OF_BOUNDS and "joint range by" in res.message


@pytest.mark.numerics
def test_cli_plan_of_a_problem_file_defaults_to_the_robust_schedule_and_hard_bounds(tmp_path):
    """``raico plan --problem FILE``: R-AICO's robust schedule and the model's hard bounds by default (stored in
    the config), the thesis's fixed schedule and no hard bounds for ``--plant/--task``; the plan is within its
    joint ranges and effort limits; a bad ``--bounds`` is one line on stderr and exit 2."""
    import json

    from typer.testing import CliRunner

    from raico.pipeline.interface.cli import app
    from raico.plants.robots import shared_robot

    runner = CliRunner()
    root = Path(__file__).resolve().parents[2]
    res = runner.invoke(app, ["plan", "--problem", str(root / "raico" / "problems" / "arm5_reach.toml"), "--dynamics", "analytic",
                              "--iterations", "12", "--json", "--artifacts", str(tmp_path)])
    assert res.exit_code == 0, res.output
    line = json.loads(res.stdout.strip().splitlines()[-1])
    cfg = json.loads((Path(line["path"]) / "meta.json").read_text())["config"]
    assert cfg["alpha_schedule"] == "robust" and cfg["bounds"] == "hard"
    plan = np.load(Path(line["path"]) / "plan.npz")
    robot = shared_robot("arm5")
    Q = plan["X"][1:, :robot.n_q]
    assert np.all(Q <= robot.upper + 1e-3) and np.all(Q >= robot.lower - 1e-3)
    assert np.all(np.abs(plan["U"]) <= robot.effort * (1 + 1e-9))
    res = runner.invoke(app, ["plan", "--plant", "arm5", "--task", "reach", "--iterations", "2", "--json",
                              "--artifacts", str(tmp_path)])
    assert res.exit_code == 0, res.output
    line = json.loads(res.stdout.strip().splitlines()[-1])
    cfg = json.loads((Path(line["path"]) / "meta.json").read_text())["config"]
    assert cfg["alpha_schedule"] == "fixed" and cfg["bounds"] == "none"
    res = runner.invoke(app, ["plan", "--plant", "arm5", "--task", "reach", "--bounds", "soft",
                              "--artifacts", str(tmp_path)])
    assert res.exit_code == 2 and "unknown bounds 'soft'" in res.output


def test_plan_config_says_the_robust_schedule_does_not_relinearize_inside_the_sweeps():
    """--no-relinearize and --belief-rate are the sweeps' relinearization, which the robust schedule does not
    do: named as ignored, left out of the cache key (the same plan either way); the fixed schedule keeps them."""
    from raico.stages.plan.stage import PlanConfig

    file = str(Path(__file__).resolve().parents[2] / "raico" / "problems" / "arm5_reach.toml")
    robust = PlanConfig(problem=file, relinearize=False, belief_rate=0.5)
    assert set(robust.ignored()) == {"relinearize", "belief_rate"}
    assert robust.normalized() == PlanConfig(problem=file).normalized()
    fixed = PlanConfig(problem=file, alpha_schedule="fixed", relinearize=False, belief_rate=0.5)
    assert fixed.ignored() == {} and fixed.normalized() != PlanConfig(problem=file, alpha_schedule="fixed").normalized()


@pytest.mark.parametrize("schedule", ["robust", "fixed"])
def test_bounds_never_active_give_the_unbounded_iterates(schedule):
    """Ranges, velocity limits and efforts far beyond anything the unbounded plan reaches: the merit is the
    cost and the messages are the unconstrained ones, so every iterate and the plan are the same bits."""
    import dataclasses

    from raico.planning.problem import Bounds

    free, _ = bounded_lq(T=12)
    X, U = exact_solution(free)
    wide = 10.0 * (np.abs(X).max() + np.abs(U).max() + 1.0)
    n = free.n_x
    b = Bounds(u_lower=np.full(N_U, -wide), u_upper=np.full(N_U, wide), q_index=np.array([0, 1]),
               q_lower=np.full(2, -wide), q_upper=np.full(2, wide), v_index=np.array([n - 1]),
               v_lower=np.array([-wide]), v_upper=np.array([wide]))
    runs = {}
    for name, pb in (("free", free), ("bounded", dataclasses.replace(free, bounds=b))):
        seen: list = []
        runs[name] = (aico(pb, AICOOptions(iterations=40, alpha=1.0, schedule=schedule),
                           callback=lambda r, Xc, Uc, seen=seen: seen.append((r.cost, Xc.copy()))), seen)
    (a, sa), (c, sc) = runs["free"], runs["bounded"]
    assert a.iterations == c.iterations and np.array_equal(a.X, c.X) and np.array_equal(a.U, c.U)
    assert [s[0] for s in sa] == [s[0] for s in sc]
    assert all(np.array_equal(x, y) for (_, x), (_, y) in zip(sa, sc))
    assert c.status is a.status


def test_a_start_outside_a_range_comes_back_as_its_velocity_limit_lets_it():
    """State 0 starts 0.5 below its range [x0 + 0.5, x0 + 3]. The per-step box follows the velocity limit
    (``(t - 1) dt vmax`` back toward the range; checked on its own with vmax = 0.1); without one the range holds
    from step 1: the plan keeps it to 1e-3, converges (not out-of-bounds), and the message says the start was
    outside and that the plan is inside from step 1."""
    import dataclasses

    from raico.planning.problem import Bounds

    free, _ = bounded_lq(T=12)
    x0 = free.x0
    vmax, dt = 0.1, 1.0
    b = Bounds(q_index=np.array([0]), q_lower=np.array([x0[0] + 0.5]), q_upper=np.array([x0[0] + 3.0]),
               v_index=np.array([free.n_x // 2]), v_lower=np.array([-np.inf]), v_upper=np.array([np.inf]))
    lo, hi = b.position_box(x0, dt, free.T)
    assert lo[1, 0] == x0[0] + 0.5      # no velocity limit on coordinate 0: inside from step 1
    from raico.planning.constraints import reachable_box

    lo, _ = reachable_box(b.q_lower, b.q_upper, x0[:1], np.array([vmax]), dt, free.T)
    assert lo[1, 0] == x0[0] and lo[3, 0] == pytest.approx(x0[0] + 0.2) and lo[7, 0] == x0[0] + 0.5
    pb = dataclasses.replace(free, bounds=b)
    res = aico(pb, AICOOptions(iterations=120, alpha=1.0, schedule="robust"))
    assert "the start is outside a joint range" in res.message and "from step 1" in res.message, res.message
    assert res.status is Status.CONVERGED, res.message
    assert res.X[1:, 0].min() >= x0[0] + 0.5 - 1e-3
