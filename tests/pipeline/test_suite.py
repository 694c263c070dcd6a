"""The solver suite: Dolan-Moré performance profiles on inputs with known answers, the budgets and
limit measures on synthetic histories, the list file's bad entries, and ``raico bench suite`` end to
end on a tiny suite (two problems, two solvers, three iterations) through the CLI."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from typer.testing import CliRunner

from raico.pipeline.errors import BadInput
from raico.pipeline.experiments import suite
from raico.pipeline.interface.cli import app

ROOT = Path(__file__).resolve().parents[2]
runner = CliRunner()


# ----------------------------------------------------------------------------- profiles
def test_performance_ratios_and_profiles_have_their_known_values():
    # problem 0: best 1 (A); 1: best 2 (B); 2: only B solves it; 3: best 5 (A); 4: nobody solves it
    m = {"A": [1.0, 4.0, None, 5.0, None], "B": [2.0, 2.0, 3.0, 10.0, math.inf]}
    r = suite.performance_ratios(m)
    assert r["A"] == [1.0, 2.0, math.inf, 1.0, math.inf]
    assert r["B"] == [2.0, 1.0, 1.0, 2.0, math.inf]
    taus = (1.0, 1.5, 2.0, 100.0)
    assert suite.profile(r["A"], taus) == [0.4, 0.4, 0.6, 0.6]    # the unsolved problem stays in the denominator
    assert suite.profile(r["B"], taus) == [0.4, 0.4, 0.8, 0.8]


def test_a_best_of_zero_gives_one_for_zero_and_inf_otherwise():
    r = suite.performance_ratios({"A": [0.0], "B": [1e-3]})
    assert r == {"A": [1.0], "B": [math.inf]}


def test_profiles_from_records_take_the_cost_and_the_time_to_target():
    recs = [{"problem": p, "solver": s, "final_cost": c, "time_to_target_s": t}
            for p, s, c, t in [("p", "A", 1.0, 0.5), ("p", "B", 1.05, None), ("q", "A", 3.0, 2.0),
                               ("q", "B", 2.0, 1.0)]]
    prof = suite.profiles(recs, ["p", "q"], ["A", "B"])
    assert prof["cost"]["ratios"] == {"A": [1.0, 1.5], "B": [1.05, 1.0]}
    assert prof["time"]["ratios"] == {"A": [1.0, 2.0], "B": [math.inf, 1.0]}
    i = suite.TAUS.index(1.1)
    assert prof["cost"]["rho"]["B"][i] == 1.0 and prof["cost"]["rho"]["A"][i] == 0.5
    assert prof["time"]["rho"]["B"][suite.TAUS.index(10.0)] == 0.5


# ----------------------------------------------------------------------------- budgets and limits
@pytest.mark.numerics
def test_the_cost_at_the_time_budget_is_the_last_iteration_finished_within_it():
    costs, elapsed = np.array([10.0, 5.0, 2.0, 1.0]), np.array([1.0, 2.0, 3.0, 4.0])
    assert suite.cost_at_budget(costs, elapsed, 0.9, budget=5.0) == 0.9      # within: the plan's own cost
    assert suite.cost_at_budget(costs, elapsed, 0.9, budget=2.5) == 5.0
    assert suite.cost_at_budget(costs, elapsed, 0.9, budget=0.5) is None     # no iteration finished
    assert suite.cost_at_budget(costs, elapsed, None, budget=5.0) is None    # diverged
    target = suite.target_of(1.0, 0.01)
    assert target == pytest.approx(1.01, rel=1e-9)
    assert suite.time_to(costs, elapsed, 2.0) == 3.0
    assert suite.time_to(costs, elapsed, 2.0, budget=2.5) is None
    assert suite.time_to(np.array([np.nan, 3.0]), np.array([1.0, 2.0]), 5.0) == 2.0


def test_limit_violations_are_the_largest_excess_over_range_and_effort():
    robot = SimpleNamespace(n_q=2, lower=np.array([-1.0, -2.0]), upper=np.array([1.0, 2.0]),
                            effort=np.array([5.0, np.inf]))
    X = np.array([[0.0, 0.0, 0, 0], [1.25, -2.5, 0, 0], [0.5, 1.0, 0, 0]])
    U = np.array([[6.0, 100.0], [-4.0, -1e9]])
    v = suite.limit_violations(robot, X, U, None)
    assert v == {"joint_range": 0.5, "velocity": 0.0, "effort": 1.0}
    inside = suite.limit_violations(robot, X[[0, 2]], U[:1] * 0, None)
    assert inside == {"joint_range": 0.0, "velocity": 0.0, "effort": 0.0}
    assert suite.limit_violations(robot, X * np.nan, U, None) == {"joint_range": None, "velocity": None,
                                                                  "effort": None}


def test_a_plan_faster_than_a_velocity_limit_is_outside():
    """Joint 0 limited to 2 rad/s, joint 1 without a limit: a plan at 2.5 rad/s on joint 0 (step 2) leaves it by
    0.5 and is judged outside although its ranges and efforts are kept; the start's speed is not the plan's."""
    robot = SimpleNamespace(n_q=2, lower=np.array([-1.0, -2.0]), upper=np.array([1.0, 2.0]),
                            effort=np.array([5.0, 5.0]), velocity=np.array([2.0, np.inf]))
    X = np.array([[0.0, 0.0, 9.0, 0], [0.02, 0.0, 2.0, 50.0], [0.045, 0.0, -2.5, 0]])
    U = np.zeros((2, 2))
    v = suite.limit_violations(robot, X, U, None)
    assert v == {"joint_range": 0.0, "velocity": 0.5, "effort": 0.0}
    rec = {"joint_range_excess": v["joint_range"], "velocity_excess": v["velocity"], "effort_excess": v["effort"]}
    assert not suite.inside_limits(rec)
    assert suite.inside_limits({**rec, "velocity_excess": 0.5 * suite.VELOCITY_TOL})
    assert not suite.inside_limits({**rec, "velocity_excess": 2 * suite.VELOCITY_TOL})
    X[2, 2] = -2.0
    assert suite.limit_violations(robot, X, U, None)["velocity"] == 0.0


# ----------------------------------------------------------------------------- the list file
PROBLEM = '''
name = "{name}"
[robot]
file = "{model}"
start = {{ shoulder = 0.3, elbow = 0.5, wrist = 0.2 }}
{weld}
[horizon]
T = {T}
dt = 0.01
[dynamics]
model = "analytic"
[costs.reach]
type = "frame_position"
frame = "{frame}"
target = [0.05, 0.0, -0.05]
relative = "start"
times = "last"
weight = 1e3
[costs.effort]
type = "control"
weight = 1e-3
'''


def _tiny(tmp_path: Path, extra: str = "", talos: bool = True) -> Path:
    """A suite of the MJCF arm (and with ``talos`` the Talos arm welded on a frame other than its root,
    which crocoddyl cannot express: skipped without example-robot-data) and two solvers, three
    iterations; plus ``extra`` entries."""
    shutil.copy(ROOT / "raico" / "problems" / "suite" / "models" / "arm3.xml", tmp_path / "arm3.xml")
    (tmp_path / "arm3.toml").write_text(PROBLEM.format(name="arm3", model="arm3.xml", weld="", T=20, frame="tip"))
    if talos:
        _talos(tmp_path)
    (tmp_path / "suite.toml").write_text(f'''
name = "tiny"
iterations = 3
time_budget_s = 60.0
[[solver]]
label = "R-AICO"
solver = "raico"
[[solver]]
label = "FDDP"
solver = "fddp"
needs = "crocoddyl"
[[solver]]
label = "later"
solver = "boxfddp-that-does-not-exist"
optional = true
{extra}
''')
    return tmp_path / "suite.toml"


def _talos(tmp_path: Path) -> None:
    """The Talos left arm welded on its gripper base as ``talos.toml`` (the test skipped without
    example-robot-data, which comes with the extra raico[baseline])."""
    from raico.plants.model_file import example_robot_data

    erd = example_robot_data()
    if erd is None:
        pytest.skip("example-robot-data is not installed (it comes with the extra raico[baseline])")
    talos = erd / "robots" / "talos_data" / "robots" / "talos_left_arm.urdf"
    (tmp_path / "talos.toml").write_text(
        PROBLEM.format(name="talos-welded", model=talos, weld='weld = "gripper_left_base_link"', T=5,
                       frame="arm_left_2_link").replace("start = { shoulder = 0.3, elbow = 0.5, wrist = 0.2 }", ""))


def test_the_list_file_keeps_bad_entries_with_their_reasons(tmp_path):
    """Pure list-file reading: no robot is loaded, so it runs without example-robot-data and crocoddyl
    (a solver that ``needs`` a missing package is then left out with its note)."""
    from raico.pipeline.experiments.expfile import available

    path = _tiny(tmp_path, '''
[[problem]]
file = "missing.toml"
[[problem]]
file = "zero.toml"
label = "arm3 no budget"
iterations = 0
''', talos=False)
    shutil.copy(tmp_path / "arm3.toml", tmp_path / "zero.toml")   # named by an entry: not a problem of its own
    s = suite.load(path)
    assert [p.label for p in s.problems] == ["missing", "arm3 no budget", "arm3"]   # entries, then the folder's
    by = {p.label: p for p in s.problems}
    assert by["missing"].reason.startswith("no problem file missing.toml")
    assert by["arm3 no budget"].reason == "a budget of 0 (iterations = 0): nothing to run"
    assert not by["arm3"].reason
    croc = available("crocoddyl")
    assert [x.label for x in s.solvers] == ["R-AICO", *(["FDDP"] if croc else [])]
    later = [n for n in s.notes if "'later'" in n]
    assert later == ["suite: solver 'later' left out (optional): unknown solver 'boxfddp-that-does-not-exist': "
                     "choose one of " + later[0].split("choose one of ")[1]]
    assert ("suite: solver 'FDDP' left out: it needs crocoddyl, which is not installed" in s.notes) is not croc
    assert len(s.notes) == 2 - croc


@pytest.mark.parametrize("extra, message", [
    ("[[problem]]\nlabel = 'x'", "give its file"),
    ("[[problem]]\nfile = 'arm3.toml'\nhorizon = 3", "unknown key 'horizon'"),
    ("[[problem]]\nfile = 'arm3.toml'\n[[problem]]\nfile = 'arm3.toml'", "two problems are labelled 'arm3'"),
    ("colour = 1", "unknown key 'colour'"),
])
def test_a_malformed_list_file_is_one_error(tmp_path, extra, message):
    path = _tiny(tmp_path, extra, talos=False)
    if extra.startswith("colour"):
        path.write_text(extra + "\n" + path.read_text())
    with pytest.raises(BadInput, match=message):
        suite.load(path)


# ----------------------------------------------------------------------------- end to end
@pytest.mark.slow
def test_bench_suite_runs_every_cell_says_why_a_cell_is_empty_and_caches(tmp_path, crocoddyl_baseline):
    path = _tiny(tmp_path, '''
[[problem]]
file = "missing.toml"
[[problem]]
file = "zero.toml"
label = "arm3 no time"
time_budget_s = 0
''')
    shutil.copy(tmp_path / "arm3.toml", tmp_path / "zero.toml")
    art, out = tmp_path / "art", tmp_path / "out"
    res = runner.invoke(app, ["bench", "suite", str(path), "--artifacts", str(art), "--out", str(out), "--quiet"])
    assert res.exit_code == 1, res.output     # the suite ran; two of its entries could not
    lines = [ln for ln in res.stderr.splitlines() if ln.startswith("suite: ")]
    assert lines[-1] == "suite: 2 problem entries could not run (missing, arm3 no time): exit 1"
    # one line per bad entry, the suite went on
    assert any(ln.startswith("suite: problem 'missing': no problem file missing.toml") for ln in lines)
    assert "suite: problem 'arm3 no time': a budget of 0 (time_budget_s = 0): nothing to run; its cells stay empty" \
        in lines
    assert any(ln.startswith("suite: talos-welded x FDDP: crocoddyl cannot express talos_left_arm.urdf welded on "
                             "'gripper_left_base_link'") for ln in lines)
    assert any(ln.startswith("suite: solver 'later' left out (optional)") for ln in lines)
    doc = json.loads((out / "tiny.json").read_text())
    recs = {(r["problem"], r["solver"]): r for r in doc["records"]}
    assert len(recs) == 4 * 2
    for solver in ("R-AICO", "FDDP"):
        r = recs[("arm3", solver)]
        assert r["status"] == "max-iterations" and r["iterations"] == 3 and r["key"]
        assert r["final_cost"] > 0 and r["joint_range_excess"] >= 0 and r["effort_excess"] >= 0
    best = min(recs[("arm3", s)]["final_cost"] for s in ("R-AICO", "FDDP"))
    assert {recs[("arm3", s)]["cost_ratio"] for s in ("R-AICO", "FDDP")} >= {1.0}
    assert all(recs[("arm3", s)]["best_cost"] == best for s in ("R-AICO", "FDDP"))
    winner = min(("R-AICO", "FDDP"), key=lambda s: recs[("arm3", s)]["final_cost"])
    assert recs[("arm3", winner)]["time_to_target_s"] is not None
    assert recs[("talos-welded", "R-AICO")]["key"] and recs[("talos-welded", "FDDP")]["key"] is None
    assert "welded on 'gripper_left_base_link'" in recs[("talos-welded", "FDDP")]["reason"]
    assert recs[("missing", "R-AICO")]["reason"].startswith("no problem file")
    # the page: the empty cells point at their reasons
    page = (out / "tiny.md").read_text()
    assert "## Empty cells and left-out solvers" in page and "Pinocchio's tree is rooted at 'arm_left_1_link'" in page
    assert (out / "tiny_profiles.png").stat().st_size > 10_000
    rho = doc["profiles"]["all"]["cost"]["rho"]
    # at tau = 1: the arm3's winner, and R-AICO on the welded Talos arm (the only solver there), of 4 problems
    assert rho["R-AICO"][0] == pytest.approx((1 + (winner == "R-AICO")) / 4)
    assert rho["FDDP"][0] == pytest.approx((winner == "FDDP") / 4)
    # every run an ordinary cached plan: exp show lists them, a second call computes nothing
    shown = runner.invoke(app, ["exp", "show", "tiny", "--artifacts", str(art), "--format", "csv"])
    assert shown.exit_code == 0 and "arm3 | FDDP" in shown.output
    again = runner.invoke(app, ["bench", "suite", str(path), "--artifacts", str(art), "--out", str(out), "--quiet",
                                "-p", "arm3", "-p", "talos-welded"])
    assert again.exit_code == 0, again.output
    import csv

    with open(art / "exp" / "tiny" / "runs.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 4 and all(r["plan.cached"] == "True" for r in rows if r["plan.key"])
    assert [r["variant"] for r in rows if not r["plan.key"]] == ["talos-welded | FDDP"]   # its error, again


# ----------------------------------------------------------------------------- the page and the README block
def _synthetic_doc():
    s = suite.Suite("mini", "", Path("suite.toml"), [suite.SolverEntry("A", {"solver": "raico"}),
                                                     suite.SolverEntry("B", {"solver": "ilqg"})],
                    [suite.ProblemEntry("p", Path("p.toml")), suite.ProblemEntry("q", Path("q.toml"), reason="r0")])
    base = {"iterations": 3, "wall_time_s": 0.1, "joint_range_excess": 0.0, "effort_excess": 0.0,
            "over_time_budget": False, "status": "max-iterations"}
    recs = [{**base, "problem": "p", "solver": "A", "final_cost": 2.0, "cost_ratio": 2.0, "time_to_target_s": None,
             "key": "a" * 16, "reason": ""},
            {**base, "problem": "p", "solver": "B", "final_cost": 1.0, "cost_ratio": 1.0, "time_to_target_s": 0.05,
             "key": "b" * 16, "reason": ""},
            *({**base, "problem": "q", "solver": x, "final_cost": None, "cost_ratio": None, "time_to_target_s": None,
               "key": None, "reason": "no problem file q.toml", "status": "not run"} for x in ("A", "B"))]
    return suite.summary(s, recs, {"date": "today", "machine": "here"})


def test_the_page_says_why_cells_are_empty_and_the_readme_block_carries_its_numbers(tmp_path):
    import importlib.util

    doc = _synthetic_doc()
    page = suite.markdown(doc)
    assert "| p | 40 it, 20 s, held | 2 (2x) | 1 (1x) |" in page
    assert "| q | 40 it, 20 s, held | - [1] | - [1] |" in page
    assert "1. no problem file q.toml" in page
    assert "ends above 1.1x the best final cost: 1 of 2 problems:\n\n- p: R-AICO's best 2x (A); the best 1 by B" in page
    assert "| A | 0.00 | 0.00 | 0.00 | 0.00 | 0.50 | 0.50 |" in page      # cost: within 2x on p, q unsolved
    (tmp_path / "suite.md").write_text(page)
    from raico.pipeline.engine.runner import finite_json

    (tmp_path / "suite.json").write_text(json.dumps(finite_json(doc)))
    spec = importlib.util.spec_from_file_location("readme_numbers", ROOT / "scripts" / "readme_numbers.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    block = mod.suite_block(tmp_path / "suite.md", tmp_path / "suite.json")
    assert "Every run" not in block and "\n### Final cost" in block
    assert f"The profiles as a plot: `{tmp_path / 'suite_profiles.png'}`." in block and "](" not in block
    assert "Over the 2 problems" in block and "A 0.00 / 0.00; B 0.50 / 0.50." in block
    # the suite judged by execution (docs/suite.md): the count, one row per cell, the profiles
    exec_block = mod.suite_exec_block(tmp_path / "suite.md", tmp_path / "suite.json")
    assert "**0 of the 2 plans** execute `ok` and achieve their task" in exec_block
    assert "| p | B | 1 | - | - | - |" in exec_block and "| q | A | - | - | - | - |" in exec_block
    assert "| A | 0.00 | 0.00 | 0.50 | 0.00 | 0.00 | 0.50 | 0.00 | 0.00 | 0.00 |" in exec_block


@pytest.mark.parametrize("args, line", [
    (["/no/such/suite.toml"], "raico: error: no suite file /no/such/suite.toml"),
    (["-p", "no-such-problem"], "raico: error: --problem no-such-problem: not in the suite; choose from "),
    (["-s", "no-such-solver"], "raico: error: --solver no-such-solver: not in the suite; choose from "),
    (["--jobs", "0"], "raico: error: --jobs must be in [1, 64]"),
])
def test_bad_arguments_are_one_line_and_exit_2_before_anything_runs(tmp_path, args, line):
    res = runner.invoke(app, ["bench", "suite", *args, "--artifacts", str(tmp_path / "art")])
    assert res.exit_code == 2
    assert res.stderr.count("\n") == 1 and res.stderr.startswith(line)
    assert not (tmp_path / "art" / "bench").exists()


@pytest.mark.numerics
def test_the_inside_profile_counts_a_plan_outside_the_limits_as_not_solved():
    """Two problems: on the first the cheaper plan leaves a joint range (by 0.1 rad), so inside the limits the
    other solver is the best and the cheaper one unsolved; on the second both stay inside."""
    from raico.pipeline.experiments import suite as st

    def rec(p, s, cost, rng, eff=0.0):
        return {"problem": p, "solver": s, "final_cost": cost, "time_to_target_s": 1.0,
                "joint_range_excess": rng, "effort_excess": eff}

    records = [rec("a", "x", 1.0, 0.1), rec("a", "y", 2.0, 0.0), rec("b", "x", 3.0, 5e-4), rec("b", "y", 3.3, 0.0, 1.0)]
    assert [st.inside_limits(r) for r in records] == [False, True, True, False]
    prof = st.profiles(records, ["a", "b"], ["x", "y"])
    assert prof["cost"]["ratios"]["x"] == [1.0, 1.0] and np.allclose(prof["cost"]["ratios"]["y"], [2.0, 1.1])
    assert prof["inside"]["ratios"]["x"][0] == math.inf and prof["inside"]["ratios"]["x"][1] == 1.0
    assert prof["inside"]["ratios"]["y"][0] == 1.0 and prof["inside"]["ratios"]["y"][1] == math.inf


# ----------------------------------------------------------------------------- judged by execution
def _exec_rec(p, s, cost, execution, achieved, rng=0.0):
    return {"problem": p, "solver": s, "final_cost": cost, "time_to_target_s": 1.0, "joint_range_excess": rng,
            "effort_excess": 0.0, "execution": execution, "task_achieved": achieved, "key": f"{p}{s}"}


def test_the_executed_profile_counts_only_ok_and_achieved_executions():
    """Three problems with known verdicts: on a the cheapest plan ends tracking-lost and the other is ok and
    achieved; on b both execute ok but x misses the task; on c nobody's execution is ok, so nobody solves it.
    The best feasible cost known on a comes from a reference (1.5, lower than y's 2.0), on b none is given."""
    records = [_exec_rec("a", "x", 1.0, "tracking-lost", False), _exec_rec("a", "y", 2.0, "ok", True),
               _exec_rec("b", "x", 3.0, "ok", False), _exec_rec("b", "y", 6.0, "ok", True),
               _exec_rec("c", "x", 1.0, "limits", False), _exec_rec("c", "y", 1.0, None, None)]
    assert [suite.executed_ok(r) for r in records] == [False, True, False, True, False, False]
    prof = suite.profiles(records, ["a", "b", "c"], ["x", "y"], best_feasible={"a": 1.5})
    ex = prof["executed"]["ratios"]
    assert ex["x"] == [math.inf, math.inf, math.inf]
    assert ex["y"] == [pytest.approx(2.0 / 1.5), 1.0, math.inf]
    assert prof["cost"]["ratios"]["x"] == [1.0, 1.0, 1.0]         # the cost profile beside it, unchanged
    # inside the limits x's cheaper plan counts (it stays in its ranges): the best feasible cost on a is 1.0
    assert prof["inside"]["ratios"]["y"][0] == 2.0 and prof["inside"]["ratios"]["x"][0] == 1.0
    taus = suite.TAUS
    assert prof["executed"]["rho"]["y"][taus.index(1.0)] == pytest.approx(1 / 3)
    assert prof["executed"]["rho"]["y"][taus.index(1.5)] == pytest.approx(2 / 3)


def test_execution_columns_use_executes_one_judgement():
    from raico.stages.evaluate.metrics import executed_task, task_note

    task = {"achieved": True, "worst": "reach", "kind": "position", "unit": "m", "error": 0.004, "tol": 0.01}
    row = {"execute.key": "k" * 16, "execute.status": "tracking-lost", **{f"execute.task.{k}": v for k, v in task.items()}}
    cols = suite.execution_columns(row)
    assert cols["execution"] == "tracking-lost" and cols["task_achieved"] is False   # within tolerance, status not ok
    assert cols["task_note"] == task_note(executed_task(task, "tracking-lost"))
    assert suite.execution_columns({**row, "execute.status": "ok"})["task_achieved"] is True
    assert suite.execution_columns({"execute.status": "not run"}) == {
        "execution": None, "task_achieved": None, "task_note": None, "execute_key": None}


@pytest.mark.slow
def test_bench_suite_executes_every_plan_and_reports_its_verdict(tmp_path):
    """Two problems (the MJCF arm, two targets) x two solvers (R-AICO, iLQG), 3 iterations, end to end: every
    plan executed in Drake; each record's columns are execute's own status and judgement of that run, and the
    executed profile solves exactly the cells executed ok and achieved."""
    shutil.copy(ROOT / "raico" / "problems" / "suite" / "models" / "arm3.xml", tmp_path / "arm3.xml")
    for name, target in (("near", "[0.02, 0.0, -0.02]"), ("far", "[0.1, 0.0, -0.1]")):
        (tmp_path / f"{name}.toml").write_text(PROBLEM.format(name=name, model="arm3.xml", weld="", T=20, frame="tip")
                                               .replace("[0.05, 0.0, -0.05]", target))
    (tmp_path / "suite.toml").write_text('name = "two"\niterations = 3\nreference = true\n[[solver]]\nlabel = "R-AICO"\n'
                                         'solver = "raico"\n[[solver]]\nlabel = "iLQG"\nsolver = "ilqg"\n')
    art, out = tmp_path / "art", tmp_path / "out"
    res = runner.invoke(app, ["bench", "suite", str(tmp_path / "suite.toml"), "--artifacts", str(art), "--out",
                              str(out), "--quiet"])
    assert res.exit_code == 0, res.output
    doc = json.loads((out / "two.json").read_text())
    from raico.stages.evaluate.metrics import STATUSES, executed_task

    assert len(doc["records"]) == 4
    for r in doc["records"]:
        assert r["key"] and r["execute_key"] and r["execution"] in STATUSES
        meta = json.loads((art / "execute" / r["execute_key"] / "meta.json").read_text())
        verdict = executed_task(meta["metrics"]["task"], meta["status"])
        assert r["execution"] == meta["status"] and r["task_achieved"] == verdict["achieved"]
        assert r["inside_limits"] == suite.inside_limits(r)
    ex = doc["profiles"]["all"]["executed"]["ratios"]
    for r in doc["records"]:
        solved = ex[r["solver"]][doc["profiles"]["all"]["problems"].index(r["problem"])] is not None
        assert solved == suite.executed_ok(r)
    assert doc["executions"]["runs"] == 4 and doc["executions"]["ok_achieved"] == sum(map(suite.executed_ok,
                                                                                           doc["records"]))
    page = (out / "two.md").read_text()
    assert "## Executed in Drake" in page and "| inside | execution | task |" in page
    for r in doc["records"]:   # the cost and the violation per iteration: the plan's iterations, the start
        assert len(r["iteration_costs"]) == r["iterations"] and len(r["iteration_range_excess"]) == r["iterations"] + 1
    assert (out / "two_iterations.png").stat().st_size > 10_000
    # the transcription reference on both (3 joints, T = 20), warm-started from one of their plans
    keys = {r["key"] for r in doc["records"]}
    assert set(doc["references"]) == {"near", "far"}
    for ref in doc["references"].values():
        assert ref["warm_key"] in keys and isinstance(ref["feasible"], bool) and ref["cost"] > 0
    assert "### The direct-transcription reference" in page


def test_iterate_range_excess_is_the_largest_excess_per_recorded_iterate():
    robot = SimpleNamespace(n_q=2, lower=np.array([-1.0, -2.0]), upper=np.array([1.0, 2.0]))
    t = np.array([0, 2, 4])
    X = np.zeros((3, 3, 4))
    X[0, 0, 0] = 5.0                  # the start (step 0) outside: not the plan's doing, left out
    X[1, 1, 1] = -2.25                # iteration 1: joint 2 0.25 below its range at step 2
    X[1, 2, 0] = 1.1                  # ... and joint 1 0.1 above at step 4
    X[2] = np.nan                     # iteration 2 not recorded
    out = suite.iterate_range_excess(X, t, robot)
    assert out[0] == 0.0 and out[1] == pytest.approx(0.25) and np.isnan(out[2])


def test_the_reference_key_is_a_boolean(tmp_path):
    path = _tiny(tmp_path, 'reference = "yes"', talos=False)
    text = path.read_text().replace('reference = "yes"\n', "")
    path.write_text('reference = "yes"\n' + text)
    with pytest.raises(BadInput, match="reference must be true or false"):
        suite.load(path)
    path.write_text("reference = true\n" + text)
    assert suite.load(path).reference is True


def test_a_spent_reference_budget_reads_the_cache_and_solves_nothing(tmp_path):
    from raico.pipeline.experiments.transcription import cache_key
    from raico.stages.plan.stage import PlanConfig, build_problem

    file = Path(suite.__file__).resolve().parents[2] / "problems" / "suite" / "arm3_sdf_reach.toml"
    s = suite.Suite("mini", "", tmp_path / "suite.toml", [suite.SolverEntry("A", {"solver": "raico"})],
                    [suite.ProblemEntry("p", file)])
    recs = [{"problem": "p", "solver": "A", "key": "k" * 16, "final_cost": 2.0, "inside_limits": True}]
    cache = SimpleNamespace(root=tmp_path)
    said: list[str] = []
    assert suite.reference_record(cache, s, s.problems[0], recs, said.append, cached_only=True) is None
    assert said == ["suite: p: no transcription reference in this call (reference_total_s = inf s spent; "
                    "the next call goes on)"]
    old = tmp_path / "reference" / f"{'k' * 16}-snopt-{suite.REFERENCE_ITERATIONS}.json"
    old.parent.mkdir()
    old.write_text(json.dumps({"cost": 0.5, "feasible": True}))   # a reference of the old key: not reused
    assert suite.reference_record(cache, s, s.problems[0], recs, said.append, cached_only=True) is None
    cfg = PlanConfig(**{**suite.options(s.problems[0], s.solvers[0]), "bounds": "hard"})
    pb = build_problem(cfg)[2]
    kept = tmp_path / "reference" / f"{cache_key(pb, 'k' * 16, 'snopt', suite.REFERENCE_ITERATIONS)}.json"
    kept.parent.mkdir(exist_ok=True)
    kept.write_text(json.dumps({"cost": 1.5, "feasible": True}))
    assert suite.reference_record(cache, s, s.problems[0], recs, said.append, cached_only=True)["cost"] == 1.5
