"""Named planning tasks: plant + task name -> objective terms, horizon and step.

Every task builds its terms from the robot's task maps at the initial posture ``q0``; the
weights follow thesis eq. (3.7) (``w_task = 1e4``, ``w_u = 1e-2``) unless the experiment says
otherwise. Choices the thesis leaves open are listed in ``TASK_NOTES`` (the report's
deviations table reads them).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from planning import objective as ob
from plants.robots import Robot
from plants.taskmaps import CenterOfMass, FramePoints

W_TASK = 1e4
W_U = 1e-2


@dataclass(frozen=True)
class TaskSpec:
    """Horizon ``T`` steps of ``dt`` s and a builder ``(robot, q0, T) -> term descriptions``.

    The builder states the objective only (``planning.objective``); via-point times are
    fractions of ``T``, so the horizon is stated once, here.
    """

    plant: str
    name: str
    T: int
    dt: float
    build: Callable[[Robot, np.ndarray, int], list]
    description: str


def _arm_reach(roll: bool):
    def build(robot: Robot, q0: np.ndarray, T: int) -> list:
        ee = ob.frame_points("ee", "ee")
        terms = [ob.via("via_x1", ee, [1.0, -0.4, 0.0], [T // 2], W_TASK),
                 ob.via("via_x2", ee, [1.0, 0.0, 0.0], [T], W_TASK)]
        if roll:
            terms.append(ob.via("roll", ob.roll("ee"), [np.pi / 2], [T // 2, T], W_TASK))
        return [*terms, ob.control(W_U)]
    return build


SOLE_POINTS = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.05, 0.0]])


def _sole_term(robot: Robot, q0: np.ndarray, T: int) -> dict:
    """Right sole kept at its initial pose at every step (three points pin the pose)."""
    target = FramePoints(robot, "r_sole", points=SOLE_POINTS).value(q0)
    return ob.via("r_sole", ob.frame_points("r_sole", "r_sole", points=SOLE_POINTS), target, range(1, T + 1),
                  W_TASK)


def _torso_frame_point(robot: Robot, q0: np.ndarray, p_torso: np.ndarray) -> np.ndarray:
    X = robot.plant.GetFrameByName("torso").CalcPoseInWorld(robot.set_state(q0))
    return X.rotation().matrix() @ p_torso + X.translation()


def _nao_reach(robot: Robot, q0: np.ndarray, T: int) -> list:
    # thesis x* = (0, 0.2, 0.06), y and z counted; read in the torso frame at t = 0 with the
    # thesis's lateral axis pointing to the robot's right (as in fig. 3.4): y = -0.2 here.
    target = _torso_frame_point(robot, q0, np.array([0.0, -0.2, 0.06]))[1:]
    return [ob.via("via_hand", ob.frame_points("r_gripper", "r_hand", axes=(1, 2)), target, [T], W_TASK),
            ob.via("via_cog", ob.cog(), CenterOfMass(robot).value(q0), [T], W_TASK),
            _sole_term(robot, q0, T), ob.control(W_U)]


def _nao_balance(offsets=(-0.1, 0.1, 0.0)):
    def build(robot: Robot, q0: np.ndarray, T: int) -> list:
        c0 = CenterOfMass(robot).value(q0)
        # weights 1e6 on the lateral axis (y: model frame x forward, y left), 10 on the others
        C = np.array([10.0, 1e6, 10.0])
        n = len(offsets)
        terms = [ob.via(f"via_cog{i + 1}", ob.cog(), c0 + np.array([0.0, dy, 0.0]), [T * (i + 1) // n], 1.0, C)
                 for i, dy in enumerate(offsets)]
        return [*terms, _sole_term(robot, q0, T), ob.control(W_U)]
    return build


def _biorob_reach(robot: Robot, q0: np.ndarray, T: int) -> list:
    from plants.taskmaps import EndEffectorPosition

    target = EndEffectorPosition(robot, "ee").value(q0) + np.array([0.5, 0.0, 0.5])
    return [ob.via("via_ee", ob.frame_points("ee", "ee"), target, [T], W_TASK), ob.control(W_U)]


def _pendulum_swing_up(robot: Robot, q0: np.ndarray, T: int) -> list:
    return [ob.via("upright", ob.frame_points("ee", "ee_xz", axes=(0, 2)), [0.0, 1.0], [T], W_TASK),
            ob.control(W_U), ob.control_limit(-robot.effort, robot.effort, 1e4)]


NAO_REACH_T = 100
PENDULUM_T = 750
TASKS: dict[tuple[str, str], TaskSpec] = {
    ("arm5", "reach"): TaskSpec("arm5", "reach", 1000, 0.002, _arm_reach(False),
                                "end effector to (1,-0.4,0) at step 500 and (1,0,0) at 1000"),
    ("arm5", "reach-roll"): TaskSpec("arm5", "reach-roll", 1000, 0.002, _arm_reach(True),
                                     "as reach, plus the roll angle at pi/2 at both via-points"),
    ("nao", "reach"): TaskSpec("nao", "reach", NAO_REACH_T, 0.01, _nao_reach,
                               "right hand to (y, z) = (-0.2, 0.06) m in the torso frame, CoG held"),
    ("nao", "balance"): TaskSpec("nao", "balance", 300, 0.01, _nao_balance(),
                                 "CoG 0.1 m right, 0.1 m left, back (steps 100, 200, 300)"),
    ("nao", "balance-inside"): TaskSpec("nao", "balance-inside", 300, 0.01, _nao_balance((-0.05, 0.03, 0.0)),
                                        "CoG offsets that stay over the feet: -0.05, +0.03, 0 m"),
    ("biorob", "reach"): TaskSpec("biorob", "reach", 500, 0.002, _biorob_reach,
                                  "end effector to x0 + (0.5, 0, 0.5) m in 1 s"),
    ("pendulum", "swing-up"): TaskSpec("pendulum", "swing-up", PENDULUM_T, 0.002, _pendulum_swing_up,
                                       "end effector to the upright (0, 1) m"),
}

TASK_NOTES = {
    "nao reach target": "thesis x* = (0, 0.2, 0.06) read in the torso frame at t=0, lateral axis to the right",
    "nao reach horizon": f"{NAO_REACH_T} steps of 10 ms, via-point at the last step (thesis gives none)",
    "nao balance weights": "w = 1 with C = diag(10, 1e6, 10) (thesis: C scaled by [1e6, 10, 10])",
    "nao right sole": "three points of the right sole held at their initial positions, w = 1e4, every step",
    "arm5 roll": "roll = atan2(y_E . z_W, z_E . z_W) about the hand axis, moved by the shoulder, elbow, forearm roll "
                 "and wrist (a roll axis between two pitch axes); target pi/2 at both via-points",
    "arm5 start": "q0 ~ N(0, 0.05^2) about the zero posture, the thesis's initial pose x2 = (1, 0, 0) m",
    "pendulum horizon": f"{PENDULUM_T} steps of 2 ms (1.5 s): 300 ms cannot swing up under +-10 N m",
}


def task_names(plant: str | None = None) -> list[str]:
    return sorted({t for p, t in TASKS if plant is None or p == plant})


def get_task(plant: str, task: str) -> TaskSpec:
    if (plant, task) not in TASKS:
        valid = ", ".join(task_names(plant)) or "none"
        raise ValueError(f"unknown task '{task}' for plant '{plant}': choose one of {valid}")
    return TASKS[(plant, task)]
