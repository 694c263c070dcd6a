"""The Python API (raico/pipeline/interface/api.py): the same runs and artifacts as the CLI, through the same cache."""

import json

import pytest
from typer.testing import CliRunner

from raico.pipeline.interface import api
from raico.pipeline.interface.cli import app
from raico.planning.tasks import PENDULUM_T
from raico.thesis import api as thesis_api


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
        thesis_api.reproduce(["fig9"], tmp_path)
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


EXP = '''
name = "api-small"
stages = ["plan"]
seeds = "range(2)"
[base]
plant = "arm5"
task = "reach"
iterations = 3
[grid]
alpha = [0.5, 5.0]
[[point]]
label = "iLQG"
solver = "ilqg"
'''


def test_api_experiments_show_plot_and_compare_as_the_cli(tmp_path, capfd):
    """exp_run returns the runs table the CLI writes, exp_show the grouped one as a DataFrame, plot a Plot, compare
    the recording and its runs; the CLI finds the same runs cached."""
    import numpy as np
    import pandas as pd

    from raico.pipeline.errors import BadInput

    f = tmp_path / "api.toml"
    f.write_text(EXP)
    arts = tmp_path / "arts"
    df = api.exp_run(f, artifacts=arts, executor="serial", quiet=True)
    assert isinstance(df, pd.DataFrame) and len(df) == 6 and set(df["variant"]) == {"alpha=0.5", "alpha=5.0", "iLQG"}
    assert not df["plan.cached"].any()
    assert capfd.readouterr().err == ""   # quiet
    res = CliRunner().invoke(app, ["exp", "run", str(f), "--executor", "serial", "--json", "--artifacts", str(arts)])
    assert res.exit_code == 0 and json.loads(res.stdout)["cached"] == 6
    # -S through the API: a new grid value, only its runs computed
    more = api.exp_run(f, ["alpha=2"], artifacts=arts, executor="serial", quiet=True)
    assert len(more) == 8 and int((~more["plan.cached"].astype(bool)).sum()) == 2
    shown = api.exp_show("api-small", artifacts=arts)
    assert isinstance(shown, pd.DataFrame) and list(shown["variant"]) == ["alpha=0.5", "alpha=5.0", "alpha=2", "iLQG"]
    one = more[more["variant"] == "alpha=5.0"]["plan.final_cost"]
    assert shown.set_index("variant").loc["alpha=5.0", "plan.final_cost"] == np.median(one)
    per_run = api.exp_show(f, group=False, where="solver == 'ilqg'", artifacts=arts)
    assert len(per_run) == 2 and set(per_run["seed"]) == {0, 1}
    with pytest.raises(BadInput, match="--metric plan.nothing: no such column"):
        api.exp_show("api-small", metrics=["plan.nothing"], artifacts=arts)
    drawn = api.plot("api-small", kind="curve", artifacts=arts)
    assert drawn.path == arts / "exp" / "api-small" / "curve-cost.png" and drawn.path.stat().st_size > 0
    assert set(drawn.series) == {"alpha=0.5, solver=raico", "alpha=2, solver=raico", "alpha=5, solver=raico",
                                 "solver=ilqg"}
    box = api.plot("api-small", kind="box", ylim=(1, 1e4), out=tmp_path / "box.png", artifacts=arts)
    assert box.limits == (1, 1e4) and (tmp_path / "box.png").exists()
    with pytest.raises(BadInput, match="--kind line needs --x OPTION"):
        api.plot("api-small", artifacts=arts)
    got = api.compare(exp="api-small", where="seed == 0 and alpha > 1", out=tmp_path / "c.rrd", artifacts=arts)
    assert got["recording"] == tmp_path / "c.rrd" and got["recording"].stat().st_size > 0
    keys = more[(more["seed"] == 0) & (more["alpha"] > 1)]["plan.key"]
    assert sorted(got["runs"].values()) == sorted(f"plan/{k}" for k in keys)
    with pytest.raises(BadInput, match="give keys or --exp NAME, not both"):
        api.compare(["abcd"], exp="api-small", artifacts=arts)
