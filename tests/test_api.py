"""The Python API (pipeline/api.py): the same runs and artifacts as the CLI, through the same cache."""

import json

import pytest
from typer.testing import CliRunner

from pipeline import api
from pipeline.cli import app
from stages.plan.tasks import PENDULUM_T


def test_api_plan_execute_and_cli_share_the_cache(tmp_path):
    p = api.plan(tmp_path, record=False, plant="pendulum", task="swing-up", dynamics="analytic", solver="ilqg",
                 iterations=2)
    assert not p.cached and p.status in ("max-iterations", "converged") and p.metrics["iterations"] == 2
    X = api.arrays(p, "plan.npz")["X"]
    assert X.shape == (PENDULUM_T + 1, 2)
    # the CLI finds the same run: a cache hit with the same key
    res = CliRunner().invoke(app, ["plan", "--plant", "pendulum", "--task", "swing-up", "--dynamics", "analytic",
                                   "--solver", "ilqg", "--iterations", "2", "--no-record", "--json",
                                   "--artifacts", str(tmp_path)])
    line = json.loads(res.stdout.strip().splitlines()[-1])
    assert res.exit_code == 0 and line["cached"] and line["key"] == p.key
    e = api.execute(tmp_path, record=False, plan=p.key)
    assert e.status in ("ok", "limits", "tracking-lost") and api.arrays(e, "rollout.npz")["X"].shape == (PENDULUM_T + 1, 2)
    again = api.plan(tmp_path, record=False, plant="pendulum", task="swing-up", dynamics="analytic", solver="ilqg",
                     iterations=2)
    assert again.cached and again.key == p.key


def test_api_learn_and_bad_input(tmp_path):
    out = api.learn(tmp_path, record=False, plant="pendulum", task="swing-up", episodes=1, iterations=2,
                    restarts=0, stride=25)
    assert out.metrics["episodes"] == 1 and len(out.metrics["gp_error_heldout"]) == 1
    with pytest.raises(ValueError, match="unknown plant 'crane'"):
        api.plan(tmp_path, plant="crane", task="reach")
    with pytest.raises(ValueError, match="unknown experiment 'fig9'"):
        api.reproduce(["fig9"], tmp_path)
    with pytest.raises(ValueError, match="unknown stage 'dance'"):
        api.run("dance", tmp_path)


def test_api_says_what_ran_unless_quiet_and_names_the_valid_keywords(tmp_path, capfd):
    import re

    api.plan(tmp_path, record=False, plant="arm5", task="reach", iterations=2)
    err = capfd.readouterr().err
    assert re.search(r"plan [0-9a-f]{16}: ran \(no cache entry\) -> .* \[", err), err
    api.plan(tmp_path, record=False, quiet=True, plant="arm5", task="reach", iterations=2)
    assert capfd.readouterr().err == ""
    with pytest.raises(TypeError, match="unknown keyword 'iteratons'; its keywords are plant, task, .*iterations"):
        api.plan(tmp_path, plant="arm5", task="reach", iteratons=2)
    with pytest.raises(ValueError, match="give --plant and --task, or --problem FILE \\(missing: --task\\)"):
        api.plan(tmp_path, plant="arm5")
