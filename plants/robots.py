"""The four robots as Drake MultibodyPlants.

``load_robot(name)`` gives a finalized continuous-time plant registered with a scene
graph, the planning joints (names, limits, efforts, default posture), the map from
planning coordinates to the plant's positions, and the end-effector frames.

Planning coordinates: ``q (n_q,)`` in rad. The plant's positions are ``P @ q`` with
``P (n_plant, n_q)``: the identity for the arms and the pendulum; for the Nao, 25
planning joints drive 26 tree joints (RHipYawPitch copies LHipYawPitch: one motor on
the real robot). Torques map back with ``P.T``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:   # Drake loads when a robot is built, not when the plant names are read
    from pydrake.multibody.plant import MultibodyPlant
    from pydrake.systems.framework import DiagramBuilder

MODELS = Path(__file__).resolve().parent / "models"
PLANTS = ("pendulum", "arm5", "biorob", "nao")
BABBLE_TORQUE_LIMIT = 10.0  # N m (thesis §4.1)

# Default postures (rad), by joint name; joints not named are 0.
_ARM_DEFAULT: dict[str, float] = {}  # arm5's zero posture is the thesis's initial pose (end effector at (1, 0, 0) m)
# Nao: standing with the torso leaned over the stance (left) leg: CoG above the left sole,
# right sole flat on the ground beside it (right knee solved so its sole height is 0).
_NAO_DEFAULT = {
    "LHipRoll": -0.22, "LHipPitch": -0.35, "LKneePitch": 0.7, "LAnklePitch": -0.35, "LAnkleRoll": 0.3,
    "RHipRoll": -0.22, "RHipPitch": -0.1975, "RKneePitch": 0.395, "RAnklePitch": -0.1975,
    "RAnkleRoll": 0.3,
    "LShoulderPitch": 1.4, "LShoulderRoll": 0.25, "LElbowYaw": -1.2, "LElbowRoll": -0.6,
    "RShoulderPitch": 1.4, "RShoulderRoll": -0.25, "RElbowYaw": 1.2, "RElbowRoll": 0.6,
}
_DEFAULTS = {"pendulum": {}, "arm5": _ARM_DEFAULT, "biorob": {"shoulder_pitch": 0.9, "elbow_pitch": 1.3,
                                                              "wrist_pitch": 0.4}, "nao": _NAO_DEFAULT}
_END_EFFECTORS = {
    "pendulum": {"ee": "ee"},
    "arm5": {"ee": "ee"},
    "biorob": {"ee": "ee"},
    "nao": {"r_hand": "r_gripper", "l_hand": "l_gripper", "r_sole": "r_sole", "l_sole": "l_sole",
            "head": "gaze"},
}
# Nao sole outline in its sole frame (m): x from heel to toe, y across (approximation of the H25 foot).
NAO_SOLE_POLYGON = np.array([[-0.055, -0.044], [0.105, -0.044], [0.105, 0.044], [-0.055, 0.044]])
# Reflected motor inertia (kg m^2, rotor inertia x gear ratio^2) on every joint of the geared
# robots. Light links (hands, wrists) otherwise make the PD loops stiff and the mass matrix
# ill-conditioned; the pendulum is the thesis's ideal point mass and has none.
REFLECTED_INERTIA = {"pendulum": 0.0, "arm5": 5e-3, "biorob": 5e-3, "nao": 5e-3}


@dataclass
class Robot:
    """A plant with its planning view. Arrays are in planning coordinates (rad, N m)."""

    name: str
    plant: MultibodyPlant
    scene_graph: Any
    builder: DiagramBuilder
    joint_names: tuple[str, ...]
    P: np.ndarray  # (n_plant, n_q)
    lower: np.ndarray
    upper: np.ndarray
    effort: np.ndarray
    default_q: np.ndarray
    end_effectors: dict[str, str]
    B_act: np.ndarray = None  # (n_plant, n_act) Drake actuation matrix: tau = B_act @ u_act
    support_polygon: np.ndarray | None = None  # (k, 2) in the stance sole frame, Nao only
    spec: Any = None  # plants.model_file.RobotSpec of a robot loaded from a user's model file
    load_report: list = field(default_factory=list)  # what loading the model file changed (one line each)
    _context: Any = field(default=None, repr=False)
    _P_pinv: np.ndarray | None = field(default=None, repr=False)  # pinv(P), computed once

    @property
    def n_q(self) -> int:
        return len(self.joint_names)

    @property
    def n_x(self) -> int:
        return 2 * self.n_q

    @property
    def context(self):
        """A plant context for kinematics queries (shared; set positions before use)."""
        if self._context is None:
            self._context = self.plant.CreateDefaultContext()
        return self._context

    def to_plant_q(self, q: np.ndarray) -> np.ndarray:
        """Planning ``(..., n_q)`` -> plant positions ``(..., n_plant)``."""
        return q @ self.P.T

    def from_plant_q(self, qp: np.ndarray) -> np.ndarray:
        """Plant positions -> planning coordinates (least squares for coupled joints)."""
        if self._P_pinv is None:
            self._P_pinv = np.linalg.pinv(self.P)
        return qp @ self._P_pinv.T

    def plant_effort(self) -> np.ndarray:
        """Effort limits ``(n_plant,)`` (N m) of the plant's joints (a coupled joint: its motor's);
        unlimited joints are ``inf``."""
        return np.array([self.effort[row != 0][0] if np.any(row != 0) else np.inf for row in self.P])

    def babble_torque_limit(self) -> np.ndarray:
        """Per planning joint: min(10 N m, effort limit)."""
        return np.minimum(BABBLE_TORQUE_LIMIT, self.effort)

    def actuation(self, tau: np.ndarray) -> np.ndarray:
        """Generalized forces in plant velocity order -> the actuation input port's order."""
        return self.B_act.T @ tau

    def set_state(self, q: np.ndarray, v: np.ndarray | None = None, context=None):
        """Write planning ``q`` (and ``v``) into a plant context; returns the context."""
        ctx = self.context if context is None else context
        self.plant.SetPositions(ctx, self.to_plant_q(q))
        if v is not None:
            self.plant.SetVelocities(ctx, self.to_plant_q(v))
        return ctx


def _build(name: str, builder: DiagramBuilder | None, time_step: float = 0.0) -> Robot:
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.multibody.tree import JointIndex
    from pydrake.systems.framework import DiagramBuilder

    builder = builder or DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step)
    if time_step > 0:  # discrete: Drake's SAP solver enforces the joint position limits
        from pydrake.multibody.plant import DiscreteContactApproximation

        plant.set_discrete_contact_approximation(DiscreteContactApproximation.kLagged)
    Parser(plant).AddModels(str(MODELS / f"{name}.urdf"))
    if name == "nao":
        # stance sole welded to the world: Drake builds the reversed tree
        plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("l_sole"))
    for i in plant.GetJointActuatorIndices():
        act = plant.get_joint_actuator(i)
        act.set_default_gear_ratio(1.0)
        act.set_default_rotor_inertia(REFLECTED_INERTIA[name])
    plant.Finalize()
    joints = [plant.get_joint(JointIndex(i)) for i in range(plant.num_joints())]
    joints = [j for j in joints if j.num_positions() == 1]
    coupled = {"RHipYawPitch": "LHipYawPitch"} if name == "nao" else {}
    planning = [j for j in joints if j.name() not in coupled]
    col = {j.name(): k for k, j in enumerate(planning)}
    P = np.zeros((plant.num_positions(), len(planning)))
    for j in joints:
        P[j.position_start(), col[coupled.get(j.name(), j.name())]] = 1.0
    effort = np.array([_effort(plant, j) for j in planning])
    default = np.array([_DEFAULTS[name].get(j.name(), 0.0) for j in planning])
    return Robot(
        name=name, plant=plant, scene_graph=scene_graph, builder=builder,
        joint_names=tuple(j.name() for j in planning), P=P,
        lower=np.array([j.position_lower_limits()[0] for j in planning]),
        upper=np.array([j.position_upper_limits()[0] for j in planning]),
        effort=effort, default_q=default, end_effectors=dict(_END_EFFECTORS[name]),
        B_act=plant.MakeActuationMatrix(),
        support_polygon=NAO_SOLE_POLYGON.copy() if name == "nao" else None,
    )


def _effort(plant: MultibodyPlant, joint) -> float:
    for i in plant.GetJointActuatorIndices():
        act = plant.get_joint_actuator(i)
        if act.joint().index() == joint.index():
            return float(act.effort_limit())
    return np.inf


def load_robot(name: str, builder: DiagramBuilder | None = None, time_step: float = 0.0) -> Robot:
    """A fresh robot (its own plant and scene graph, optionally inside ``builder``).

    ``time_step`` 0 (the default, used for planning): a continuous-time plant, joint limits
    not enforced. ``time_step > 0``: a discrete plant (SAP) that enforces the joint position
    limits (the arms' execution model)."""
    if name not in PLANTS:
        raise ValueError(f"unknown plant '{name}': choose one of {', '.join(PLANTS)}")
    return _build(name, builder, time_step)


@cache
def shared_robot(name: str) -> Robot:
    """One robot per name and process for kinematics and dynamics queries (not for diagrams)."""
    return load_robot(name)



def chain_reach(robot: Robot, frame_name: str) -> tuple[np.ndarray, float] | None:
    """How far frame ``frame_name`` can get from the robot's base: ``(base (3,), reach)`` (m, world).

    The chain from the frame's body down to the world: ``base`` is where it leaves the world (the
    origin of the joint whose parent is the world), ``reach`` the sum of the distances between
    successive joint origins along it, the frame's offset from the last one, and each prismatic
    joint's largest travel. Revolute joints turn about their origins, so the frame never gets
    farther from ``base`` than ``reach`` (a bound, not the workspace). ``None`` where the chain does
    not reach the world through one-coordinate joints and welds (a free or ball joint, a prismatic
    joint without limits, a robot standing on a welded sole whose tree Drake re-rooted)."""
    plant, ctx = robot.plant, robot.context
    frame = plant.GetFrameByName(frame_name)
    by_child = {plant.get_joint(i).child_body().index(): plant.get_joint(i) for i in plant.GetJointIndices()}
    world = plant.world_body().index()
    point = frame.CalcPoseInWorld(ctx).translation()
    reach, body = 0.0, frame.body().index()
    for _ in range(plant.num_bodies()):
        if body == world:
            return None    # the frame is on the world: nothing moves it
        joint = by_child.get(body)
        if joint is None or joint.num_positions() > 1:
            return None
        origin = joint.frame_on_child().CalcPoseInWorld(ctx).translation()
        reach += float(np.linalg.norm(point - origin))
        if joint.num_positions() == 1 and joint.type_name() == "prismatic":
            travel = max(abs(float(joint.position_lower_limits()[0])), abs(float(joint.position_upper_limits()[0])))
            if not np.isfinite(travel):
                return None
            reach += travel
        point = joint.frame_on_parent().CalcPoseInWorld(ctx).translation()
        body = joint.parent_body().index()
        if body == world:
            return point, reach
    return None
