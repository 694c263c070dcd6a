"""What the plan stage says before planning a problem file's robot: a target beyond the reach in its
direction (a lift's travel reaches up, not out), a start outside the joint limits against the bounds
in force."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.plants.test_model_file import problem_text, user_robot, write_problem
from tests.tolerance import close

# a lift (prismatic, 0-0.4 m up) under a horizontal two-link arm (both joints about z): it reaches
# 0.5 + 0.41 = 0.91 m out from the lift's axis and 0.1 + 0.4 = 0.5 m up from the lift's foot at
# (0, 0, 0.2); the link lengths with the lift's travel sum to 1.41 m
LIFT_URDF = """<?xml version="1.0"?>
<robot name="lift_arm">
  <link name="base"><inertial><mass value="5"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/>
  </inertial></link>
  <joint name="lift" type="prismatic"><parent link="base"/><child link="column"/><axis xyz="0 0 1"/>
    <origin xyz="0 0 0.2"/><limit lower="0" upper="0.4" effort="200" velocity="0.5"/></joint>
  <link name="column"><inertial><origin xyz="0 0 0.05"/><mass value="2"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="shoulder" type="revolute"><parent link="column"/><child link="upper"/><axis xyz="0 0 1"/>
    <origin xyz="0 0 0.1"/><limit lower="-2.5" upper="2.5" effort="50" velocity="3"/></joint>
  <link name="upper"><inertial><origin xyz="0.25 0 0"/><mass value="1"/>
    <inertia ixx="0.001" iyy="0.02" izz="0.02" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="elbow" type="revolute"><parent link="upper"/><child link="fore"/><axis xyz="0 0 1"/>
    <origin xyz="0.5 0 0"/><limit lower="-2.5" upper="2.5" effort="30" velocity="3"/></joint>
  <link name="fore"><inertial><origin xyz="0.2 0 0"/><mass value="0.6"/>
    <inertia ixx="0.001" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="tip_joint" type="fixed"><parent link="fore"/><child link="tip"/><origin xyz="0.41 0 0"/></joint>
  <link name="tip"/>
</robot>
"""

REACH = """
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


def lift_arm(tmp_path: Path) -> Path:
    p = tmp_path / "lift_arm.urdf"
    p.write_text(LIFT_URDF)
    return p


def _load(path: Path):
    from raico.plants.model_file import RobotSpec, load_model

    return load_model(RobotSpec(file=str(path)))


def _sampled_extent(robot, frame: str, direction: np.ndarray, base: np.ndarray, n: int = 4000) -> float:
    """The largest ``direction . (p - base)`` over ``n`` configurations drawn uniformly in the joint ranges
    (revolute joints without one: a whole turn), with every corner of the ranges (m)."""
    import itertools

    plant = robot.plant
    ctx = plant.CreateDefaultContext()
    lo = np.where(np.isfinite(robot.lower), robot.lower, -np.pi)
    hi = np.where(np.isfinite(robot.upper), robot.upper, np.pi)
    rng = np.random.default_rng(0)
    corners = np.array(list(itertools.product(*zip(lo, hi))))
    frame = plant.GetFrameByName(frame)
    best = -np.inf
    for q in np.vstack([corners, rng.uniform(lo, hi, (n, robot.n_q))]):
        plant.SetPositions(ctx, robot.P @ q)
        best = max(best, float(direction @ (frame.CalcPoseInWorld(ctx).translation() - base)))
    return best


def test_the_reach_along_a_direction_is_a_bound_exact_for_a_lift_under_a_horizontal_arm(tmp_path):
    """Out: the arm's 0.91 m, the lift's travel adds nothing; up: the lift's travel and the column, the
    arm adds nothing; every sampled configuration stays within the bound, and for the lift arm (joints
    about one axis and a lift along it) the bound is attained."""
    from raico.plants.robots import kinematic_chain

    robot = _load(lift_arm(tmp_path))
    chain = kinematic_chain(robot, "tip")
    assert close(chain.base, [0.0, 0.0, 0.2])
    assert close(chain.reach(), 1.41)
    out, up, down = np.array([1.0, 0, 0]), np.array([0, 0, 1.0]), np.array([0, 0, -1.0])
    assert close(chain.reach_along(out), 0.91) and close(chain.reach_along(up), 0.5)
    assert close(chain.reach_along(down), -0.1)    # the arm never gets below its shoulder
    slant = np.array([0.6, 0.0, 0.8])
    assert close(chain.reach_along(slant), 0.6 * 0.91 + 0.8 * 0.5)
    for d in (out, up, slant, np.array([0.0, -0.6, 0.8])):
        sampled = _sampled_extent(robot, "tip", d, chain.base)
        assert sampled <= chain.reach_along(d) + 1e-9 and chain.reach_along(d) - sampled < 0.02, (d, sampled)
    # a chain of non-parallel joints (the two-link arm pitches about y on a base): its bound is its length
    # out and its sampled extent stays inside it in every direction
    two = _load(user_robot(tmp_path))
    chain = kinematic_chain(two, "tip")
    assert close(chain.base, [0.0, 0.0, 0.1]) and close(chain.reach(), 0.55)
    for d in (out, up, -up, slant):
        assert _sampled_extent(two, "tip", d, chain.base) <= chain.reach_along(d) + 1e-9


@pytest.mark.parametrize("target,said", [
    ([1.17, 0.0, 0.5], (1.17, 0.91, [1.0, 0.0, 0.0])),   # out: within the 1.41 m of links and travel, not the arm's
    ([0.0, 0.0, 0.95], (0.75, 0.5, [0.0, 0.0, 1.0])),    # up: above the lift's top
    ([0.5, 0.0, 0.9], (0.7, 0.5, [0.0, 0.0, 1.0])),      # toward it within reach, but above the lift's top
    ([0.6, 0.3, 0.5], None), ([0.5, 0.0, 0.6], None)])   # reachable: nothing said
def test_a_target_beyond_the_reach_in_its_direction_is_said(tmp_path, target, said):
    """A target farther from the lift's foot along some direction (toward it, along the joints' axes, out
    from them) than the chain can get along it is said, with that direction and both distances."""
    from raico.stages.plan.stage import PlanConfig, build_problem, reach_notes

    p = write_problem(tmp_path, "lift", problem_text(str(lift_arm(tmp_path)), {}, REACH.format(target=target), T=10))
    robot, _, problem, _, _ = build_problem(PlanConfig(problem=str(p)))
    notes = reach_notes(robot, problem)
    assert len(notes) == (said is not None), notes
    if said is not None:
        far, reach, direction = said
        assert (f"lies {far:.3g} m from the robot's base at [0.0, 0.0, 0.2] m along {direction}, beyond its reach "
                f"of {reach:.3g} m along it") in notes[0], notes


@pytest.mark.parametrize("bounds,costs,needle", [
    ("", "", "the hard bounds (--bounds hard, the default for a problem file) bring them back as fast as their velocity limits allow"),
    ("none", "", "no joint_limit term either: it plans as if there were no limits"),
    ("none", '\n[costs.limits]\ntype = "joint_limit"\ntimes = "all"\nweight = 1e3\n', "the joint_limit term pulls")])
def test_a_start_outside_the_limits_is_said_as_the_bounds_in_force_treat_it(tmp_path, bounds, costs, needle):
    """A problem file plans with hard bounds unless told otherwise: the note says so (it said "planning knows
    no limits" whatever the bounds), and the model's load report no longer guesses."""
    from raico.plants.robots import load_robot_for
    from raico.stages.plan.stage import PlanConfig, build_problem, start_limit_notes

    text = problem_text(str(user_robot(tmp_path)), {"start": {"shoulder": 2.5}},
                        REACH.format(target=[0.3, 0.0, 0.4]) + costs, T=10, dynamics="analytic")
    cfg = PlanConfig(problem=str(write_problem(tmp_path, "outside", text)), bounds=bounds).normalized()
    robot, _, problem, _, desc = build_problem(cfg)
    assert (problem.bounds is not None) == (bounds == "")
    notes = start_limit_notes(cfg, robot, problem)
    assert len(notes) == 1 and "outside the joint limits on shoulder (2.5, range -2 to 2)" in notes[0], notes
    assert needle in notes[0], notes
    report = [ln for ln in load_robot_for(desc).load_report if "outside the file's joint limits" in ln]
    assert len(report) == 1 and "knows no limits" not in report[0], report
    inside = PlanConfig(problem=str(write_problem(tmp_path, "inside", text.replace("2.5", "1.5")))).normalized()
    robot, _, problem, _, _ = build_problem(inside)
    assert start_limit_notes(inside, robot, problem) == []


def test_the_notes_are_said_once_per_experiment_and_once_within_a_loop(raico, tmp_path, capfd):
    """An experiment says a variant's notes before its runs, not in each run; plan() within
    ``load_notes_said`` (a learning loop's episodes) says each note once; a single plan says it."""
    from raico.stages.plan.stage import PlanConfig, load_notes_said, plan

    text = problem_text(str(lift_arm(tmp_path)), {"start": {"shoulder": 3.0}}, REACH.format(target=[1.17, 0.0, 0.5]),
                        T=10)
    p = write_problem(tmp_path, "lift", text)
    f = tmp_path / "exp.toml"
    f.write_text(f'name = "lift"\nstages = ["plan"]\nseeds = "range(3)"\n[base]\nproblem = "{p}"\n'
                 'iterations = 1\nq0_std = 0.01\n')
    res = raico("exp", "run", f, "--executor", "serial", "--artifacts", tmp_path / "arts")
    assert res.exit_code == 0, res.output
    for needle in ("beyond its reach", "the start is outside the joint limits on shoulder"):
        assert sum(needle in ln for ln in res.stderr.splitlines()) == 1, res.stderr
    capfd.readouterr()
    cfg = PlanConfig(problem=str(p), iterations=1).normalized()
    with load_notes_said():
        for _ in range(3):
            plan(cfg)
    err = capfd.readouterr().err
    assert err.count("beyond its reach") == 1 and err.count("the start is outside") == 1, err
    plan(cfg)
    err = capfd.readouterr().err
    assert err.count("beyond its reach") == 1 and err.count("the start is outside") == 1, err


def test_a_target_at_the_reach_is_within_it(tmp_path):
    """The arm stretched out (0.91 m from the lift's axis, at its top): at the bound, as rounded; no note.
    A millimetre farther: the note."""
    from raico.stages.plan.stage import PlanConfig, build_problem, reach_notes

    for x, said in ((0.91, 0), (0.911, 1)):
        p = write_problem(tmp_path, "edge", problem_text(str(lift_arm(tmp_path)), {},
                                                         REACH.format(target=[x * 0.6, x * 0.8, 0.7]), T=10))
        robot, _, problem, _, _ = build_problem(PlanConfig(problem=str(p)))
        assert len(reach_notes(robot, problem)) == said
