"""``raico execute`` with noise on the free-standing Nao: seeds give different rollouts and
a status each; the recording shows the status, contacts, support polygon and CoG marker."""

import json
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from raico.pipeline.interface.cli import app
from raico.stages.evaluate.metrics import STATUSES

runner = CliRunner()


def run_json(*args):
    res = runner.invoke(app, [str(a) for a in args])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_execute_with_noise_on_the_free_nao(tmp_path):
    plan = run_json("plan", "--plant", "nao", "--task", "reach", "--solver", "raico", "--iterations", 1,
                    "--no-record", "--json", "--artifacts", tmp_path)
    noisy = ("--x0-noise", 0.02, "--process-noise", 0.5)
    runs = [run_json("execute", "--plan", plan["key"], *noisy, "--seed", s, "--json", "--artifacts", tmp_path,
                     *(() if s == 1 else ("--no-record",))) for s in (1, 2)]
    assert runs[0]["key"] != runs[1]["key"]
    rollouts = [np.load(Path(r["path"]) / "rollout.npz") for r in runs]
    for r, d in zip(runs, rollouts):
        assert r["status"] == r["metrics"]["status"] and r["status"] in STATUSES
        assert d["q_free"].shape == (101, 33) and d["X"].shape == (101, 50)
    # different initial states and torque noise: different rollouts, from the first sample on
    assert not np.allclose(rollouts[0]["X"][0], rollouts[1]["X"][0])
    assert np.abs(rollouts[0]["q_free"] - rollouts[1]["q_free"]).max() > 1e-3
    # the same seed again: the cached run, the same rollout
    again = run_json("execute", "--plan", plan["key"], *noisy, "--seed", 1, "--no-record", "--json",
                     "--artifacts", tmp_path)
    assert again["cached"] and again["key"] == runs[0]["key"]

    from rerun.chunk import RrdReader

    chunks = RrdReader(Path(runs[0]["recording"])).stream().to_chunks()
    rows = {}
    for c in chunks:
        rows[c.entity_path] = rows.get(c.entity_path, 0) + c.num_rows
    for entity in ("/world/support_polygon", "/world/contact_points", "/world/cog_ground", "/world/zmp",
                   "/world/robot/torso"):
        assert rows.get(entity) == 101, entity
    assert rows.get("/cog/zmp_margin", 0) > 0 and rows.get("/contact/force", 0) > 0
    assert rows["/status"] == 1 and rows["/events"] == (3 if runs[0]["status"] != "ok" else 2)
