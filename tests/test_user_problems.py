"""What a user's own robot and problem file meet before and after planning: a target beyond the
robot's reach said before planning, control toward gravity, success judged per term kind in its unit."""

from __future__ import annotations

import numpy as np
from typer.testing import CliRunner

from pipeline.cli import app
from tests.test_model_file import problem_text, user_robot, write_problem

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


def test_chain_reach_is_the_link_lengths_to_the_frame(tmp_path):
    from plants.model_file import RobotSpec, load_model
    from plants.robots import chain_reach, shared_robot

    robot = load_model(RobotSpec(file=str(user_robot(tmp_path))))
    base, reach = chain_reach(robot, "tip")     # base 0.1, upper arm 0.3, forearm 0.25 (m)
    assert np.allclose(base, 0.0, atol=1e-12) and np.isclose(reach, 0.65, rtol=1e-12)
    base, reach = chain_reach(shared_robot("arm5"), "ee")
    assert np.isclose(reach, 1.25, rtol=1e-12)   # five links of 0.25 m (its end effector starts at (1, 0, 0))


def test_a_target_beyond_reach_is_said_before_planning_and_planned_anyway(tmp_path):
    urdf = user_robot(tmp_path)
    far = write_problem(tmp_path, "far", problem_text(str(urdf), {}, FAR_REACH.format(target=[3.0, 0.0, 0.0]), T=10))
    r = CliRunner().invoke(app, ["plan", "--problem", str(far), "--iterations", "2", "--artifacts", str(tmp_path / "a")])
    assert r.exit_code == 0, r.output
    notes = [ln for ln in r.stderr.splitlines() if "beyond its reach" in ln]
    assert len(notes) == 1 and "'reach'" in notes[0] and "3 m from the robot's base" in notes[0] \
        and "reach of 0.65 m" in notes[0] and "planning anyway" in notes[0], r.stderr
    assert "plan " in r.stderr   # and it planned
    near = write_problem(tmp_path, "near", problem_text(str(urdf), {}, FAR_REACH.format(target=[0.3, 0.0, 0.4]), T=10))
    r = CliRunner().invoke(app, ["plan", "--problem", str(near), "--iterations", "2", "--artifacts", str(tmp_path / "a")])
    assert r.exit_code == 0 and "beyond its reach" not in r.stderr, r.stderr
