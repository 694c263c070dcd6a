"""``raico execute --controller mpc``: receding-horizon control of an arm in Drake, pushed; bad input."""

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from raico.pipeline.interface.cli import app
from raico.stages.evaluate.metrics import STATUSES

runner = CliRunner()
PUSH = "hand:30:0.9:0.1"   # 30 N along world x on arm5's hand from 0.9 s for 0.1 s, before the last via-point's 1 s


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def run_json(*args):
    res = invoke(*args)
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def arm5_plan(tmp_path_factory):
    root = tmp_path_factory.mktemp("mpc")
    plan = run_json("plan", "--plant", "arm5", "--task", "reach", "--solver", "raico", "--iterations", 30,
                    "--no-record", "--json", "--artifacts", root)
    return plan["key"], root


@pytest.mark.slow
def test_mpc_absorbs_a_push_the_plans_controller_does_not(arm5_plan):
    key, root = arm5_plan
    common = ("--plan", key, "--push", PUSH, "--json", "--artifacts", root)
    plan_ctrl = run_json("execute", *common, "--no-record")
    mpc = run_json("execute", *common, "--controller", "mpc", "--horizon", 100, "--iterations-per-tick", 1,
                   "--solver", "raico")
    for r in (plan_ctrl, mpc):
        assert r["status"] in STATUSES and r["status"] == r["metrics"]["status"]
    last = "via_x2@1000"   # the final target, 0.1 s after the push ends
    assert plan_ctrl["metrics"]["via_point_errors"][last] > 0.03
    assert mpc["metrics"]["via_point_errors"][last] < 0.01
    m = mpc["metrics"]
    assert m["mpc_ticks"] == 1000 and m["mpc_iterations"] == 1000 and m["mpc_horizon"] == 100
    assert 0 <= m["mpc_over_period"] <= 1000 and m["mpc_median_tick_s"] > 0
    d = np.load(Path(mpc["path"]) / "rollout.npz")
    assert d["mpc_solve_time"].shape == (1000,) and np.all(d["mpc_iterations"] == 1)
    assert np.all(np.isfinite(d["mpc_cost"])) and d["mpc_over_budget"].dtype == bool
    assert d["mpc_violation"].shape == (1000, 2) and np.all(d["mpc_violation"] >= 0)
    assert d["mpc_predicted"].shape == (1000, 101, d["X"].shape[1])   # each tick's predicted window
    assert np.all(np.isfinite(d["mpc_predicted"]))
    # the recording: the solve time per tick, the predicted hand paths (the latest and two fading before it)
    from rerun.chunk import RrdReader

    rows: dict[str, int] = {}
    for c in RrdReader(Path(mpc["recording"])).stream().to_chunks():
        rows[c.entity_path] = rows.get(c.entity_path, 0) + c.num_rows
    assert rows.get("/mpc/tick", 0) > 0
    assert all(rows.get(f"/world/predicted/ee/{age}", 0) > 0 for age in range(3)), sorted(rows)
    assert m["mpc_max_violation"] == pytest.approx(d["mpc_violation"].max(axis=0).tolist(), rel=0, abs=0)
    # the per-tick over-period flags are the solve times against the period
    assert np.array_equal(d["mpc_over_budget"], d["mpc_solve_time"] > m["mpc_period"])


@pytest.mark.slow
def test_the_split_mpc_absorbs_the_push_too(arm5_plan):
    """``--rti``: the feedback phase's times recorded, and the final target reached as the whole tick's MPC does."""
    key, root = arm5_plan
    r = run_json("execute", "--plan", key, "--push", PUSH, "--json", "--artifacts", root, "--no-record",
                 "--controller", "mpc", "--horizon", 100, "--solver", "raico", "--rti")
    m = r["metrics"]
    assert m["via_point_errors"]["via_x2@1000"] < 0.01 and m["mpc_ticks"] == 1000
    d = np.load(Path(r["path"]) / "rollout.npz")
    assert d["mpc_feedback_time"].shape == (1000,) and np.all(d["mpc_feedback_time"] > 0)
    assert m["mpc_median_feedback_s"] == float(np.median(d["mpc_feedback_time"]))


@pytest.mark.parametrize("args, message", [
    (("--controller", "mpc", "--period", 0.0005), "shorter than the simulation step"),
    (("--controller", "mpc", "--period", 0.0015), "must divide the planning step"),
    (("--controller", "mpc", "--horizon", 1001), "longer than the problem's 1000 steps"),
    (("--controller", "mpc", "--solver", "ilqg"), "cannot warm-start"),
    (("--controller", "mpc", "--push", "nosuchframe:10:0.1:0.1"), "no such frame"),
    (("--push", "hand:10:0.1"), "expected FRAME:NEWTONS:START:DURATION"),
    (("--horizon", 10), "is an option of --controller mpc"),
    (("--controller", "mpc", "--solver", "fddp", "--rti"), "solver fddp has no preparation / feedback split"),
    (("--controller", "mpc", "--rti", "--period", 0.001), "--rti prepares the next planning step"),
    (("--rti",), "is an option of --controller mpc"),
    (("--controller", "mpc", "--final-target", "end"), "--final-target must be one of receding, fixed"),
    (("--final-target", "fixed"), "--final-target is an option of --controller mpc"),
    (("--controller", "mpc", "--window-posture", 1), "--window-posture is for a floating robot's MPC"),
    (("--controller", "mpc", "--window-target", "plan"), "--window-target is for a floating robot's MPC"),
])
def test_bad_input(arm5_plan, args, message):
    key, root = arm5_plan
    res = invoke("execute", "--plan", key, *args, "--no-record", "--artifacts", root)
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.output.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and message in lines[0], res.output


def test_the_scenario_file_expands(tmp_path):
    root = Path(__file__).resolve().parents[2]
    res = invoke("exp", "run", root / "experiments" / "ur5_payload_push.toml", "--dry-run", "--artifacts", tmp_path)
    assert res.exit_code == 0, res.output
    assert "3 variants x 3 seeds = 9 runs" in res.output
