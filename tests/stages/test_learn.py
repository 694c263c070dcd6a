"""The learning loop end to end on small settings: real Drake babbling and execution, real GP fits."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from raico.pipeline.interface.cli import app
from raico.planning.tasks import PENDULUM_T

runner = CliRunner()
SMALL = ["--plant", "pendulum", "--task", "swing-up", "--sigma-star", "0", "--sigma-weight", "1e-2",
         "--iterations", "3", "--max-points", "200", "--restarts", "0", "--stride", "25"]


def learn_json(tmp_path, *extra):
    res = runner.invoke(app, ["learn", *SMALL, *map(str, extra), "--json", "--artifacts", str(tmp_path)])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout.strip().splitlines()[-1]), res.stderr


def test_learn_runs_cached_episodes_and_records_each_episode(tmp_path):
    from rerun.chunk import RrdReader

    from raico.pipeline.engine.artifacts import as_artifact
    from raico.pipeline.engine.cache import Cache

    two, err = learn_json(tmp_path, "--episodes", 2)
    m = two["metrics"]
    # each episode's line says whether the execution achieved the task, not only that it ran
    lines = [ln for ln in err.splitlines() if ln.startswith("learn episode")]
    assert len(lines) == 2 and all(("; task achieved: " in ln) != ("; task missed: " in ln) for ln in lines), err
    assert all(("; task achieved: " in ln) == a for ln, a in zip(lines, m["achieved"]))
    assert all("worst term 'theta'" in ln and " rad (end angle)]" in ln for ln in lines)   # the task's own criterion
    assert m["episodes"] == 2 and len(m["gp_error"]) == len(m["task_error"]) == len(m["fit_time_s"]) == 2
    # the GP scored on a fixed held-out babbling set too (never trained on), per joint normalized;
    # how much of each execution fed the data
    assert all(0 < e < float("inf") for e in m["gp_error_heldout"])
    assert len(m["gp_nrmse_joint"][0]) == len(m["gp_nrmse_heldout_joint"][0]) == 1
    assert m["data_steps"] == [PENDULUM_T, PENDULUM_T] and m["episodes_feeding_data"] == 2 and m["episodes_truncated"] == 0
    doc = as_artifact(Cache(tmp_path).require("learn", two["key"])).document("episodes.json")
    eps = doc["episodes"]
    # every episode's numbers come from its own cached fit, plan and execute runs
    for e in eps:
        fit = json.loads((tmp_path / "fit" / e["fit"] / "meta.json").read_text())
        plan = json.loads((tmp_path / "plan" / e["plan"] / "meta.json").read_text())
        assert e["n_points"] == fit["metrics"]["n_points"] and e["plan_time_s"] == plan["metrics"]["wall_time_s"]
        assert plan["config"]["dynamics"] == "learned" and plan["config"]["sigma_star"] == "0.0"
    # the second fit trains on the babbling plus the first execution (every 25th of its steps)
    assert eps[1]["n_points"] == eps[0]["n_points"] + PENDULUM_T // 25
    plan2 = json.loads((tmp_path / "plan" / eps[1]["plan"] / "meta.json").read_text())
    assert plan2["inputs"] == [f"fit/{eps[1]['fit']}", f"plan/{eps[0]['plan']}"]  # warm-started

    rrd = Path(two["recording"])
    chunks = RrdReader(rrd).stream().to_chunks()
    def rows(entity, timeline):
        return sum(c.num_rows for c in chunks if c.entity_path == entity and timeline in c.timeline_names)

    # one view per quantity: GP error per joint (log10), distance planned and executed, times, points
    assert rows("/gp_error_log10", "episode") == 2 and rows("/gp_error_heldout_log10", "episode") == 2
    assert rows("/distance/executed_theta_angle_error_rad", "episode") == rows("/distance/planned", "episode") == 2
    assert rows("/time/fit", "episode") == rows("/time/execute", "episode") == 2
    assert rows("/episode/torque", "episode") == 2
    # per episode the robot at its executed final pose and that episode's paths (not static: each episode its own)
    assert rows("/world/robot/rod", "episode") == 2
    assert rows("/world/paths/executed", "episode") >= 2 and rows("/world/paths/planned", "episode") >= 2
    assert not [c for c in chunks if c.is_static and c.entity_path.startswith("/world/paths")]

    # one more episode: the first two are cache hits (same configs), only the third runs
    three, err = learn_json(tmp_path, "--episodes", 3)
    assert not three["cached"] and three["metrics"]["gp_error"][:2] == m["gp_error"]
    assert err.count("(cached)") == 2 and err.count("(ran)") == 1
    again, _ = learn_json(tmp_path, "--episodes", 3)
    assert again["cached"] and again["key"] == three["key"]


@pytest.mark.parametrize("args, needle", [
    (["--episodes", "0"], "episodes must be in [1, 100]"),
    (["--episodes", "1", "--schedule", "batch-10"], "schedule must be 'every' or 'batch-N' with N >= 100"),
    (["--episodes", "1", "--sigma-star", "lots"], "sigma-star must be a number or none, got 'lots'"),
])
def test_learn_bad_input_is_one_line(tmp_path, args, needle):
    res = runner.invoke(app, ["learn", *SMALL[:4], *args, "--artifacts", str(tmp_path)])
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.exit_code == 2 and len(lines) == 1 and needle in lines[0], res.stderr


def test_killed_learn_resumes_without_recomputing_finished_episodes(tmp_path):
    cmd = [str(Path(sys.executable).with_name("raico")), "learn", *SMALL, "--episodes", "2", "--no-record",
           "--artifacts", str(tmp_path)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.time() + 120
        while time.time() < deadline and not list((tmp_path / "execute").glob("[0-9a-f]*/meta.json")):
            time.sleep(0.2)
        assert list((tmp_path / "execute").glob("[0-9a-f]*/meta.json")), "the first episode never finished"
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    # Under load the whole loop can finish before the kill lands: its own entry is then dropped, so the
    # rerun walks the episodes again; what is tested is that finished episodes are not recomputed.
    for entry in (tmp_path / "learn").glob("[0-9a-f]*"):
        shutil.rmtree(entry)
    done = {p.parent.name for p in (tmp_path / "execute").glob("[0-9a-f]*/meta.json")}
    before = {k: (tmp_path / "execute" / k / "meta.json").stat().st_mtime_ns for k in done}
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "episode 1/2" in res.stderr and "(cached)" in res.stderr.split("episode 2/2")[0]
    after = {p.parent.name for p in (tmp_path / "execute").glob("[0-9a-f]*/meta.json")}
    assert done <= after and len(after) == 2
    assert {k: (tmp_path / "execute" / k / "meta.json").stat().st_mtime_ns for k in done} == before


def test_babbling_pace_and_plant_defaults(tmp_path):
    """One random knot every 0.25 s (the pendulum's 15 samples keep their 5 knots); 0 means
    the plant's default, resolved before the key (one cache entry per meaning)."""
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.runner import run_key
    from raico.stages.learn import LearnConfig, babble_knots

    assert (babble_knots(15), babble_knots(100), babble_knots(4)) == (5, 33, 1)
    big = LearnConfig(plant="biorob", task="reach", babble_points=1000)  # a valid babbling run
    assert babble_knots(1000) == 333  # 99.9 s at one knot per 0.25 s would be 400: one per three samples
    big.babble_config().validate()
    arm = LearnConfig(plant="biorob", task="reach").normalized()
    assert (arm.babble_points, arm.stride) == (200, 20)
    pend = LearnConfig(plant="pendulum", task="swing-up").normalized()
    assert (pend.babble_points, pend.stride) == (15, 5)
    explicit = LearnConfig(plant="biorob", task="reach", babble_points=200, stride=20)
    cache = Cache(tmp_path)
    assert run_key(cache, "learn", LearnConfig(plant="biorob", task="reach")) == run_key(cache, "learn", explicit)
    with pytest.raises(ValueError, match="warm-from"):
        LearnConfig(plant="biorob", task="reach", warm_from="sideways").validate()


@pytest.mark.numerics
def test_plan_warm_start_from_the_trajectory_or_the_controls(tmp_path, monkeypatch):
    """Thesis §4.5 'initialized with the last planned trajectory': AICO/R-AICO linearize first at the
    earlier plan's states (X_init) and controls; 'controls' rolls the controls out; iLQG always does."""
    import numpy as np

    from raico.stages.base import Artifact
    from raico.stages.plan import stage as plan_stage
    from raico.stages.plan.stage import PlanConfig

    first = plan_stage.plan(PlanConfig(plant="pendulum", task="swing-up", dynamics="analytic", iterations=2))
    folder = tmp_path / "p"
    folder.mkdir()
    np.savez(folder / "plan.npz", **first.arrays())
    warm = Artifact("plan", "1" * 16, folder, {"status": "ok"})
    seen = {}
    real = plan_stage.solve

    def spy(problem, solver, options, callback=None, **init):
        seen[solver] = init
        return real(problem, solver, options, callback=callback, **init)

    monkeypatch.setattr(plan_stage, "solve", spy)
    cfg = PlanConfig(plant="pendulum", task="swing-up", dynamics="analytic", iterations=1, warm_start=warm.ref)
    plan_stage.plan(cfg.normalized(), warm_start=warm)
    assert np.array_equal(seen["raico"]["X_init"], first.arrays()["X"])
    assert np.array_equal(seen["raico"]["U_init"], first.arrays()["U"])
    from dataclasses import replace
    plan_stage.plan(replace(cfg, warm_from="controls").normalized(), warm_start=warm)
    assert "X_init" not in seen["raico"] and np.array_equal(seen["raico"]["U_init"], first.arrays()["U"])
    plan_stage.plan(replace(cfg, solver="ilqg").normalized(), warm_start=warm)
    assert "X_init" not in seen["ilqg"]
    assert replace(cfg, solver="ilqg").normalized().warm_from == "controls"  # one key per meaning
    assert replace(cfg, warm_start=None).normalized().warm_from == "controls"
    # R-AICO from the zero-control rollout (FDDP's other start) instead of x0 held
    plan_stage.plan(replace(cfg, warm_start=None, start="rollout").normalized())
    assert "X_init" not in seen["raico"] and not seen["raico"]["U_init"].any()
    plan_stage.plan(replace(cfg, warm_start=None).normalized())
    assert seen["raico"] == {}  # the thesis's start: x0 held at every step
    assert replace(cfg, solver="ilqg", warm_start=None, start="rollout").normalized().start == "held"
    with pytest.raises(ValueError, match="start"):
        replace(cfg, start="sideways").validate()


@pytest.mark.numerics
def test_learn_takes_no_data_after_a_lost_execution(tmp_path):
    """A BioRob planned on a GP of 15 babbling samples loses tracking; only the steps
    before its failure time join the next fit (every 20th), flagged and counted."""
    import math

    from raico.stages.base import Artifact
    from raico.stages.fit.stage import usable_steps

    res = runner.invoke(app, ["learn", "--plant", "biorob", "--task", "reach", "--episodes", "2", "--babble-points",
                              "15", "--iterations", "3", "--alpha", "2", "--restarts", "0", "--no-record", "--json",
                              "--artifacts", str(tmp_path)])
    assert res.exit_code == 0, res.output
    m = json.loads(res.stdout.strip().splitlines()[-1])["metrics"]
    assert m["execution_status"][0] == "tracking-lost" and m["data_truncated"][0]
    k = m["data_steps"][0]
    assert 0 < k < 500 and m["episodes_truncated"] >= 1
    assert m["n_points"][1] == m["n_points"][0] + math.ceil(k / 20)
    # the rule itself: ok (and at-a-limit) executions give every step, failed ones the steps before the failure
    def art(status, t):
        return Artifact("execute", "0" * 16, tmp_path, {"status": status, "metrics": {"failure_time": t}})
    assert usable_steps(art("ok", None), 0.002, 750) == 750
    assert usable_steps(art("limits", 0.5), 0.002, 750) == 750
    assert usable_steps(art("tracking-lost", 0.5), 0.002, 750) == 250
    assert usable_steps(art("diverged", 0.0), 0.002, 750) == 0


def test_learn_is_a_composite_stage_keyed_with_its_steps_code(tmp_path, monkeypatch):
    """``learn`` is a registered stage (its recorder with the others); its code version
    joins its steps', so editing the plan stage's code gives it another key; its steps are only the
    stages it names."""
    import dataclasses

    from raico.pipeline.engine import keys, runner
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.ui import Reporter
    from raico.pipeline.recordings.registry import RECORDERS
    from raico.stages.execute.config import ExecuteConfig
    from raico.stages.learn import LearnConfig
    from raico.stages.registry import get_stage, stage_names

    stage = get_stage("learn")
    assert "learn" in stage_names() and "learn" in RECORDERS
    assert stage.step_stages == ("babble", "fit", "plan", "execute")
    version = keys.code_version(stage)
    assert all(keys.code_version(get_stage(s)) in version for s in stage.step_stages)
    cache, cfg = Cache(tmp_path), LearnConfig(plant="pendulum", task="swing-up")
    key = runner.run_key(cache, "learn", cfg)
    real = keys.sources_version
    monkeypatch.setattr(keys, "sources_version", lambda name, src: "plan+edited" if name == "plan" else real(name, src))
    assert runner.run_key(cache, "learn", cfg) != key
    only_babble = dataclasses.replace(stage, step_stages=("babble",))
    with pytest.raises(ValueError, match="runs babble as steps, not execute"):
        runner.composite_steps(cache, only_babble, Reporter(quiet=True)).run("execute", ExecuteConfig(plan="x"))
