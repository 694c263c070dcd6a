"""End-to-end CLI tests of plan, execute and reproduce on small settings (real Drake, real files)."""

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from pipeline.cli import app

runner = CliRunner()


def run_json(*args):
    res = runner.invoke(app, [str(a) for a in args])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_plan_and_execute_arm5_pseudo(tmp_path):
    line = run_json("plan", "--plant", "arm5", "--task", "reach", "--solver", "raico", "--alpha", 1,
                    "--iterations", 8, "--json", "--artifacts", tmp_path)
    m = line["metrics"]
    assert line["status"] in ("converged", "max-iterations") and m["iterations"] <= 8
    for k in ("initial_cost", "final_cost", "iterations", "status", "wall_time_s", "via_point_errors"):
        assert k in m
    assert m["final_cost"] < m["first_iteration_cost"] < m["initial_cost"]
    assert set(m["via_point_errors"]) == {"via_x1@500", "via_x2@1000"}
    folder = Path(line["path"])
    for name in ("plan.npz", "recording.rrd", "trajectory.mcap", "meta.json"):
        assert (folder / name).is_file()
    d = np.load(folder / "plan.npz")
    assert d["X"].shape == (1001, 10) and d["O"].shape == (1000, 5, 10) and d["costs"].shape == (m["iterations"],)
    again = run_json("plan", "--plant", "arm5", "--task", "reach", "--solver", "raico", "--alpha", 1,
                     "--iterations", 8, "--json", "--artifacts", tmp_path)
    assert again["cached"] and again["key"] == line["key"]

    ex = run_json("execute", "--plan", line["key"], "--json", "--artifacts", tmp_path)
    em = ex["metrics"]
    assert set(em["via_point_errors"]) == {"via_x1@500", "via_x2@1000"}
    # computed torque in Drake follows the plan closely
    assert em["rmse_planned_executed"] < 0.01
    assert abs(em["via_point_errors"]["via_x2@1000"] - m["via_point_errors"]["via_x2@1000"]) < 0.01
    r = np.load(Path(ex["path"]) / "rollout.npz")
    assert r["X"].shape == (1001, 10) and r["tau"].shape == (1000, 5)


def test_plan_recording_has_costs_robot_and_task(tmp_path):
    import subprocess
    import sys

    from rerun.chunk import RrdReader

    line = run_json("plan", "--plant", "pendulum", "--task", "swing-up", "--solver", "ilqg", "--iterations", 3,
                    "--json", "--artifacts", tmp_path)
    rrd = Path(line["path"]) / "recording.rrd"
    rerun = Path(sys.executable).with_name("rerun")
    assert subprocess.run([str(rerun), "rrd", "verify", str(rrd)], capture_output=True).returncode == 0
    chunks = RrdReader(rrd).stream().to_chunks()

    def rows(entity, timeline):
        return sum(c.num_rows for c in chunks if c.entity_path == entity and timeline in c.timeline_names)

    assert rows("/cost/total", "iteration") == line["metrics"]["iterations"]
    assert rows("/world/robot/rod", "sim_time") == 751  # T + 1 planned states of the swing-up
    assert rows("/task/upright/value", "sim_time") == 751
    assert rows("/task/upright/target", "sim_time") == 1


def test_nao_balance_plan_and_execute_reports_cog(tmp_path):
    line = run_json("plan", "--plant", "nao", "--task", "balance", "--solver", "raico", "--alpha", 1,
                    "--iterations", 3, "--no-record", "--json", "--artifacts", tmp_path)
    assert line["metrics"]["final_cost"] < line["metrics"]["initial_cost"]
    ex = run_json("execute", "--plan", line["key"], "--no-record", "--json", "--artifacts", tmp_path)
    for k in ("cog_inside_fraction", "cog_min_margin", "torque_saturation", "r_sole_drift"):
        assert k in ex["metrics"]
    r = np.load(Path(ex["path"]) / "rollout.npz")
    assert ex["metrics"]["cog_inside_fraction"] == pytest.approx(np.mean(r["cog_margin"] > 0))
    assert ex["metrics"]["cog_min_margin"] == pytest.approx(np.nanmin(r["cog_margin"]))


@pytest.mark.parametrize("args, needle", [
    (["plan", "--plant", "arm5", "--task", "nope"], "reach, reach-roll"),
    (["plan", "--plant", "arm5", "--task", "reach", "--solver", "sqp"], "aico, raico, ilqg"),
    (["plan", "--plant", "arm5", "--task", "reach", "--dynamics", "quantum"], "pseudo, analytic, learned"),
    (["plan", "--plant", "arm5", "--task", "reach", "--dynamics", "learned"], "--model KEY goes with"),
    (["plan", "--plant", "arm5", "--task", "reach", "--dynamics", "learned", "--model", " "], "empty artifact"),
    (["execute", "--plan", ""], "empty artifact"),
    (["ls", "plann"], "unknown stage 'plann'"),
    (["plan", "--plant", "arm5", "--task", "reach", "--alpha", "-1"], "alpha"),
    (["plan", "--plant", "arm5", "--task", "reach", "--iterations", "0"], "iterations"),
    (["execute", "--plan", "0123456789abcdef"], "no artifact"),
    (["reproduce", "--figure", "fig9"], "fig3.2a"),
])
def test_bad_input_is_one_line(tmp_path, args, needle):
    res = runner.invoke(app, [*args, "--artifacts", str(tmp_path)])
    assert res.exit_code != 0
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and needle in lines[0], res.stderr


def test_execute_rejects_corrupt_plan(tmp_path):
    line = run_json("plan", "--plant", "pendulum", "--task", "swing-up", "--iterations", 1, "--no-record",
                    "--json", "--artifacts", tmp_path)
    (Path(line["path"]) / "plan.npz").write_bytes(b"garbage")
    res = runner.invoke(app, ["execute", "--plan", line["key"], "--artifacts", str(tmp_path)])
    assert res.exit_code != 0 and "changed" in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "execute").exists() or not [p for p in (tmp_path / "execute").iterdir()
                                                        if not p.name.startswith(".")]


def test_reproduce_quick_figure_writes_png_claims_and_is_cached(tmp_path):
    res = runner.invoke(app, ["reproduce", "--figure", "fig3.2a", "--quick", "--jobs", "1", "--json",
                              "--artifacts", str(tmp_path)])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout.strip().splitlines()[-1])
    out = Path(doc["path"])
    import matplotlib.image as mpimg

    img = mpimg.imread(out / "figure.png")
    assert img.shape[:2] == (462, 660) and img[..., :3].std() > 0.05  # 6 x 4.2 in at 110 dpi, not blank
    claims = json.loads((out / "claims.json").read_text())
    # the table is the claim functions applied to the runs' own metrics
    from stages.evaluate.claims import evaluate_claims
    from stages.evaluate.summary import summarize

    runs = {}
    for r in claims["runs"]:
        meta = json.loads((Path(r["recording"]).parent / "meta.json").read_text())
        runs.setdefault(r["variant"], []).append({"status": meta["status"], "metrics": meta["metrics"]})
    S = {label: summarize(label, rs) for label, rs in runs.items()}
    assert claims["claims"] == evaluate_claims(("raico_converges", "all_converge_aico_fastest"), S, [], "fig3.2a")
    assert all(Path(r["recording"]).is_file() for r in claims["runs"])
    assert (tmp_path / "report-quick" / "README.md").is_file()
    again = runner.invoke(app, ["reproduce", "--figure", "fig3.2a", "--quick", "--jobs", "1", "--json",
                                "--artifacts", str(tmp_path)])
    doc2 = json.loads(again.stdout.strip().splitlines()[-1])
    assert doc2["cached_runs"] == doc2["runs"] == 8


def test_evaluate_plan_and_rollout(tmp_path):
    p = run_json("plan", "--plant", "pendulum", "--task", "swing-up", "--solver", "ilqg", "--iterations", 5,
                 "--no-record", "--json", "--artifacts", tmp_path)
    e = run_json("execute", "--plan", p["key"], "--no-record", "--json", "--artifacts", tmp_path)
    ev = run_json("evaluate", "--plan", p["key"], "--rollout", e["key"], "--json", "--artifacts", tmp_path)
    m = ev["metrics"]
    assert m["final_cost"] == p["metrics"]["final_cost"] and m["rmse_planned_executed"] == e["metrics"]["rmse_planned_executed"]
    assert (Path(ev["path"]) / "cost.png").is_file() and (Path(ev["path"]) / "evaluation.json").is_file()
    other = run_json("plan", "--plant", "pendulum", "--task", "swing-up", "--solver", "ilqg", "--iterations", 2,
                     "--no-record", "--json", "--artifacts", tmp_path)
    res = runner.invoke(app, ["evaluate", "--plan", other["key"], "--rollout", e["key"], "--artifacts", str(tmp_path)])
    assert res.exit_code != 0 and "not executed from plan" in res.stderr


def test_no_record_then_record_is_cached_and_writes_the_recording(tmp_path):
    args = ["plan", "--plant", "pendulum", "--task", "swing-up", "--solver", "ilqg", "--iterations", 2,
            "--json", "--artifacts", tmp_path]
    first = run_json(*args, "--no-record")
    folder = Path(first["path"])
    assert not first["cached"] and first["recording"] is None and not (folder / "recording.rrd").exists()
    second = run_json(*args)
    assert second["cached"] and second["key"] == first["key"]
    assert second["recording"] == str(folder / "recording.rrd") and (folder / "recording.rrd").stat().st_size > 1000
    assert (folder / "trajectory.mcap").is_file()
    meta = json.loads((folder / "meta.json").read_text())
    assert "recording.rrd" not in meta["files"]  # derived, not data
    derived = json.loads((folder / "derived.json").read_text())
    assert derived["recording.rrd"]["size"] == (folder / "recording.rrd").stat().st_size


@pytest.mark.parametrize("command", ["babble", "plan", "execute", "evaluate", "reproduce", "ls", "show"])
def test_every_command_has_help(command):
    res = runner.invoke(app, [command, "--help"])
    assert res.exit_code == 0 and "Usage" in res.output
    if command in ("babble", "plan", "execute", "evaluate"):
        for shared in ("--artifacts", "--no-record", "--quiet", "--json"):
            assert shared in res.output, (command, shared)
    if command == "plan":  # the whole task list, from the task registry
        text = " ".join(res.output.split())
        assert "nao: balance- inside" in text or "nao: balance-inside" in text
        assert "pendulum: swing-" in text
