"""The built-in plants, loaded as any model file is, and the robot of a stored plan.

A built-in plant is a model file with its robot's facts: ``plants/models/NAME.urdf`` and
``plants/models/NAME.toml``, whose keys are a problem file's ``[robot]`` keys (``file``, ``weld``,
``armature``, ``start``) plus the facts (:class:`plants.model_file.RobotSpec`): the joints one motor
couples, the end effectors, hands and soles, the sole's outline, how the robot is executed and the
learning loop's defaults. ``load_robot(name)`` is ``load_model(builtin_spec(name))``: one route from a
file to a :class:`plants.robot.Robot` (a finalized continuous-time plant registered with a scene graph, the planning
joints, the map from planning coordinates to the plant's positions, the facts).

Planning coordinates: ``q (n_q,)`` in rad. The plant's positions are ``P @ q`` with
``P (n_plant, n_q)``: the identity unless joints are coupled (the Nao: 25 planning joints drive 26
tree joints, RHipYawPitch copies LHipYawPitch: one motor on the real robot). Torques map back with
``P.T``.
"""

from __future__ import annotations

import tomllib
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from plants.model_file import RobotSpec, load_model, shared_model
from plants.robot import BABBLE_TORQUE_LIMIT, LEARN_DEFAULTS, Robot

if TYPE_CHECKING:   # Drake loads when a robot is built, not when the plant names are read
    from pydrake.systems.framework import DiagramBuilder

__all__ = ["BABBLE_TORQUE_LIMIT", "LEARN_DEFAULTS", "MODELS", "PLANTS", "Robot", "builtin_spec", "chain_reach",
           "load_robot", "load_robot_for", "robot_for", "shared_robot"]

MODELS = Path(__file__).resolve().parent / "models"
PLANTS = ("pendulum", "cartpole", "arm5", "biorob", "nao")  # the built-in plants: plants/models/NAME.{urdf,toml}


@cache
def builtin_spec(name: str):
    """The :class:`plants.model_file.RobotSpec` of built-in plant ``name`` (``plants/models/NAME.toml``)."""
    if name not in PLANTS:
        raise ValueError(f"unknown plant '{name}': choose one of {', '.join(PLANTS)}")
    d = tomllib.loads((MODELS / f"{name}.toml").read_text())
    return RobotSpec.from_dict({**d, "file": str(MODELS / d["file"]), "plant": name})


def load_robot(name: str, builder: DiagramBuilder | None = None, time_step: float = 0.0) -> Robot:
    """A fresh built-in robot (its own plant and scene graph, optionally inside ``builder``), loaded from its
    model file as any model file is (``plants.model_file.load_model``).

    ``time_step`` 0 (the default, used for planning): a continuous-time plant, joint limits
    not enforced. ``time_step > 0``: a discrete plant (SAP) that enforces the joint position
    limits (the arms' execution model)."""
    return load_model(builtin_spec(name), builder, time_step)


@cache
def shared_robot(name: str) -> Robot:
    """One robot per name and process for kinematics and dynamics queries (not for diagrams)."""
    return load_robot(name)


def _desc_spec(desc: dict, true: bool) -> dict | None:
    """The stored spec of a plan description: the model file's (``robot``) or, with ``true``, the
    true robot's where the problem states one (``robot_true``)."""
    return (desc.get("robot_true") or desc.get("robot")) if true else desc.get("robot")


def robot_for(desc: dict, true: bool = False) -> Robot:
    """The shared robot of a stored plan description (``problem.json``): a built-in plant by name,
    or a model file's robot by its spec (``desc["robot"]``; with ``true`` the robot that is
    executed, ``desc["robot_true"]`` where the problem states one)."""
    spec = _desc_spec(desc, true)
    return shared_robot(desc["plant"]) if spec is None else shared_model(RobotSpec.from_dict(spec))


def load_robot_for(desc: dict, builder=None, time_step: float = 0.0, true: bool = False) -> Robot:
    """A fresh robot (its own plant) of a stored plan description, as ``plants.robots.load_robot``
    (``true``: as :func:`robot_for`)."""
    spec = _desc_spec(desc, true)
    if spec is None:
        return load_robot(desc["plant"], builder, time_step)
    return load_model(RobotSpec.from_dict(spec), builder, time_step)


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
