"""MPC above the whole-body stabilizer on the free-standing Nao, pushes on the floating execution: a short
run (few ticks, a short horizon) and bad input."""

import copy
import dataclasses
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from raico.pipeline.interface.cli import app
from raico.plants.robots import shared_robot
from raico.stages.evaluate.metrics import STATUSES
from raico.stages.execute.config import ExecuteConfig
from raico.stages.execute.stage import execute
from tests.stages.test_execute_floating import desc_for, pseudo_plan
from tests.tolerance import assert_close

T, DT, H = 20, 0.01, 5


def nao_problem(q0: np.ndarray):
    """The balance task's planning problem (the Nao's pseudo-dynamics, left sole fixed) from ``q0``."""
    from raico.stages.plan.stage import PlanConfig, build_problem

    return build_problem(PlanConfig(plant="nao", task="balance-inside", dynamics="pseudo"), q0=q0)[2]


@pytest.mark.slow
@pytest.mark.numerics
def test_the_floating_execution_runs_mpc_above_the_stabilizer_pushed():
    nao = shared_robot("nao")
    Q = np.tile(nao.default_q, (T + 1, 1))
    seen: list[np.ndarray] = []

    def planning(q0):
        seen.append(q0.copy())
        return nao_problem(q0)

    cfg = ExecuteConfig(plan="hold", controller="mpc", horizon=H, push=("torso:0,2,0:0.05:0.05",))
    out = execute(cfg, desc_for("nao", nao.default_q, T, DT), pseudo_plan(Q, DT), planning=planning)
    m = out.metrics
    assert m["status"] in STATUSES and m["controller"] == "mpc"
    assert m["start"] == "standing"              # above the stabilizer: the standing start by default
    # the problem is rebuilt from the executed start posture (the standing start's projection)
    assert len(seen) == 1 and np.array_equal(seen[0], out.X[0, :nao.n_q])
    assert m["mpc_ticks"] == T and m["mpc_horizon"] == H and m["mpc_iterations"] == T
    pred = out.mpc["mpc_predicted"]
    assert pred.shape == (T, H + 1, 2 * nao.n_q) and np.all(np.isfinite(pred))
    # each window starts at the state measured at its tick (the windows are kept in float32)
    assert_close(pred[:, 0], out.X[:T], rel=float(np.finfo(np.float32).eps))
    assert out.mpc["mpc_solve_time"].shape == (T,)


@pytest.mark.slow
@pytest.mark.numerics
def test_the_window_holds_the_standing_start_only_with_its_weights():
    from raico.stages.execute.floating import _floating_mpc

    nao = shared_robot("nao")
    n = nao.n_q
    plan = pseudo_plan(np.tile(nao.default_q, (T + 1, 1)), DT)
    q = nao.default_q + 0.01
    old = _floating_mpc(ExecuteConfig(plan="hold", controller="mpc", horizon=H), plan, plan["X"], q, nao_problem,
                        DT, 0.001)
    assert "window_hold" not in old.problem.term_names()      # the default: the plan's problem alone
    cfg = ExecuteConfig(plan="hold", controller="mpc", horizon=H, window_posture=1.0, window_damping=0.1)
    mpc = _floating_mpc(cfg, plan, plan["X"], q, nao_problem, DT, 0.001)
    hold = mpc.problem.term("window_hold")
    assert hold.times is None and hold.weight == 1.0           # every window step
    np.testing.assert_array_equal(hold.target, np.r_[q, np.zeros(n)])
    np.testing.assert_array_equal(np.diag(hold.C), np.r_[np.full(n, 1.0), np.full(n, 0.1)])
    assert sorted(mpc.problem.term_names()) == sorted([*old.problem.term_names(), "window_hold"])
    # the run: a few ticks of the held window above the stabilizer
    out = execute(cfg, desc_for("nao", nao.default_q, T, DT), plan, planning=nao_problem)
    m = out.metrics
    assert m["status"] in STATUSES and m["controller"] == "mpc" and m["mpc_ticks"] == T
    assert np.all(np.isfinite(out.mpc["mpc_predicted"]))


@pytest.mark.slow
@pytest.mark.numerics
def test_the_window_tracks_the_plan_step_by_step():
    from raico.stages.execute.floating import _floating_mpc

    nao = shared_robot("nao")
    n = nao.n_q
    Q = nao.default_q + 0.02 * np.sin(np.linspace(0, 3, T + 1))[:, None]   # a plan that moves
    plan = pseudo_plan(Q, DT)
    cfg = ExecuteConfig(plan="hold", controller="mpc", horizon=H, window_posture=10.0, window_damping=0.1,
                        window_target="plan")

    def short(q0):   # the balance problem cut to the plan's T steps (a target per step of the plan)
        p, terms = nao_problem(q0), []
        for term in p.state_terms:
            c = copy.copy(term)
            if term.times is not None:
                c._set_times(term.times[term.times <= T])
            terms.append(c)
        return dataclasses.replace(p, T=T, state_terms=terms)

    mpc = _floating_mpc(cfg, plan, plan["X"], Q[0], short, DT, 0.001)
    hold = mpc.problem.term("window_hold")
    assert hold.per_step and hold.times is None
    np.testing.assert_array_equal(hold.target, plan["X"])           # the plan's positions and velocities
    np.testing.assert_array_equal(np.diag(hold.C), np.r_[np.full(n, 10.0), np.full(n, 0.1)])
    window = next(t for t in mpc.window.state_terms if t.name == "window_hold")
    for k in (0, 3, T - 2):                                          # the window's targets: the absolute steps
        mpc._set_tick(k)
        np.testing.assert_array_equal(window.target, plan["X"][np.minimum(np.arange(k, k + H + 1), T)])
    out = execute(cfg, desc_for("nao", nao.default_q, T, DT), plan, planning=short)
    assert out.metrics["status"] in STATUSES and out.metrics["mpc_ticks"] == T
    assert np.all(np.isfinite(out.mpc["mpc_predicted"]))


@pytest.mark.slow
@pytest.mark.numerics
def test_the_stabilizer_follows_the_window_ahead_and_the_run_is_judged_against_its_predictions(monkeypatch):
    from raico.stages.execute import floating
    from raico.stages.execute.wbc import Reference

    nao = shared_robot("nao")
    followed: list[tuple[int, np.ndarray]] = []
    judged: dict = {}
    follow, metrics = Reference.follow, floating.execution_metrics

    def spy_follow(self, k, X):
        followed.append((k, np.array(X[0])))
        follow(self, k, X)

    def spy_metrics(*args, **kw):
        judged["X_track"] = kw.get("X_track")
        return metrics(*args, **kw)

    monkeypatch.setattr(Reference, "follow", spy_follow)
    monkeypatch.setattr(floating, "execution_metrics", spy_metrics)
    cfg = ExecuteConfig(plan="hold", controller="mpc", horizon=H, window_lead=2)
    out = execute(cfg, desc_for("nao", nao.default_q, T, DT), pseudo_plan(np.tile(nao.default_q, (T + 1, 1)), DT),
                  planning=nao_problem)
    pred = out.mpc["mpc_predicted"]
    # the stabilizer's reference at the tick's step: the window's state two steps ahead (float32 windows)
    assert [k for k, _ in followed] == list(range(T))
    eps = float(np.finfo(np.float32).eps)
    assert_close(np.array([x for _, x in followed]), pred[:, 2], rel=eps)
    # tracking-lost judged against each step's prediction from the tick before (the window's second state)
    aim = judged["X_track"]
    assert aim.shape == out.X.shape and np.array_equal(aim[0], out.X_plan[0])
    assert_close(aim[1:], pred[:, 1], rel=eps)


@pytest.mark.numerics
def test_the_reference_follows_a_window():
    from raico.plants.floating import shared_floating
    from raico.plants.robots import builtin_spec
    from raico.stages.execute.wbc import Reference, plan_cog

    free = shared_floating(builtin_spec("nao"))
    nao = free.fixed
    Q = np.tile(nao.default_q, (T + 1, 1))
    X = pseudo_plan(Q, DT)["X"]
    ref = Reference(free, X, X, DT)
    W = X[:4].copy()
    W[:, :nao.n_q] += 0.01 * np.arange(4)[:, None]
    W[:, nao.n_q:] = 1.0
    ref.follow(7, W)
    (q, v, a), (c, cd, cdd), _ = ref.at(7 * DT)
    # (at the step's start: the interpolation's weights 1 and 0, rounding only)
    assert_close(q, np.clip(W[0, :nao.n_q], nao.lower, nao.upper) @ nao.P.T)
    assert_close(v, W[1, nao.n_q:] @ nao.P.T)
    assert_close(c, plan_cog(nao, W[:3], DT)[0][0])
    assert_close(a, (W[1, nao.n_q:] - W[0, nao.n_q:]) @ nao.P.T / DT)
    # steps past the window's first three keep the plan
    np.testing.assert_array_equal(ref.Q[10], np.clip(X[10, :nao.n_q], nao.lower, nao.upper) @ nao.P.T)


@pytest.fixture(scope="module")
def nao_plan(tmp_path_factory):
    root = tmp_path_factory.mktemp("nao-mpc")
    res = CliRunner().invoke(app, ["plan", "--plant", "nao", "--task", "balance-inside", "--dynamics", "pseudo",
                                   "--iterations", "1", "--no-record", "--json", "--artifacts", str(root)])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout.strip().splitlines()[-1])["key"], root


@pytest.mark.slow
@pytest.mark.parametrize("args, message", [
    (("--controller", "mpc", "--push", "nosuchframe:10:0.1:0.1"), "no such frame"),
    (("--controller", "wbc", "--push", "nosuchframe:10:0.1:0.1"), "no such frame"),
    (("--controller", "mpc", "--period", 0.005), "once per planning step"),
    (("--controller", "mpc", "--horizon", 301), "longer than the problem's 300 steps"),
    (("--controller", "mpc", "--rti"), "runs on a fixed-base robot's MPC"),
    (("--controller", "mpc", "--window-posture", -1), "--window-posture must be a finite weight >= 0"),
    (("--controller", "mpc", "--window-damping", "nan"), "--window-damping must be a finite weight >= 0"),
    (("--controller", "wbc", "--window-damping", 0.1), "--window-damping is an option of --controller mpc"),
    (("--controller", "mpc", "--window-target", "nowhere"), "--window-target must be one of start, plan"),
    (("--controller", "mpc", "--window-lead", -1), "--window-lead must be 0 or a number of planning steps"),
    (("--controller", "mpc", "--horizon", 5, "--window-lead", 4), "past the horizon's 5 steps"),
])
def test_bad_input_on_the_floating_robot(nao_plan, args, message):
    key, root = nao_plan
    res = CliRunner().invoke(app, ["execute", "--plan", key, *map(str, args), "--no-record", "--artifacts", str(root)])
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.output.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and message in lines[0], res.output


def test_a_final_target_enters_the_window_only_with_the_problems_end_without_the_receding_end():
    from raico.planning.mpc import window_times

    times, T, H = np.array([100, 200, 300]), 300, 100
    # the default: the final target at the window's last step from the first tick on
    assert window_times(times, T, H, 150).tolist() == [50, 100]
    assert window_times(times, T, H, 150, receding_end=False).tolist() == [50]
    # once the problem's end is inside the window both agree: the absolute last step
    for k in (200, 250, 299):
        assert window_times(times, T, H, k, receding_end=False).tolist() == window_times(times, T, H, k).tolist()
    assert window_times(times, T, H, 250, receding_end=False).tolist() == [50]
    assert window_times(None, T, H, 5, receding_end=False) is None


def test_the_nao_scenario_file_expands(tmp_path):
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    res = CliRunner().invoke(app, ["exp", "run", str(root / "experiments" / "nao_push_mpc.toml"), "--dry-run",
                                   "--artifacts", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert "10 variants x 10 seeds = 100 runs" in res.output


def test_the_cog_via_point_margins_pass_over_a_state_term(tmp_path):
    from pathlib import Path

    from raico.stages.evaluate.metrics import cog_via_point_margins
    from raico.stages.plan.stage import PlanConfig, build_problem

    text = (Path(__file__).resolve().parents[2] / "raico" / "problems" / "nao_balance-inside.toml").read_text()
    path = tmp_path / "nao_damped.toml"
    path.write_text(text + '\n[costs.damping]\ntype = "state"\ntarget = "start"\nprecision = {q = 0.0, v = 1.0}\n'
                    'times = "all"\nweight = 1e-2\n')
    problem = build_problem(PlanConfig(problem=str(path), dynamics="pseudo"))[2]
    square = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    assert sorted(cog_via_point_margins(problem, square)) == ["via_cog1@100", "via_cog2@200", "via_cog3@300"]
