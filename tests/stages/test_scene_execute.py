"""A scene end to end: the shipped example planned and executed (status, smallest distance, recording), and an
execution that runs into an object reported ``collided``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from raico.pipeline.interface.cli import app
from raico.planning.costs import Collision
from raico.planning.objective import objective_from_description
from raico.stages.evaluate.metrics import STATUSES
from tests.plants.test_scene import _problem

ROOT = Path(__file__).resolve().parents[2]
POLE = ROOT / "raico" / "problems" / "examples" / "ur5_pole.toml"


def _plan_and_execute(problem: Path, arts: Path, *plan_args: str) -> tuple[Path, Path]:
    r = CliRunner().invoke(app, ["plan", "--problem", str(problem), *plan_args, "--artifacts", str(arts)])
    assert r.exit_code == 0, r.output
    plan = next((arts / "plan").iterdir())
    r = CliRunner().invoke(app, ["execute", "--plan", plan.name, "--artifacts", str(arts)])
    assert r.exit_code == 0, r.output
    return plan, next((arts / "execute").iterdir())


def _metrics(folder: Path) -> dict:
    meta = json.loads((folder / "meta.json").read_text())
    return meta.get("metrics", meta)


def _smallest(plan: Path, X: np.ndarray) -> float:
    desc = json.loads((plan / "problem.json").read_text())
    terms = [t for t in objective_from_description(desc).state_terms if isinstance(t, Collision)]
    return min(t.smallest(X)[0] for t in terms)


def test_the_shipped_scene_example_plans_executes_and_records_its_distances(tmp_path):
    """Few iterations: the outcome is not asserted, only that the execution's status is one of the statuses and
    says collided exactly when a distance went below 0, and that its smallest distance is the rollout's."""
    from rerun.chunk import RrdReader

    plan, execute = _plan_and_execute(POLE, tmp_path / "a", "--iterations", "4")
    m = _metrics(execute)
    assert m["status"] in STATUSES and "collided" in STATUSES
    X = np.load(execute / "rollout.npz")["X"]
    assert m["min_distance"] == _smallest(plan, X)
    assert m["contact"] == (m["min_distance"] < 0) and (m["status"] == "collided") <= m["contact"]
    assert 0.0 <= m["min_distance_time"] <= 1.0 and " | " in m["min_distance_pair"]
    entities = {str(c.entity_path) for c in RrdReader(str(execute / "recording.rrd")).stream()}
    assert {"/world/scene/pole", "/world/scene/table", "/world/distances", "/collision/min_distance",
            "/world/robot/forearm_link/collision/forearm_link_0"} <= entities


BLOCKED = """
[[scene]]
name = "wall"
type = "box"
size = [0.6, 0.02, 0.8]
pose = [0.2906, 0.2448, 0.6, 0.0, 0.0, 0.7]
"""
SWING = """
[costs.reach]
type = "frame_position"
frame = "tip"
target = [0.152, 0.39, 0.615]
times = "last"
weight = 1e4

[costs.control]
type = "control"
weight = 1e-3

[costs.watch]
type = "collision"
pairs = [["robot", "wall"]]
margin = 0.0
hard = false
weight = 0.0
"""


def test_an_execution_that_runs_into_an_object_is_collided(tmp_path):
    """The arm turns 1 rad about its yaw axis through a wall standing radially on the bisector (0.08-0.68 m from the
    axis, 0.2-1.0 m high: no way round or over it within reach); the collision term only watches (weight 0): the plan
    goes through the wall, the executed arm meets it, and the status says so."""
    problem = _problem(tmp_path, costs=SWING, scene=BLOCKED, start={"yaw": 0.2, "shoulder": 0.6, "elbow": 0.9}, T=40)
    plan, execute = _plan_and_execute(problem, tmp_path / "a", "--iterations", "30")
    X_plan = np.load(plan / "plan.npz")["X"]
    assert _smallest(plan, X_plan) < -0.02   # the premise: the plan passes through the wall
    m = _metrics(execute)
    assert m["status"] == "collided" and m["contact"] and m["min_distance"] < 0, m
    assert m["reason"].startswith("contact: ") and "| wall at t = " in m["reason"]
