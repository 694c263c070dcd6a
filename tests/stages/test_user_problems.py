"""What a user's own robot and problem file meet before and after planning: a target beyond the
robot's reach said before planning, control toward gravity, success judged per term kind in its unit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from raico.pipeline.interface.cli import app
from raico.plants.model_file import example_robot_data
from tests.plants.test_model_file import problem_text, user_robot, write_problem
from tests.tolerance import close

FAR_REACH = """
[costs.reach]
type = "frame_position"
frame = "tip"
target = {target}
times = "last"
weight = 1e4

[costs.control]
type = "control"
weight = 1e-2
"""


@pytest.mark.numerics
def test_chain_reach_is_the_link_lengths_to_the_frame(tmp_path):
    from raico.plants.model_file import RobotSpec, load_model
    from raico.plants.robots import chain_reach, shared_robot

    robot = load_model(RobotSpec(file=str(user_robot(tmp_path))))
    base, reach = chain_reach(robot, "tip")     # the shoulder 0.1 m up, upper arm 0.3, forearm 0.25 (m)
    assert close(base, [0.0, 0.0, 0.1]) and close(reach, 0.55)
    base, reach = chain_reach(shared_robot("arm5"), "ee")
    assert close(reach, 1.25)   # five links of 0.25 m (its end effector starts at (1, 0, 0))


def test_a_target_beyond_reach_is_said_before_planning_and_planned_anyway(tmp_path):
    urdf = user_robot(tmp_path)
    far = write_problem(tmp_path, "far", problem_text(str(urdf), {}, FAR_REACH.format(target=[3.0, 0.0, 0.0]), T=10))
    r = CliRunner().invoke(app, ["plan", "--problem", str(far), "--iterations", "2", "--artifacts", str(tmp_path / "a")])
    assert r.exit_code == 0, r.output
    notes = [ln for ln in r.stderr.splitlines() if "beyond its reach" in ln]
    assert len(notes) == 1 and "'reach'" in notes[0] and "3 m from the robot's base" in notes[0] \
        and "reach of 0.55 m" in notes[0] and "planning anyway" in notes[0], r.stderr
    assert "plan " in r.stderr   # and it planned
    near = write_problem(tmp_path, "near", problem_text(str(urdf), {}, FAR_REACH.format(target=[0.3, 0.0, 0.4]), T=10))
    r = CliRunner().invoke(app, ["plan", "--problem", str(near), "--iterations", "2", "--artifacts", str(tmp_path / "a")])
    assert r.exit_code == 0 and "beyond its reach" not in r.stderr, r.stderr


UR5 = Path(__file__).resolve().parents[2] / "raico" / "problems" / "examples" / "ur5_reach.toml"


def _ur5_toward_gravity(tmp_path: Path) -> Path:
    """The README's UR5 reach with its control term toward the gravity-compensating torque."""
    text = UR5.read_text()
    assert text.rstrip().endswith('type = "control"\nweight = 1e-3')
    p = tmp_path / "ur5_reach.toml"   # beside nothing: the model file is a package:// URI
    p.write_text(text.rstrip() + '\ntarget = "gravity"\n')
    return p


@pytest.mark.numerics
@pytest.mark.skipif(example_robot_data() is None, reason="example-robot-data is not installed (pip extra baseline)")
@pytest.mark.parametrize("solver,iterations", [("raico", 20), ("fddp", 30)])
def test_control_toward_gravity_lets_an_arm_that_holds_itself_up_reach(tmp_path, solver, iterations):
    """The UR5 pays for holding itself up under a control cost toward zero; toward gravity it reaches
    closer (and the whole cost falls by two orders of magnitude)."""
    from raico.planning import crocoddyl as cm
    from raico.stages.plan.stage import PlanConfig, plan

    if solver == "fddp" and not cm.AVAILABLE:
        pytest.skip(cm.UNAVAILABLE_REASON)
    out = {}
    for label, path in (("zero", UR5), ("gravity", _ur5_toward_gravity(tmp_path))):
        m = plan(PlanConfig(problem=str(path), solver=solver, iterations=iterations).normalized()).metrics()
        out[label] = (m["final_cost"], m["via_point_errors"]["reach@100"])
    (c0, e0), (c1, e1) = out["zero"], out["gravity"]
    assert e1 < e0 / 3 and c1 < c0 / 10, out


@pytest.mark.numerics
def test_control_weights_per_joint_and_gravity_target_are_read_and_checked(tmp_path):
    from raico.planning.costs import ControlCost, ControlGravity
    from raico.stages.plan.stage import PlanConfig, build_problem

    urdf = user_robot(tmp_path)
    costs = FAR_REACH.format(target=[0.3, 0.0, 0.4]).replace("weight = 1e-2", "weight = [1e-2, 4e-2]")
    p = write_problem(tmp_path, "w", problem_text(str(urdf), {}, costs + '\n[costs.hold]\ntype = "control"\n'
                                                  'target = "gravity"\nweight = 0.5\n', T=10, dynamics="analytic"))
    _, _, problem, _, desc = build_problem(PlanConfig(problem=str(p)))
    effort = problem.term("control")
    assert isinstance(effort, ControlCost) and effort.weight == 4e-2 and np.allclose(effort.c, [0.25, 1.0])
    hold = problem.term("hold")
    assert isinstance(hold, ControlGravity) and hold in problem.joint_terms and hold.weight == 0.5
    U = np.ones((problem.T, 2))
    assert np.allclose(effort.value(U), 1e-2 + 4e-2)
    # the pseudo-dynamics' controls are accelerations: the gravity term does not apply to them
    _, _, pseudo, _, _ = build_problem(PlanConfig(problem=str(p), dynamics="pseudo"))
    assert "hold" not in pseudo.term_names() and "control" in pseudo.term_names()
    for bad, needle in (("weight = [1e-2]", "has 1 values, expected 2"), ('target = "up"', 'or "gravity"')):
        q = write_problem(tmp_path, "bad", problem_text(str(urdf), {}, costs.replace("weight = [1e-2, 4e-2]", bad)
                                                        + ("\nweight = 1.0" if "target" in bad else ""), T=10))
        with pytest.raises(ValueError, match=needle.replace("[", r"\[")):
            build_problem(PlanConfig(problem=str(q)))


@pytest.mark.numerics
def test_gravity_torques_hold_the_robot_still_and_their_jacobian_is_exact(tmp_path):
    from raico.plants.dynamics import AnalyticDynamics, GravityTorques
    from raico.plants.model_file import RobotSpec, load_model
    from raico.plants.numdiff import check_jacobian

    robot = load_model(RobotSpec(file=str(user_robot(tmp_path))))
    g = GravityTorques(robot)
    q = np.array([0.7, -0.4])
    tau, G = g.value_and_jacobian(q)
    assert np.abs(tau).min() > 0.1   # an arm that holds itself up (N m)
    acc = AnalyticDynamics(robot, 0.01).qddot(q, np.zeros(2), tau)
    assert np.abs(acc).max() <= 1e-9 * np.abs(tau).max()
    assert check_jacobian("dg/dq", G, g.value, q)


def test_crocoddyl_costs_control_toward_gravity_on_damped_joints_as_raico(tmp_path):
    """crocoddyl's own residual takes the actuation's torque u - D v, raico's term u: on damped joints the
    adapter measures the control itself, so the plan's cost is raico's (tests/planning/
    test_crocoddyl_damped_gravity.py: per term and derivatives)."""
    from raico.planning import crocoddyl as cm
    from raico.stages.plan.stage import PlanConfig, build_problem

    if not cm.AVAILABLE:
        pytest.skip(cm.UNAVAILABLE_REASON)
    urdf = user_robot(tmp_path)   # its shoulder is damped
    costs = FAR_REACH.format(target=[0.3, 0.0, 0.4]) + 'target = "gravity"\n'
    p = write_problem(tmp_path, "damped", problem_text(str(urdf), {}, costs, T=10, dynamics="analytic"))
    _, _, problem, _, _ = build_problem(PlanConfig(problem=str(p)))
    cp = cm.build(problem)
    rng = np.random.default_rng(0)
    X = problem.x0 + 0.5 * rng.standard_normal((problem.T + 1, problem.x0.size))
    U = rng.standard_normal((problem.T, problem.n_u))
    c = problem.cost(X, U)
    assert abs(cp.cost(X, U) - c) <= 1e-9 * c   # sums over 11 nodes of two recursions' rounding (tests/tolerance.py)


# ------------------------------------------------------------------ task achieved, per term kind in its unit
HELD = """
[costs.reach]
type = "frame_position"
frame = "tip"
target = [0.005, 0.0, 0.0]
relative = "start"
times = "last"
weight = 1e4

[costs.bend]
type = "posture"
joints = ["elbow"]
target = [0.03]
relative = "start"
times = "last"
weight = 10.0
{tol}

[costs.control]
type = "control"
weight = 1e-2
"""


def _held_problem(tmp_path, tol: str = ""):
    from raico.stages.plan.stage import PlanConfig, build_problem

    urdf = tmp_path / "two_link" / "urdf" / "two_link.urdf"
    urdf = urdf if urdf.exists() else user_robot(tmp_path)
    p = write_problem(tmp_path, "held", problem_text(str(urdf), {}, HELD.format(tol=tol), T=10))
    _, _, problem, _, _ = build_problem(PlanConfig(problem=str(p)))
    return problem, np.tile(problem.x0, (problem.T + 1, 1))   # the robot held at its start: errors 5 mm, 0.03 rad


@pytest.mark.numerics
def test_each_term_is_judged_in_its_unit_against_its_kinds_tolerance(tmp_path):
    from raico.planning.achieved import TASK_TOLERANCES, task_errors, task_line, task_verdict

    problem, X = _held_problem(tmp_path)
    errors = task_errors(problem, X)
    assert {k: (v["kind"], v["unit"], v["tol"]) for k, v in errors.items()} == {
        "reach": ("position", "m", TASK_TOLERANCES["position"][0]), "bend": ("posture", "rad", 0.05)}
    assert np.isclose(errors["reach"]["error"], 0.005, rtol=1e-9) and np.isclose(errors["bend"]["error"], 0.03, rtol=1e-9)
    verdict = task_verdict(errors)   # 0.03 rad is not judged against the 0.01 m of a position
    assert verdict["achieved"] and verdict["worst"] == "bend"   # 0.03 / 0.05 above 0.005 / 0.01
    assert task_line(verdict) == "task achieved: worst term 'bend' 0.03 rad <= 0.05 rad (posture)"
    problem, X = _held_problem(tmp_path, "tol = 0.02")    # the term's own tolerance
    verdict = task_verdict(task_errors(problem, X))
    assert not verdict["achieved"] and task_line(verdict) == "task missed: worst term 'bend' 0.03 rad > 0.02 rad (posture)"
    X[-1] = np.nan   # a diverged execution misses
    assert task_verdict(task_errors(problem, X))["error"] == np.inf
    with pytest.raises(ValueError, match=r"tol must be a number > 0"):
        _held_problem(tmp_path, "tol = -1.0")


@pytest.mark.numerics
def test_the_outcome_line_names_the_worst_term_and_its_unit():
    from raico.pipeline.engine.runner import Outcome, outcome_line

    task = {"achieved": True, "worst": "level", "kind": "orientation", "unit": "rad", "error": 0.0818, "tol": 0.1}
    line = outcome_line(Outcome("execute", "k" * 16, "p", True, "ok", {"task": task, "via_point_errors": {"reach@9": 0.002}}))
    assert "[ok; task achieved: worst term 'level' 0.0818 rad <= 0.1 rad (orientation)]" in line
    line = outcome_line(Outcome("execute", "k" * 16, "p", True, "limits", {"task": task}))
    assert "task missed: worst term 'level' 0.0818 rad <= 0.1 rad (orientation)" in line   # achieved needs status ok


def test_runs_table_has_achieved_and_exp_show_counts_statuses_and_only_the_used_thresholds(tmp_path):
    import json

    problem = write_problem(tmp_path, "reach", problem_text(str(user_robot(tmp_path)), {},
                                                            FAR_REACH.format(target=[0.3, 0.0, 0.4]), T=10,
                                                            dynamics="analytic"))
    exp = tmp_path / "exp.toml"
    exp.write_text(f'name = "reach-user"\nstages = ["plan", "execute"]\nseeds = "range(2)"\n[base]\n'
                   f'problem = "{problem}"\niterations = 2\nq0_std = 0.05\n')
    arts = tmp_path / "arts"
    r = CliRunner().invoke(app, ["exp", "run", str(exp), "--executor", "serial", "--artifacts", str(arts)])
    assert r.exit_code == 0, r.output
    rows = json.loads((arts / "exp" / "reach-user" / "runs.json").read_text())["rows"]
    assert [type(row["achieved"]) for row in rows] == [bool, bool]
    assert all(row["achieved"] == (row["execute.status"] == "ok" and row["execute.task.achieved"]) for row in rows)
    assert all(row["execute.task.worst"] == "reach" and row["execute.task.unit"] == "m" for row in rows)
    columns = set().union(*rows)
    assert "execute.thresholds.tracking_lost_rad" in columns
    assert not {c for c in columns if c.endswith(("foot_lift_m", "fall_torso_drop_m", "contact_tol_m"))}
    r = CliRunner().invoke(app, ["exp", "show", "reach-user", "--format", "json", "--artifacts", str(arts)])
    assert r.exit_code == 0, r.output
    (group,) = json.loads(r.stdout)
    k = sum(row["achieved"] for row in rows)
    assert group["achieved"] == f"{k}/2"
    statuses = {}
    for row in rows:
        statuses[row["status"]] = statuses.get(row["status"], 0) + 1
    assert group["statuses"] == ", ".join(f"{s} {n}" for s, n in sorted(statuses.items(), key=lambda kv: -kv[1]))
