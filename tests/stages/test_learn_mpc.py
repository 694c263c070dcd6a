"""The learned model in the loop: MPC on a plan of a learned model runs on that model (the model file plus the
residual GP, with the plan's uncertainty term), the learn loop's episodes executed under MPC, and its bad input."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from tests.tolerance import assert_close, bound

DATA = Path(__file__).resolve().parents[1] / "data"
PROBLEM = DATA / "arm2_payload.toml"


def last_json(res) -> dict:
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout.strip().splitlines()[-1])


def learned_plan(raico, art: Path) -> tuple[dict, dict]:
    """A residual fit on a short babbling of the test arm's true robot, and a plan on it with the uncertainty term."""
    babble = last_json(raico("babble", "--problem", PROBLEM, "--episodes", 1, "--duration", 3.0, "--dt", 0.02,
                             "--substeps", 10, "--json", "--artifacts", art))
    fit = last_json(raico("fit", "--data", babble["key"], "--residual", "--restarts", 0, "--json", "--artifacts", art))
    plan = last_json(raico("plan", "--problem", PROBLEM, "--dynamics", "learned", "--model", fit["key"],
                           "--solver", "raico", "--iterations", 5, "--sigma-star", 0, "--sigma-weight", 1e-4,
                           "--json", "--artifacts", art))
    return fit, plan


@pytest.mark.numerics
def test_the_mpc_of_a_learned_plan_runs_on_its_model(raico, tmp_path):
    """The execute stage's MPC model of a plan of a residual fit is the model file plus that GP (the fit's arrays
    built again, independently, give the same step), with the plan's uncertainty term; a tick's window is a
    rollout of that model."""
    from raico.planning.costs import Uncertainty
    from raico.planning.mpc import MPC, learned_model
    from raico.planning.problem_file import read_problem
    from raico.plants.learned import ResidualDynamics, build_learned
    from raico.plants.model_file import shared_model
    from raico.stages.base import Artifact
    from raico.stages.execute.stage import planning_problem

    art = tmp_path / "art"
    fit, plan = learned_plan(raico, art)
    meta = json.loads((Path(plan["path"]) / "meta.json").read_text())
    problem = planning_problem(Artifact("plan", plan["key"], Path(plan["path"]), meta))
    dyn = learned_model(problem.dynamics)
    assert isinstance(dyn, ResidualDynamics)
    unc = [t for t in problem.joint_terms if isinstance(t, Uncertainty)]
    assert len(unc) == 1 and learned_model(unc[0].model) is dyn
    with np.load(Path(fit["path"]) / "model.npz") as f:
        params = {k: f[k] for k in f.files}
    robot = shared_model(read_problem(PROBLEM).robot_spec())
    ref = build_learned(robot, dyn.dt, params)
    rng = np.random.default_rng(0)
    for _ in range(5):
        x = np.concatenate([np.array([0.3, 0.5]) + 0.2 * rng.standard_normal(2), rng.standard_normal(2)])
        u = rng.standard_normal(problem.n_u)
        assert_close(dyn.step(x, u), ref.step(x, u), rel=bound(200, 10.0))
    with pytest.raises(ValueError, match="cannot"):   # crocoddyl's window is the model file's, not this model
        MPC(problem, 10, "fddp")
    mpc = MPC(problem, 10, "raico", iterations=1)
    X = np.load(Path(plan["path"]) / "plan.npz")
    mpc.start_from(X["X"], X["U"], X["o"], X["O"])
    for k in range(3):
        mpc.tick(X["X"][k] + 1e-3)
    W, U = mpc.X, mpc.U
    assert mpc.window.dynamics is problem.dynamics
    window_unc = [t for t in mpc.window.joint_terms if isinstance(t, Uncertainty)]   # in the window's cost
    assert len(window_unc) == 1 and window_unc[0].T == mpc.H and window_unc[0].model is unc[0].model
    for j in range(mpc.H):   # the window's trajectory: its controls rolled out on the learned model
        assert_close(W[j + 1], problem.dynamics.step(W[j], U[j]), rel=bound(500, 100.0))


@pytest.mark.slow
def test_learn_with_episodes_under_mpc_feeds_their_data(raico, tmp_path):
    """Two episodes under MPC on the learned model, pushed: each execution is a tick per planning step, and the
    data count per episode is the babbling's samples, then every 5th usable executed step of each episode."""
    art = tmp_path / "art"
    line = last_json(raico("learn", "--problem", PROBLEM, "--episodes", 2, "--babble-points", 40, "--iterations", 5,
                           "--alpha", 1, "--residual", "--stride", 5, "--restarts", 0, "--sigma-star", 0,
                           "--sigma-weight", 1e-4, "--controller", "mpc", "--horizon", 10,
                           "--push", "tip:2:0.2:0.05", "--json", "--no-record", "--artifacts", art))
    doc = json.loads((Path(line["path"]) / "episodes.json").read_text())
    first, second = doc["episodes"]
    for e in (first, second):
        ex = json.loads((art / "execute" / e["execute"] / "meta.json").read_text())
        assert ex["config"]["controller"] == "mpc" and ex["config"]["push"] == ["tip:2:0.2:0.05"]
        assert ex["metrics"]["mpc_ticks"] == 50 and e["mpc_median_tick_s"] > 0
    assert first["n_points"] == 40 and first["data_steps"] > 0
    assert second["n_points"] == first["n_points"] + math.ceil(first["data_steps"] / 5), (first, second)


@pytest.mark.parametrize("args, needle", [
    (("--controller", "mpc", "--mpc-solver", "fddp"), "cannot control with the learned model"),
    (("--controller", "mpc", "--mpc-solver", "ilqg"), "cannot control with the learned model"),
    (("--horizon", 10), "--horizon is an option of --controller mpc"),
    (("--final-target", "fixed"), "--final-target is an option of --controller mpc"),
    (("--controller", "mpc", "--final-target", "end"), "--final-target must be one of receding, fixed"),
    (("--controller", "mpc", "--period", 0.003), "must divide the planning step"),
    (("--controller", "wbc"), "controller must be pd or mpc"),
    (("--push", "nowhere:2:0.2"), "expected FRAME:NEWTONS:START:DURATION"),
])
def test_learn_mpc_bad_input_is_one_line(raico, tmp_path, args, needle):
    res = raico("learn", "--problem", PROBLEM, "--residual", *args, "--artifacts", tmp_path)
    assert res.exit_code == 2, res.output
    assert res.output.strip().count("\n") == 0 and needle in res.output, res.output
    assert not (tmp_path / "learn").exists()


def test_learn_mpc_refused_for_a_floating_robot(raico, tmp_path):
    res = raico("learn", "--plant", "nao", "--task", "balance", "--controller", "mpc", "--artifacts", tmp_path)
    assert res.exit_code == 2, res.output
    assert res.output.strip().count("\n") == 0 and "for fixed-base robots" in res.output, res.output
