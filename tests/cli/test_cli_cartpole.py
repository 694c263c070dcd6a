"""The cart-pole end to end through the CLI on small settings: planned with the motor on the cart only,
executed in Drake, refused with pseudo-dynamics, and learned from scratch with PILCO's data count."""

import json
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from raico.pipeline.interface.cli import app

runner = CliRunner()


def run_json(*args):
    res = runner.invoke(app, [str(a) for a in args])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_plan_and_execute_cartpole(tmp_path):
    """iLQG plans the swing-up (40 steps of 0.1 s, 10 substeps); the plan stores every joint's torque, zero on
    the pole, within the cart's 10 N; the execution applies it on the discrete plant, the cart on its rail."""
    line = run_json("plan", "--plant", "cartpole", "--task", "swing-up", "--solver", "ilqg", "--iterations", 5,
                    "--no-record", "--json", "--artifacts", tmp_path)
    d = np.load(Path(line["path"]) / "plan.npz")
    assert d["U"].shape == (40, 2) and d["o"].shape == (40, 2) and d["O"].shape == (40, 2, 4)
    assert np.all(d["U"][:, 1] == 0) and np.all(d["o"][:, 1] == 0) and np.all(d["O"][:, 1] == 0)
    assert np.any(d["U"][:, 0] != 0)
    desc = json.loads((Path(line["path"]) / "problem.json").read_text())
    assert desc["dt"] == 0.1 and desc["T"] == 40 and desc["control_kind"] == "torque"
    ex = run_json("execute", "--plan", line["key"], "--no-record", "--json", "--artifacts", tmp_path)
    r = np.load(Path(ex["path"]) / "rollout.npz")
    assert r["X"].shape == (41, 4) and np.all(r["tau"][:, 1] == 0)
    assert np.all(np.abs(r["tau"][:, 0]) <= 10.0 + 1e-9)
    assert np.all(np.abs(r["X"][:, 0]) <= 2.0 + 1e-3)   # the rail's range, kept by the discrete plant


def test_pseudo_dynamics_are_refused_on_an_unactuated_joint(tmp_path):
    res = runner.invoke(app, ["plan", "--plant", "cartpole", "--task", "swing-up", "--dynamics", "pseudo",
                              "--artifacts", str(tmp_path)])
    assert res.exit_code == 2
    assert "unactuated joints (pole)" in res.output


def test_learn_takes_pilcos_data_per_episode(tmp_path):
    """From scratch: one random 4 s episode (41 samples at 0.1 s), then 40 executed steps per episode join the
    zero-mean GP's data (every step: stride 1); the episode's fit has all earlier data."""
    line = run_json("learn", "--plant", "cartpole", "--task", "swing-up", "--episodes", 2, "--iterations", 2,
                    "--alpha", 1, "--alpha-schedule", "robust", "--no-record", "--json", "--artifacts", tmp_path)
    m = line["metrics"]
    assert m["babble_seconds"] == 4.0
    assert m["n_points"][0] == 41 and m["n_points"][1] == 41 + m["data_steps"][0]
    if m["execution_status"][0] == "ok":   # a whole execution joins: its 40 steps
        assert m["data_steps"][0] == 40
    assert m["executed_seconds"] == [4.0, 4.0]
    fit = json.loads((tmp_path / "fit" / json.loads((Path(line["path"]) / "episodes.json").read_text())
                      ["episodes"][0]["fit"] / "fit.json").read_text())
    assert fit.get("residual", False) is False
