"""The learning loop end to end on small settings: real Drake babbling and execution, real GP fits."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipeline.cli import app

runner = CliRunner()
SMALL = ["--plant", "pendulum", "--task", "swing-up", "--sigma-star", "0", "--sigma-weight", "1e-2",
         "--iterations", "3", "--max-points", "200", "--restarts", "0", "--stride", "25"]


def learn_json(tmp_path, *extra):
    res = runner.invoke(app, ["learn", *SMALL, *map(str, extra), "--json", "--artifacts", str(tmp_path)])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout.strip().splitlines()[-1]), res.stderr


def test_learn_runs_cached_episodes_and_records_each_episode(tmp_path):
    from rerun.chunk import RrdReader

    from pipeline.cache import Cache
    from pipeline.runner import as_artifact

    two, _ = learn_json(tmp_path, "--episodes", 2)
    m = two["metrics"]
    assert m["episodes"] == 2 and len(m["gp_error"]) == len(m["task_error"]) == len(m["fit_time_s"]) == 2
    doc = as_artifact(Cache(tmp_path).require("learn", two["key"])).document("episodes.json")
    eps = doc["episodes"]
    # every episode's numbers come from its own cached fit, plan and execute runs
    for e in eps:
        fit = json.loads((tmp_path / "fit" / e["fit"] / "meta.json").read_text())
        plan = json.loads((tmp_path / "plan" / e["plan"] / "meta.json").read_text())
        assert e["n_points"] == fit["metrics"]["n_points"] and e["plan_time_s"] == plan["metrics"]["wall_time_s"]
        assert plan["config"]["dynamics"] == "learned" and plan["config"]["sigma_star"] == "0.0"
    # the second fit trains on the babbling plus the first execution (every 25th of 750 steps: 30 points)
    assert eps[1]["n_points"] == eps[0]["n_points"] + 30
    plan2 = json.loads((tmp_path / "plan" / eps[1]["plan"] / "meta.json").read_text())
    assert plan2["inputs"] == [f"fit/{eps[1]['fit']}", f"plan/{eps[0]['plan']}"]  # warm-started

    rrd = Path(two["recording"])
    chunks = RrdReader(rrd).stream().to_chunks()
    def rows(entity, timeline):
        return sum(c.num_rows for c in chunks if c.entity_path == entity and timeline in c.timeline_names)

    assert rows("/learn/gp_error", "episode") == 2
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
    done = {p.parent.name for p in (tmp_path / "execute").glob("[0-9a-f]*/meta.json")}
    before = {k: (tmp_path / "execute" / k / "meta.json").stat().st_mtime_ns for k in done}
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "episode 1/2" in res.stderr and "(cached)" in res.stderr.split("episode 2/2")[0]
    after = {p.parent.name for p in (tmp_path / "execute").glob("[0-9a-f]*/meta.json")}
    assert done <= after and len(after) == 2
    assert {k: (tmp_path / "execute" / k / "meta.json").stat().st_mtime_ns for k in done} == before
