"""The built-in plants, loaded as any model file is, and the robot of a stored plan.

A built-in plant is a model file with its robot's facts: ``raico/plants/models/NAME.urdf`` and
``raico/plants/models/NAME.toml``, whose keys are a problem file's ``[robot]`` keys (``file``, ``weld``,
``armature``, ``start``) plus the facts (:class:`raico.plants.model_file.RobotSpec`): the joints one motor
couples, the end effectors, hands and soles, the sole's outline, how the robot is executed and the
learning loop's defaults. ``load_robot(name)`` is ``load_model(builtin_spec(name))``: one route from a
file to a :class:`raico.plants.robot.Robot` (a finalized continuous-time plant registered with a scene graph, the planning
joints, the map from planning coordinates to the plant's positions, the facts).

Planning coordinates: ``q (n_q,)`` in rad. The plant's positions are ``P @ q`` with
``P (n_plant, n_q)``: the identity unless joints are coupled (the Nao: 25 planning joints drive 26
tree joints, RHipYawPitch copies LHipYawPitch: one motor on the real robot). Torques map back with
``P.T``.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from raico.plants.model_file import RobotSpec, load_model, shared_model
from raico.plants.robot import BABBLE_TORQUE_LIMIT, LEARN_DEFAULTS, Robot

if TYPE_CHECKING:   # Drake loads when a robot is built, not when the plant names are read
    from pydrake.systems.framework import DiagramBuilder

__all__ = ["BABBLE_TORQUE_LIMIT", "LEARN_DEFAULTS", "MODELS", "PLANTS", "Chain", "Robot", "builtin_spec", "chain_reach",
           "kinematic_chain", "load_robot", "load_robot_for", "robot_for", "shared_robot"]

MODELS = Path(__file__).resolve().parent / "models"
PLANTS = ("pendulum", "cartpole", "arm5", "biorob", "nao")  # the built-in plants: raico/plants/models/NAME.{urdf,toml}


@cache
def builtin_spec(name: str):
    """The :class:`raico.plants.model_file.RobotSpec` of built-in plant ``name`` (``raico/plants/models/NAME.toml``)."""
    if name not in PLANTS:
        raise ValueError(f"unknown plant '{name}': choose one of {', '.join(PLANTS)}")
    d = tomllib.loads((MODELS / f"{name}.toml").read_text())
    return RobotSpec.from_dict({**d, "file": str(MODELS / d["file"]), "plant": name})


def load_robot(name: str, builder: DiagramBuilder | None = None, time_step: float = 0.0) -> Robot:
    """A fresh built-in robot (its own plant and scene graph, optionally inside ``builder``), loaded from its
    model file as any model file is (``raico.plants.model_file.load_model``).

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


def load_robot_for(desc: dict, builder=None, time_step: float = 0.0, true: bool = False,
                   before_finalize=None) -> Robot:
    """A fresh robot (its own plant) of a stored plan description, as ``raico.plants.robots.load_robot``
    (``true``: as :func:`robot_for`; ``before_finalize``: as ``raico.plants.model_file.load_model``)."""
    spec = _desc_spec(desc, true)
    if spec is None:
        return load_model(builtin_spec(desc["plant"]), builder, time_step, before_finalize)
    return load_model(RobotSpec.from_dict(spec), builder, time_step, before_finalize)


PARALLEL = 1e-9   # |a x b| of two unit joint axes below this: parallel (rounding of a file's axes and poses)


@dataclass(frozen=True)
class Link:
    """A vector of a kinematic chain (m, world, at the robot's current configuration) and the number of
    moving joints, counted from the world, that move it; ``travel`` ``(lower, upper)`` (m): ``vector`` is
    a prismatic joint's unit axis, scaled by its position in that range."""

    vector: np.ndarray
    movers: int
    travel: tuple[float, float] | None = None


@dataclass(frozen=True)
class Chain:
    """The chain from the world to a point of a frame: ``base (3,)`` where it leaves the world (m, world),
    its moving ``joints`` from the world outward (``(kind, unit axis (3,) in world)``) and its ``links``:
    the point is ``base`` plus the sum of the links, each turned and the prismatic ones scaled by the
    joints that move them."""

    base: np.ndarray
    joints: tuple[tuple[str, np.ndarray], ...]
    links: tuple[Link, ...]

    def reach(self) -> float:
        """How far the point can get from ``base`` in any direction (m): the links' lengths and each
        prismatic joint's largest travel (a bound, not the workspace)."""
        return sum(max(abs(link.travel[0]), abs(link.travel[1])) if link.travel else float(np.linalg.norm(link.vector))
                   for link in self.links)

    def reach_along(self, direction: np.ndarray) -> float:
        """A bound on how far the point can get from ``base`` along unit ``direction (3,)`` (m, world):
        ``max_q d . (p(q) - base)`` is at most the sum over the links of the most each one can add.

        Why a bound from the chain and not sampled configurations: a sample's extent lies inside the
        workspace, so a target beyond it may still be reachable, and a note that says "beyond its reach"
        must be true; this bound is never below the true extent, and it is exact where it matters most,
        a lift or a shoulder that sits above the base. A link that no revolute joint turns (world-fixed,
        or moved by prismatic joints only) adds ``d . v``; one that only joints about parallel axes ``a``
        turn keeps its component along ``a`` (a vertical lift, a column's height, a SCARA's links) and
        adds ``(d . a)(a . v) + |d_perp| |v_perp|`` (``_perp``: the parts normal to ``a``); any other adds
        its length ``|v|``. A prismatic link adds the larger of its range's two ends. Each term is at
        most ``|v|``, so the bound is never above :meth:`reach`; the joints' revolute ranges are not
        used (a bound, not the workspace)."""
        d = np.asarray(direction, float)
        return sum(max(self._most(d, lim * link.vector, link.movers) for lim in link.travel) if link.travel
                   else self._most(d, link.vector, link.movers) for link in self.links)

    def _most(self, d: np.ndarray, v: np.ndarray, movers: int) -> float:
        """The most ``d . R v`` can be over the rotations ``R`` the first ``movers`` joints make."""
        axes = [axis for kind, axis in self.joints[:movers] if kind == "revolute"]
        if not axes:
            return float(d @ v)
        a = axes[0]
        if any(np.linalg.norm(np.cross(a, b)) > PARALLEL for b in axes[1:]):
            return float(np.linalg.norm(v))
        return float((d @ a) * (a @ v) + np.linalg.norm(d - (d @ a) * a) * np.linalg.norm(v - (a @ v) * a))


def kinematic_chain(robot: Robot, frame_name: str, offset=(0.0, 0.0, 0.0)) -> Chain | None:
    """The chain that carries the point ``offset (3,)`` (m, frame coordinates) of frame ``frame_name``
    from the world, at the robot's current configuration (:class:`Chain`); ``None`` where the chain does
    not reach the world through revolute, prismatic and welded joints (a free or ball joint, a
    prismatic joint without limits, a robot standing on a welded sole whose tree Drake re-rooted) or the
    point is on the world."""
    plant, ctx = robot.plant, robot.context
    frame = plant.GetFrameByName(frame_name)
    by_child = {plant.get_joint(i).child_body().index(): plant.get_joint(i) for i in plant.GetJointIndices()}
    world = plant.world_body().index()
    point = np.asarray(frame.CalcPoseInWorld(ctx).multiply(np.asarray(offset, float)), float)
    down: list[tuple[np.ndarray, int, tuple[float, float] | None]] = []   # (vector, moving joints above, travel)
    joints: list[tuple[str, np.ndarray]] = []   # the moving joints, from the frame down
    body = frame.body().index()
    for _ in range(plant.num_bodies()):
        if body == world:
            return None    # the point is on the world: nothing moves it
        joint = by_child.get(body)
        if joint is None or joint.num_positions() > 1:
            return None
        kind = joint.type_name() if joint.num_positions() == 1 else "weld"
        if kind not in ("revolute", "prismatic", "weld"):
            return None
        if kind != "weld":   # a weld: the point stays where it is, on the parent body now
            origin = joint.frame_on_child().CalcPoseInWorld(ctx).translation()
            down.append((point - origin, len(joints), None))
            rotation = joint.frame_on_parent().CalcPoseInWorld(ctx).rotation().matrix()
            axis = rotation @ np.asarray(joint.revolute_axis() if kind == "revolute" else joint.translation_axis())
            joints.append((kind, axis / np.linalg.norm(axis)))
            if kind == "prismatic":
                lo, hi = float(joint.position_lower_limits()[0]), float(joint.position_upper_limits()[0])
                if not (np.isfinite(lo) and np.isfinite(hi)):
                    return None
                down.append((joints[-1][1], len(joints), (lo, hi)))
            point = joint.frame_on_parent().CalcPoseInWorld(ctx).translation()
        body = joint.parent_body().index()
        if body == world:
            m = len(joints)
            links = tuple(Link(v, m - above, travel) for v, above, travel in down)
            return Chain(point, tuple(joints[::-1]), links)
    return None


def chain_reach(robot: Robot, frame_name: str) -> tuple[np.ndarray, float] | None:
    """How far frame ``frame_name`` can get from the robot's base in any direction: ``(base (3,), reach)``
    (m, world; :meth:`Chain.reach`), ``None`` as :func:`kinematic_chain`."""
    chain = kinematic_chain(robot, frame_name)
    return None if chain is None else (chain.base, chain.reach())
