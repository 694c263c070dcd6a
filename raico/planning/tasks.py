"""Named planning tasks: plant + task name -> objective terms, horizon and step.

The built-in plants' tasks are problem files shipped in ``problems/`` (``raico.planning.problem_file``):
every task builds its terms from the robot's task maps at the initial posture ``q0``; the weights
follow thesis eq. (3.7) (``w_task = 1e4``, ``w_u = 1e-2``) unless the experiment says otherwise.
Choices the thesis leaves open are listed in ``TASK_NOTES`` (the report's deviations table reads
them).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial

import numpy as np

from raico.planning.problem_file import SHIPPED, ProblemFile, build_terms, read_problem
from raico.plants.robots import Robot

W_TASK = 1e4
W_U = 1e-2


@dataclass(frozen=True)
class TaskSpec:
    """Horizon ``T`` steps of ``dt`` s, the default dynamics and a builder ``(robot, q0, T) -> term
    descriptions`` (``raico.planning.objective``): the objective only, from a problem file."""

    plant: str
    name: str
    T: int
    dt: float
    build: Callable[[Robot, np.ndarray, int], list]
    description: str
    dynamics: str = "pseudo"
    start: str | dict | None = None  # the robot's start posture in place of its default ("zero" or {joint: rad})
    achieved: dict | None = None  # the problem file's [achieved]: {joint, angle, tol} of an execution's end
    substeps: int = 1  # model steps per control step of dt (the problem file's [dynamics] substeps)

    def robot(self, robot: Robot) -> Robot:
        """``robot`` with this task's start posture as its default (itself where the task names none): ``"zero"``
        sets every joint to 0, clipped to its range (the Nao's elbow rolls stop 0.03 rad short of it)."""
        if self.start is None:
            return robot
        q = np.zeros(robot.n_q) if self.start == "zero" else robot.default_q.copy()
        for name, value in ({} if isinstance(self.start, str) else self.start).items():   # "zero" or {joint: value}
            if name not in robot.joint_names:
                raise ValueError(f"[robot] start: unknown joint '{name}'")
            q[list(robot.joint_names).index(name)] = value
        return replace(robot, default_q=np.clip(q, robot.lower, robot.upper))


def task_from_problem(problem: ProblemFile) -> TaskSpec:
    """The task a problem file states (its terms built at the start posture ``q0``)."""
    return TaskSpec(problem.robot_label, problem.name, problem.T, problem.dt, partial(build_terms, problem),
                    problem.doc["description"], problem.dynamics, problem.plant_start, problem.achieved,
                    problem.substeps)


def _shipped_tasks() -> dict[tuple[str, str], TaskSpec]:
    """The built-in plants' tasks: the problem files shipped in ``problems/`` (``PLANT_TASK.toml``)."""
    out = {}
    for f in sorted(SHIPPED.glob("*.toml")):
        plant, _, task = f.stem.partition("_")
        spec = task_from_problem(read_problem(f))
        out[(plant, task)] = replace(spec, plant=plant, name=task)
    return out


TASKS: dict[tuple[str, str], TaskSpec] = _shipped_tasks()
STANDING_REACH_T = TASKS[("nao", "reach")].T
PENDULUM_T = TASKS[("pendulum", "swing-up")].T

TASK_NOTES = {
    "nao reach target": "thesis x* = (0, 0.2, 0.06) read in the torso frame at t=0, lateral axis to the right",
    "nao reach horizon": f"{STANDING_REACH_T} steps of 10 ms, via-point at the last step (thesis gives none)",
    "nao balance weights": "w = 1 with C = diag(10, 1e6, 10) (thesis: C scaled by [1e6, 10, 10])",
    "nao right sole": "three points of the right sole held at their initial positions, w = 1e4, every step",
    "arm5 roll": "roll = atan2(y_E . z_W, z_E . z_W) about the hand axis, moved by the shoulder, elbow, forearm roll "
                 "and wrist (a roll axis between two pitch axes); target pi/2 at both via-points",
    "arm5 start": "q0 ~ N(0, 0.05^2) about the zero posture, the thesis's initial pose x2 = (1, 0, 0) m",
    "pendulum horizon": f"{PENDULUM_T} steps of 2 ms ({PENDULUM_T * 0.002:g} s): 300 ms cannot swing up under +-10 N m, "
                        "1.5 s leaves the upright out of reach (every plan pushes at the limit throughout)",
}


def task_names(plant: str | None = None) -> list[str]:
    return sorted({t for p, t in TASKS if plant is None or p == plant})


def get_task(plant: str, task: str) -> TaskSpec:
    if (plant, task) not in TASKS:
        valid = ", ".join(task_names(plant)) or "none"
        raise ValueError(f"unknown task '{task}' for plant '{plant}': choose one of {valid}")
    return TASKS[(plant, task)]
