"""Task maps phi(q) with Jacobians.

Contract: a task map takes joint positions ``q (n_q,)`` in planning coordinates (rad)
and returns a task value ``(dim,)`` (metres or radians) and its Jacobian
``(dim, n_q)``. ``values_and_jacobians(Q)`` does the same for ``Q (K, n_q)`` and
returns ``(K, dim)`` and ``(K, dim, n_q)``. Task maps know nothing of time or costs.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class TaskMap(Protocol):
    name: str
    dim: int

    def value_and_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``phi(q) (dim,)`` and ``d phi / d q (dim, n_q)``."""
        ...

    def values_and_jacobians(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Batched: ``(K, dim)`` and ``(K, dim, n_q)`` for ``Q (K, n_q)``."""
        ...


class _BatchByPoints:
    def values_and_jacobians(self, Q: np.ndarray):
        parts = [self.value_and_jacobian(q) for q in Q]  # type: ignore[attr-defined]
        return np.stack([p[0] for p in parts]), np.stack([p[1] for p in parts])

    def value(self, q: np.ndarray) -> np.ndarray:
        return self.value_and_jacobian(q)[0]  # type: ignore[attr-defined]


class JointPositions(_BatchByPoints):
    """Selected joint positions: ``phi(q) = S q`` (a joint-space goal)."""

    def __init__(self, n_q: int, indices: list[int] | None = None, name: str = "joints"):
        idx = list(range(n_q)) if indices is None else list(indices)
        self.S = np.eye(n_q)[idx]
        self.dim = len(idx)
        self.name = name

    def value_and_jacobian(self, q):
        return self.S @ q, self.S.copy()

    def values_and_jacobians(self, Q):
        K = Q.shape[0]
        return Q @ self.S.T, np.broadcast_to(self.S, (K, *self.S.shape)).copy()


class _DrakeMap(_BatchByPoints):
    """Base for maps evaluated on a robot's plant (planning coordinates mapped by ``robot.P``).

    Subclasses implement ``_in_plant(qp)``: value and Jacobian in plant coordinates
    ``qp = P q`` (so ``J = J_plant P``); a batch maps its coordinates in one product each way.

    Speed: where the plant's kinematic tree compiles (:func:`plants.codegen.rbd.tree_kernels`,
    checked against Drake when built) the forward kinematics and Jacobians run in C
    (``_compiled_in_plant``), the same quantities as Drake's calls up to rounding; otherwise, or
    for non-finite positions, Drake's calls.
    """

    _kernels = None   # per instance: the tree kernels, or False where they are unavailable

    def __init__(self, robot, name: str):
        from pydrake.multibody.tree import JacobianWrtVariable

        self.robot = robot
        self.name = name
        self._plant = robot.plant
        self._ctx = robot.plant.CreateDefaultContext()
        self._world = robot.plant.world_frame()
        self._wrt = JacobianWrtVariable.kQDot  # revolute joints only: qdot == v

    def _set_plant(self, qp: np.ndarray):
        """The context at plant positions ``qp (m,)``."""
        self._plant.SetPositions(self._ctx, qp)
        return self._ctx

    def _in_plant(self, qp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``phi (dim,)`` and ``d phi / d qp (dim, m)`` at plant positions ``qp (m,)``."""
        raise NotImplementedError

    def tree_kernels(self):
        """The compiled tree kernels of the robot (``plants.codegen.rbd``), or ``None``."""
        k = self._kernels
        if k is None:
            from plants.codegen.rbd import tree_kernels

            try:
                k = tree_kernels(self.robot)
            except (NotImplementedError, AttributeError):
                k = False
            self._kernels = k
        return k or None

    def _compiled_in_plant(self, kernels, qp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def _eval_plant(self, qp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        k = self.tree_kernels()
        if k is not None and np.all(np.isfinite(qp)):
            return self._compiled_in_plant(k, qp)
        return self._in_plant(qp)

    def value_and_jacobian(self, q):
        P = self.robot.P
        v, Jp = self._eval_plant(P @ q)
        return v, Jp @ P

    def values_and_jacobians(self, Q: np.ndarray):
        """Batched (coordinates mapped once for all rows); rows with non-finite ``q`` give
        NaN (Drake would abort on them)."""
        P = self.robot.P
        ok = np.flatnonzero(np.all(np.isfinite(Q), axis=1))
        V = np.full((Q.shape[0], self.dim), np.nan)
        J = np.full((Q.shape[0], self.dim, Q.shape[1]), np.nan)
        k = self.tree_kernels()
        if ok.size == 0:  # nothing finite: all NaN (a diverged trajectory)
            return V, J
        if k is not None:
            V[ok], Jp = self._compiled_batch(k, Q[ok] @ P.T)
        else:
            Jp = np.empty((ok.size, self.dim, P.shape[0]))
            for i, qp in enumerate(Q[ok] @ P.T):
                V[ok[i]], Jp[i] = self._in_plant(qp)
        J[ok] = Jp @ P
        return V, J

    def _compiled_batch(self, kernels, Qp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Values ``(K, dim)`` and plant Jacobians ``(K, dim, m)`` at the rows of ``Qp``."""
        out = [self._compiled_in_plant(kernels, qp) for qp in Qp]
        return (np.array([o[0] for o in out]).reshape(len(Qp), self.dim),
                np.array([o[1] for o in out]).reshape(len(Qp), self.dim, -1))


class _OnFrame:
    """A task map read at a frame fixed to a body: the data the compiled task messages need."""

    @property
    def body_name(self) -> str:
        """The body the frame is fixed to."""
        return self._body_name

    @property
    def frame_rotation(self) -> np.ndarray:
        """``R_BF (3, 3)``: the frame's orientation in its body."""
        return self._R_BF


class FramePoints(_OnFrame, _DrakeMap):
    """World positions (m) of points fixed in a frame, stacked: ``(3 k,)``; Jacobian ``(3 k, n_q)``.

    One point at the frame origin is an end-effector position; ``axes`` keeps some coordinates
    (e.g. ``(1, 2)`` for y and z). Three points on a sole pin its whole pose.
    """

    def __init__(self, robot, frame: str, points=None, axes=(0, 1, 2), name: str | None = None):
        super().__init__(robot, name or f"{frame}_position")
        self.frame = robot.plant.GetFrameByName(frame)
        self.points = np.zeros((1, 3)) if points is None else np.atleast_2d(points).astype(float)
        rows = [3 * k + a for k in range(len(self.points)) for a in axes]
        self.rows = np.array(rows)
        self.dim = len(rows)
        self._points_T = np.ascontiguousarray(self.points.T)  # (3, k), as Drake takes them
        self._all_rows = rows == list(range(3 * len(self.points)))
        self._body_name = self.frame.body().name()
        X_BF = self.frame.GetFixedPoseInBodyFrame()
        self._R_BF = np.ascontiguousarray(X_BF.rotation().matrix())
        self._p_BF = np.ascontiguousarray(X_BF.translation())

    @property
    def frame_offset(self) -> np.ndarray:
        """``p_BF (3,)`` m: the frame's origin in its body."""
        return self._p_BF

    def _compiled_in_plant(self, kernels, qp):
        pos, J = kernels.frame_points(qp, kernels.tree.body(self._body_name), self._R_BF,
                                      self._p_BF, self.points)
        p = pos.reshape(-1)
        if self._all_rows:
            return p, J
        return p[self.rows], J[self.rows]

    def _compiled_batch(self, kernels, Qp):
        pos, J = kernels.frame_points_batch(Qp, kernels.tree.body(self._body_name), self._R_BF,
                                            self._p_BF, self.points)
        p = pos.reshape(len(Qp), -1)
        if self._all_rows:
            return p, J
        return p[:, self.rows], J[:, self.rows]

    def _in_plant(self, qp):
        ctx = self._set_plant(qp)
        p = self._plant.CalcPointsPositions(ctx, self.frame, self._points_T, self._world)  # (3, k)
        J = self._plant.CalcJacobianTranslationalVelocity(
            ctx, self._wrt, self.frame, self._points_T, self._world, self._world)
        # Drake stacks point k's x, y, z at rows 3k .. 3k+2
        p = p.T.reshape(-1)
        if self._all_rows:
            return p, J
        return p[self.rows], J[self.rows]


def EndEffectorPosition(robot, frame: str, axes=(0, 1, 2), name: str | None = None) -> FramePoints:
    """Position (m) of a frame's origin in the world, coordinates ``axes``."""
    return FramePoints(robot, frame, axes=axes, name=name or f"{frame}_position")


class RollAngle(_OnFrame, _DrakeMap):
    """The end effector's roll (rad): rotation about its pointing axis x_E, measured from "z_E up".

    ``roll = atan2(y_E . z_W, z_E . z_W)``; defined wherever x_E is not vertical. Its Jacobian
    follows from the angular-velocity Jacobian ``J_w``: ``d(e . z_W) = J_w . (e x z_W)``.
    """

    dim = 1

    def __init__(self, robot, frame: str, name: str = "roll"):
        super().__init__(robot, name)
        self.frame = robot.plant.GetFrameByName(frame)
        self._body_name = self.frame.body().name()
        self._R_BF = np.ascontiguousarray(self.frame.GetFixedPoseInBodyFrame().rotation().matrix())

    def _in_plant(self, qp):
        ctx = self._set_plant(qp)
        R = self.frame.CalcPoseInWorld(ctx).rotation().matrix()
        Jw = self._plant.CalcJacobianAngularVelocity(
            ctx, self._wrt, self.frame, self._world, self._world)
        return self._roll(R, Jw)

    def _compiled_in_plant(self, kernels, qp):
        R, Jw = kernels.frame_rotation(qp, kernels.tree.body(self._body_name), self._R_BF)
        return self._roll(R, Jw)

    def _compiled_batch(self, kernels, Qp):
        R, Jw = kernels.frame_rotation_batch(Qp, kernels.tree.body(self._body_name), self._R_BF)
        out = [self._roll(Rk, Jk) for Rk, Jk in zip(R, Jw)]
        return np.array([o[0] for o in out]), np.array([o[1] for o in out])

    @staticmethod
    def _roll(R, Jw):
        y, z, up = R[:, 1], R[:, 2], np.array([0.0, 0.0, 1.0])
        a, b = y @ up, z @ up
        da = np.cross(y, up) @ Jw
        db = np.cross(z, up) @ Jw
        return np.array([np.arctan2(a, b)]), ((b * da - a * db) / (a * a + b * b))[None, :]


class CenterOfMass(_DrakeMap):
    """Center of gravity (m) in the world (Drake's CalcCenterOfMassPositionInWorld), ``axes``."""

    def __init__(self, robot, axes=(0, 1, 2), name: str = "cog"):
        super().__init__(robot, name)
        self.axes = np.array(axes)
        self.dim = len(self.axes)

    def _in_plant(self, qp):
        ctx = self._set_plant(qp)
        c = self._plant.CalcCenterOfMassPositionInWorld(ctx)
        J = self._plant.CalcJacobianCenterOfMassTranslationalVelocity(
            ctx, self._wrt, self._world, self._world)
        return c[self.axes], J[self.axes]

    def _compiled_in_plant(self, kernels, qp):
        c, J = kernels.com(qp)
        return c[self.axes], J[self.axes]

    def _compiled_batch(self, kernels, Qp):
        c, J = kernels.com_batch(Qp)
        return c[:, self.axes], J[:, self.axes]


class Stack(_BatchByPoints):
    """Several task maps side by side: values concatenated, Jacobians stacked."""

    def __init__(self, maps: list, name: str = "stack"):
        self.maps = list(maps)
        self.dim = sum(m.dim for m in self.maps)
        self.name = name

    def value_and_jacobian(self, q):
        parts = [m.value_and_jacobian(q) for m in self.maps]
        return np.concatenate([p[0] for p in parts]), np.vstack([p[1] for p in parts])

    def values_and_jacobians(self, Q):
        """Batched through each map's own batch (so non-finite rows give NaN there too)."""
        parts = [m.values_and_jacobians(Q) for m in self.maps]
        return np.concatenate([p[0] for p in parts], axis=1), np.concatenate([p[1] for p in parts], axis=1)


# --------------------------------------------------------------------------------------------
# Examples: one or more configured instances of every task map class, checked against finite
# differences by tests/test_derivatives.py (and turned into via-point examples in
# planning.costs). A new task map class registers an example here.
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TaskMapExample:
    """``build(robot) -> TaskMap`` on the plants named in ``plants`` (``None``: every plant)."""

    name: str
    build: Callable[[Any], TaskMap]
    plants: tuple[str, ...] | None = None

    def applies_to(self, plant: str) -> bool:
        return self.plants is None or plant in self.plants


TASKMAP_EXAMPLES: dict[str, TaskMapExample] = {}


def register_taskmap_example(name: str, build: Callable[[Any], TaskMap],
                             plants: tuple[str, ...] | None = None) -> TaskMapExample:
    """Register an example task map (unique ``name``)."""
    if name in TASKMAP_EXAMPLES:
        raise ValueError(f"task map example '{name}' is already registered")
    TASKMAP_EXAMPLES[name] = TaskMapExample(name, build, plants)
    return TASKMAP_EXAMPLES[name]


def _first_end_effector(robot) -> str:
    return next(iter(robot.end_effectors.values()))


def _stack_example(robot) -> Stack:
    ee = _first_end_effector(robot)
    return Stack([EndEffectorPosition(robot, ee, axes=(0, 2)), CenterOfMass(robot, axes=(1,)),
                  JointPositions(robot.n_q, [0])], name="stack")


register_taskmap_example("joint_positions",
                         lambda r: JointPositions(r.n_q, sorted({0, r.n_q - 1})))
register_taskmap_example("ee_position", lambda r: EndEffectorPosition(r, _first_end_effector(r)))
register_taskmap_example("ee_position_yz",
                         lambda r: EndEffectorPosition(r, _first_end_effector(r), axes=(1, 2)))
register_taskmap_example("frame_points", lambda r: FramePoints(
    r, _first_end_effector(r), points=[[0, 0, 0], [0.1, 0, 0], [0, 0.05, 0.02]]))
register_taskmap_example("roll", lambda r: RollAngle(r, _first_end_effector(r)))
register_taskmap_example("center_of_mass", lambda r: CenterOfMass(r))
register_taskmap_example("stack", _stack_example)
