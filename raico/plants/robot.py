"""What every robot is: a Drake plant with its planning view and its facts (:class:`Robot`).

A robot comes from a model file (``raico.plants.model_file.load_model``; the built-in plants are model files
too, ``raico.plants.robots``). Arrays are in planning coordinates: ``q (n_q,)`` in rad, torques in N m; the
plant's positions are ``P @ q``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:   # Drake loads when a robot is built
    from pydrake.multibody.plant import MultibodyPlant
    from pydrake.systems.framework import DiagramBuilder

BABBLE_TORQUE_LIMIT = 10.0  # N m (thesis §4.1)
LEARN_DEFAULTS = {"babble_points": 200, "stride": 20}  # the learning loop's defaults where a robot states none


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
    spec: Any  # the raico.plants.model_file.RobotSpec it was loaded from: its file, its mounting and its facts
    B_act: np.ndarray = None  # (n_plant, n_act) Drake actuation matrix: tau = B_act @ u_act
    velocity: np.ndarray | None = None  # (n_q,) rad/s (m/s), the model file's velocity limits (inf: none); None: unknown
    load_report: list = field(default_factory=list)  # what loading the model file changed (one line each)
    _context: Any = field(default=None, repr=False)
    _P_pinv: np.ndarray | None = field(default=None, repr=False)  # pinv(P), computed once

    @property
    def n_q(self) -> int:
        return len(self.joint_names)

    @property
    def n_x(self) -> int:
        return 2 * self.n_q

    # -- the robot's facts, read from its spec (raico.plants.model_file.FACTS) --------------------------
    @property
    def end_effectors(self) -> dict[str, str]:
        """Label -> frame."""
        return dict(self.spec.end_effectors)

    @property
    def support_polygon(self) -> np.ndarray | None:
        """``(k, 2)`` a sole's outline in its frame (m); None: no soles."""
        return np.array(self.spec.sole) if self.spec.sole else None

    @property
    def hands(self) -> tuple[str, ...]:
        """Frames drawn as hands."""
        return self.spec.hands

    @property
    def feet(self) -> tuple[str, ...]:
        """Sole frames, the stance (welded) one first."""
        return self.spec.feet

    @property
    def execution(self) -> str:
        """How the robot is executed (``raico.plants.model_file.EXECUTIONS``)."""
        return self.spec.execution

    @property
    def time_step(self) -> float:
        """The execution's step (s; a continuous plant's largest integrator step)."""
        return self.spec.time_step

    @property
    def builtin(self) -> bool:
        """A built-in plant (its plans store its name only), not a user's model file."""
        return self.spec.plant is not None

    @property
    def stands_on_a_link(self) -> bool:
        """Welded to the world at a link inside its tree (a humanoid on its sole), not at its root: the welded
        model's joint torques then carry what the unmodelled contacts carry, and are not its motors'."""
        from pydrake.multibody.tree import JointIndex

        plant, world = self.plant, self.plant.world_body().index()
        joints = [plant.get_joint(JointIndex(i)) for i in range(plant.num_joints())]
        welded = {j.child_body().index() for j in joints if j.parent_body().index() == world}
        return any(j.child_body().index() in welded and j.parent_body().index() != world for j in joints)

    @property
    def floating(self) -> bool:
        """Executed free-floating on its soles (a humanoid), not welded to the world."""
        return self.execution == "floating"

    def learn_defaults(self) -> dict[str, int]:
        """The learning loop's defaults: ``babble_points`` and ``stride`` (an arm's where the robot names none)."""
        return {**LEARN_DEFAULTS, **dict(self.spec.learn)}

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

    @property
    def actuated(self) -> np.ndarray:
        """Indices ``(n_act,)`` of the planning joints with a motor (all but the spec's ``unactuated``)."""
        off = set(self.spec.unactuated)
        return np.array([k for k, n in enumerate(self.joint_names) if n not in off], dtype=np.int64)

    @property
    def underactuated(self) -> bool:
        """Some planning joint has no motor (the cart-pole's pole): torque controls are the actuated joints'."""
        return len(self.actuated) < self.n_q

    @property
    def S(self) -> np.ndarray:
        """``(n_q, n_act)`` the selection of the actuated joints: joint torques ``tau = S @ u`` of motor
        commands ``u (n_act,)`` (N m or N); the identity for a fully actuated robot."""
        return np.eye(self.n_q)[:, self.actuated]

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
