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

    Speed: where the plant's kinematic tree compiles (:func:`raico.plants.codegen.rbd.tree_kernels`,
    checked against Drake when built) the forward kinematics and Jacobians run in C
    (``_compiled_in_plant``), the same quantities as Drake's calls up to rounding; otherwise, or
    for non-finite positions, Drake's calls.
    """

    dim: int          # the map's dimension (set by the subclass)
    _kernels = None   # per instance: the tree kernels, or False where they are unavailable

    def __init__(self, robot, name: str):
        from pydrake.multibody.tree import JacobianWrtVariable

        self.robot = robot
        self.name = name
        self._plant = robot.plant
        self._ctx = robot.plant.CreateDefaultContext()
        self._world = robot.plant.world_frame()
        self._wrt = JacobianWrtVariable.kQDot  # revolute and prismatic joints only: qdot == v

    def _set_plant(self, qp: np.ndarray):
        """The context at plant positions ``qp (m,)``."""
        self._plant.SetPositions(self._ctx, qp)
        return self._ctx

    def _in_plant(self, qp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``phi (dim,)`` and ``d phi / d qp (dim, m)`` at plant positions ``qp (m,)``."""
        raise NotImplementedError

    def tree_kernels(self):
        """The compiled tree kernels of the robot (``raico.plants.codegen.rbd``), or ``None``."""
        k = self._kernels
        if k is None:
            from raico.plants.codegen.rbd import tree_kernels

            try:
                k = tree_kernels(self.robot)
            except NotImplementedError:  # no tree kernels for this plant (said by tree_kernels)
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
            V[ok], Jp = self._drake_batch(Q[ok] @ P.T)
        J[ok] = Jp @ P
        return V, J

    def _drake_batch(self, Qp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Values ``(K, dim)`` and plant Jacobians ``(K, dim, m)`` at the rows of ``Qp`` by Drake's
        calls (``_in_plant`` row by row)."""
        V = np.empty((len(Qp), self.dim))
        Jp = np.empty((len(Qp), self.dim, Qp.shape[1]))
        for i, qp in enumerate(Qp):
            V[i], Jp[i] = self._in_plant(qp)
        return V, Jp

    def _compiled_batch(self, kernels, Qp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Values ``(K, dim)`` and plant Jacobians ``(K, dim, m)`` at the rows of ``Qp``."""
        out = [self._compiled_in_plant(kernels, qp) for qp in Qp]
        return (np.array([o[0] for o in out]).reshape(len(Qp), self.dim),
                np.array([o[1] for o in out]).reshape(len(Qp), self.dim, -1))


class _OnFrame:
    """A task map read at a frame fixed to a body: the data the compiled task messages need."""

    _body_name: str      # set by the task map's constructor
    _R_BF: np.ndarray

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


# --------------------------------------------------------------------------------------------
# SO(3) / SE(3) logarithms and their Jacobians (Pinocchio's formulas, numpy)
# --------------------------------------------------------------------------------------------
_EPS = float(np.finfo(float).eps)
_PREC2 = _EPS ** (1.0 / 3.0)   # Pinocchio's TaylorSeriesExpansion<double>::precision<2>() (6.1e-6)
_PREC3 = _EPS ** (1.0 / 4.0)   # ... precision<3>() (1.2e-4)


def _skew(v: np.ndarray) -> np.ndarray:
    """``[v]x (3, 3)``: ``[v]x w = v x w``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b (3,)``: np.cross's arithmetic on Python floats (np.cross's axis handling costs
    tens of microseconds a call, more than the rest of a logarithm)."""
    a0, a1, a2 = a.tolist()
    b0, b1, b2 = b.tolist()
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def _unskew(M: np.ndarray) -> np.ndarray:
    """The vector of the antisymmetric part of ``M (3, 3)``: ``(M - M^T) / 2 = [v]x``."""
    return 0.5 * np.array([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]])


def _renormalized(R: np.ndarray) -> np.ndarray:
    """``R`` projected back onto a rotation (columns made orthonormal, as Pinocchio's
    ``renormalize_rotation_matrix``)."""
    c0 = R[:, 0] / np.linalg.norm(R[:, 0])
    c1 = R[:, 1] / np.linalg.norm(R[:, 1])
    c2 = _cross3(c0, c1)
    return np.column_stack([_cross3(c1, c2), c1, c2])


def log3_angle(R) -> tuple[float, np.ndarray]:
    """``(theta, r)``: the rotation vector ``r = theta a (3,)`` of ``R (3, 3)`` (``exp([r]x) = R``,
    ``theta = |r|`` in ``[0, pi]``), computed as Pinocchio's ``log3``: ``theta r / (2 sin theta)``
    from the antisymmetric part, its Taylor expansion below ``theta = 6e-6``, and within ``1 - cos
    theta < 6e-6`` of ``pi`` (where ``sin theta`` vanishes) the axis from the quaternion of ``R``'s
    largest diagonal entry. At ``theta = pi`` the sign of ``r`` is that of Pinocchio's rule:
    ``log3`` jumps from ``r`` to ``-r`` there."""
    Rn = _renormalized(np.asarray(R, float))
    tr = float(np.trace(Rn))
    cos_value = (tr - 1.0) / 2.0
    if cos_value >= -1.0 + _PREC2:
        if tr <= 3.0 - _PREC2:
            theta = float(np.arccos(cos_value))
        else:  # acos near 0 is inaccurate: 2 (1 - cos theta) = theta^2 + O(theta^4)
            theta = float(np.sqrt(2.0 * (1.0 - cos_value) + _EPS * _EPS))
        a = _unskew(Rn)   # sin(theta) * axis
        if theta >= _PREC2:
            t = theta / np.sin(theta)
        else:
            n2 = float(a @ a)
            t = 1.0 + n2 / 6.0 + n2 * n2 * 3.0 / 40.0
        return theta, t * a
    # near pi: the axis from the quaternion (w, x) of R (4 x_i^2 = 2 R_ii - tr + 1), largest entry first
    val = 2.0 * np.diag(Rn) - tr + 1.0
    if val[0] >= val[1]:
        i0 = 0 if val[0] >= val[2] else 2
    else:
        i0 = 1 if val[1] >= val[2] else 2
    i1, i2 = (i0 + 1) % 3, (i0 + 2) % 3
    s = np.sqrt(val[i0] + _EPS + _EPS * _EPS) * (1.0 if Rn[i2, i1] >= Rn[i1, i2] else -1.0)
    axis = np.empty(3)
    axis[i0] = s / 2.0
    axis[i1] = (Rn[i1, i0] + Rn[i0, i1]) / (2.0 * s)
    axis[i2] = (Rn[i2, i0] + Rn[i0, i2]) / (2.0 * s)
    w = (Rn[i2, i1] - Rn[i1, i2]) / (2.0 * s)
    norm = float(np.linalg.norm(axis))
    theta = 2.0 * float(np.arctan2(norm, w))
    return theta, theta * axis / norm


def log3(R) -> np.ndarray:
    """The rotation vector ``(3,)`` of ``R (3, 3)`` (rad; Pinocchio's ``pin.log3``): see
    :func:`log3_angle`."""
    return log3_angle(R)[1]


def jlog3(theta: float, r: np.ndarray) -> np.ndarray:
    """:func:`Jlog3` from ``theta`` and ``r = log3(R)`` (Taylor expansion below ``theta = 1.2e-4``)."""
    if theta < _PREC3:
        alpha = 1.0 / 12.0 + theta * theta / 720.0
        diag = 0.5 * (2.0 - theta * theta / 6.0)
    else:
        st_1mct = np.sin(theta) / (1.0 - np.cos(theta))   # cot(theta / 2)
        alpha = 1.0 / (theta * theta) - st_1mct / (2.0 * theta)
        diag = 0.5 * theta * st_1mct
    return alpha * np.outer(r, r) + diag * np.eye(3) + _skew(0.5 * r)


def Jlog3(R) -> np.ndarray:
    """``d log3(R exp([d]x)) / d d`` at ``d = 0`` ``(3, 3)`` (Pinocchio's ``pin.Jlog3``: the inverse
    of the right Jacobian of ``exp``): ``I + [r]x / 2 + (1 / theta^2 - cot(theta / 2) / (2 theta))
    [r]x^2``, ``r = log3(R)``. A body-frame (LOCAL) angular velocity ``w`` moves ``log3(R)`` by
    ``Jlog3(R) w``."""
    return jlog3(*log3_angle(R))


def log6_parts(R: np.ndarray, p: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """``(theta, w, log6 (6,))`` of the pose ``(R, p)``."""
    a = _unskew(R)
    t2 = float(a @ a)   # sin(theta)^2 (Pinocchio's argument of the expansions near 0)
    theta, w = log3_angle(R)
    if np.trace(R) >= 3.0 - _PREC2:
        alpha = 1.0 - t2 / 12.0 - t2 * t2 / 720.0
        beta = 1.0 / 12.0 + t2 / 720.0
    else:
        st, ct = np.sin(theta), np.cos(theta)
        alpha = theta * st / (2.0 * (1.0 - ct))
        beta = 1.0 / (theta * theta) - st / (2.0 * theta * (1.0 - ct))
    lin = alpha * p - 0.5 * _cross3(w, p) + (beta * (w @ p)) * w
    return theta, w, np.concatenate([lin, w])


def log6(R, p) -> np.ndarray:
    """The twist ``(6,)``, linear part first, of the pose ``M = (R (3, 3), p (3,))``: ``exp6`` of it
    is ``M`` (Pinocchio's ``pin.log6(M).vector``): angular part ``w = log3(R)``, linear part
    ``V(w)^-1 p`` with ``V`` the left Jacobian of ``exp`` on SO(3)."""
    return log6_parts(np.asarray(R, float), np.asarray(p, float))[2]


def jlog6(theta: float, w: np.ndarray, p: np.ndarray) -> np.ndarray:
    """:func:`Jlog6` from ``theta``, ``w = log3(R)`` and ``p``."""
    A = jlog3(theta, w)
    t2 = theta * theta
    if theta < _PREC3:
        beta = 1.0 / 12.0 + t2 / 720.0
        beta_dot_over_theta = 1.0 / 360.0
    else:
        tinv = 1.0 / theta
        t2inv = tinv * tinv
        st, ct = np.sin(theta), np.cos(theta)
        inv_2_2ct = 1.0 / (2.0 * (1.0 - ct))
        beta = t2inv - st * tinv * inv_2_2ct
        beta_dot_over_theta = -2.0 * t2inv * t2inv + (1.0 + st * tinv) * t2inv * inv_2_2ct
    wTp = float(w @ p)
    v = (beta_dot_over_theta * wTp) * w - (t2 * beta_dot_over_theta + 2.0 * beta) * p
    C = np.outer(v, w) + beta * np.outer(w, p) + (wTp * beta) * np.eye(3) + _skew(0.5 * p)
    J = np.zeros((6, 6))
    J[:3, :3] = J[3:, 3:] = A
    J[:3, 3:] = C @ A
    return J


def Jlog6(R, p) -> np.ndarray:
    """``d log6(M exp6(d)) / d d`` at ``d = 0`` ``(6, 6)``, twists linear part first (Pinocchio's
    ``pin.Jlog6``): ``[[Jlog3, C Jlog3], [0, Jlog3]]``. A body-frame (LOCAL) spatial velocity
    ``(v, w)`` of ``M`` moves ``log6(M)`` by ``Jlog6(M) (v, w)``."""
    R, p = np.asarray(R, float), np.asarray(p, float)
    theta, w = log3_angle(R)
    return jlog6(theta, w, p)


# -- the same, batched over a leading axis: rows (K, 3, 3) and (K, 3) -------------------------------
# Each formula is the scalar one above, evaluated for every row at once; where the scalar code
# branches, the batch computes both sides with safe arguments and keeps each row's own (np.where),
# and log3's near-pi rows (the quaternion route, rare) are the scalar function's, row by row.
def _cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` row by row, ``(K, 3)`` each (np.cross's formula without its axis handling)."""
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=1)


def _skew_rows(v: np.ndarray) -> np.ndarray:
    """``[v_k]x (K, 3, 3)`` of the rows of ``v (K, 3)``."""
    S = np.zeros((v.shape[0], 3, 3))
    S[:, 0, 1], S[:, 0, 2] = -v[:, 2], v[:, 1]
    S[:, 1, 0], S[:, 1, 2] = v[:, 2], -v[:, 0]
    S[:, 2, 0], S[:, 2, 1] = -v[:, 1], v[:, 0]
    return S


def _unskew_rows(M: np.ndarray) -> np.ndarray:
    """:func:`_unskew` of each ``M (K, 3, 3)``: ``(K, 3)``."""
    return 0.5 * np.stack([M[:, 2, 1] - M[:, 1, 2], M[:, 0, 2] - M[:, 2, 0],
                           M[:, 1, 0] - M[:, 0, 1]], axis=1)


def _renormalized_rows(R: np.ndarray) -> np.ndarray:
    """:func:`_renormalized` of each ``R (K, 3, 3)``."""
    c0 = R[:, :, 0] / np.sqrt(np.einsum("ki,ki->k", R[:, :, 0], R[:, :, 0]))[:, None]
    c1 = R[:, :, 1] / np.sqrt(np.einsum("ki,ki->k", R[:, :, 1], R[:, :, 1]))[:, None]
    c2 = _cross_rows(c0, c1)
    return np.stack([_cross_rows(c1, c2), c1, c2], axis=2)


def _trace_rows(R: np.ndarray) -> np.ndarray:
    return R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2]


def log3_angle_rows(R) -> tuple[np.ndarray, np.ndarray]:
    """:func:`log3_angle` of each ``R (K, 3, 3)``: ``theta (K,)``, ``r (K, 3)``."""
    R = np.asarray(R, float)
    Rn = _renormalized_rows(R)
    tr = _trace_rows(Rn)
    cos_value = (tr - 1.0) / 2.0
    near_pi = ~(cos_value >= -1.0 + _PREC2)
    acos = np.arccos(np.clip(cos_value, -1.0, 1.0))   # clipped for the rows that do not use it
    near0 = np.sqrt(2.0 * (1.0 - cos_value) + _EPS * _EPS)
    theta = np.where(tr <= 3.0 - _PREC2, acos, near0)
    a = _unskew_rows(Rn)   # sin(theta) * axis
    n2 = np.einsum("ki,ki->k", a, a)
    big = theta >= _PREC2
    t = np.where(big, theta / np.sin(np.where(big, theta, 1.0)),
                 1.0 + n2 / 6.0 + n2 * n2 * 3.0 / 40.0)
    r = t[:, None] * a
    for k in np.flatnonzero(near_pi):
        theta[k], r[k] = log3_angle(R[k])
    return theta, r


def jlog3_rows(theta: np.ndarray, r: np.ndarray) -> np.ndarray:
    """:func:`jlog3` of each row: ``theta (K,)``, ``r (K, 3)`` -> ``(K, 3, 3)``."""
    small = theta < _PREC3
    th = np.where(small, 1.0, theta)
    st_1mct = np.sin(th) / (1.0 - np.cos(th))   # cot(theta / 2)
    t2 = theta * theta
    alpha = np.where(small, 1.0 / 12.0 + t2 / 720.0, 1.0 / (th * th) - st_1mct / (2.0 * th))
    diag = np.where(small, 0.5 * (2.0 - t2 / 6.0), 0.5 * th * st_1mct)
    J = alpha[:, None, None] * (r[:, :, None] * r[:, None, :]) + _skew_rows(0.5 * r)
    J[:, 0, 0] += diag
    J[:, 1, 1] += diag
    J[:, 2, 2] += diag
    return J


def log6_parts_rows(R: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`log6_parts` of each pose: ``R (K, 3, 3)``, ``p (K, 3)`` -> ``theta (K,)``,
    ``w (K, 3)``, ``log6 (K, 6)``."""
    a = _unskew_rows(R)
    t2 = np.einsum("ki,ki->k", a, a)   # sin(theta)^2
    theta, w = log3_angle_rows(R)
    taylor = _trace_rows(R) >= 3.0 - _PREC2
    th = np.where(taylor, 1.0, theta)
    st, ct = np.sin(th), np.cos(th)
    alpha = np.where(taylor, 1.0 - t2 / 12.0 - t2 * t2 / 720.0, th * st / (2.0 * (1.0 - ct)))
    beta = np.where(taylor, 1.0 / 12.0 + t2 / 720.0,
                    1.0 / (th * th) - st / (2.0 * th * (1.0 - ct)))
    wp = np.einsum("ki,ki->k", w, p)
    lin = alpha[:, None] * p - 0.5 * _cross_rows(w, p) + (beta * wp)[:, None] * w
    return theta, w, np.concatenate([lin, w], axis=1)


def jlog6_rows(theta: np.ndarray, w: np.ndarray, p: np.ndarray) -> np.ndarray:
    """:func:`jlog6` of each row: ``theta (K,)``, ``w``, ``p (K, 3)`` -> ``(K, 6, 6)``."""
    A = jlog3_rows(theta, w)
    t2 = theta * theta
    small = theta < _PREC3
    tinv = 1.0 / np.where(small, 1.0, theta)
    t2inv = tinv * tinv
    st, ct = np.sin(theta), np.cos(theta)
    inv_2_2ct = 1.0 / (2.0 * (1.0 - np.where(small, 0.0, ct)))
    beta = np.where(small, 1.0 / 12.0 + t2 / 720.0, t2inv - st * tinv * inv_2_2ct)
    beta_dot_over_theta = np.where(
        small, 1.0 / 360.0, -2.0 * t2inv * t2inv + (1.0 + st * tinv) * t2inv * inv_2_2ct)
    wTp = np.einsum("ki,ki->k", w, p)
    v = (beta_dot_over_theta * wTp)[:, None] * w - (t2 * beta_dot_over_theta + 2.0 * beta)[:, None] * p
    C = v[:, :, None] * w[:, None, :] + beta[:, None, None] * (w[:, :, None] * p[:, None, :]) \
        + _skew_rows(0.5 * p)
    d = wTp * beta
    C[:, 0, 0] += d
    C[:, 1, 1] += d
    C[:, 2, 2] += d
    J = np.zeros((theta.shape[0], 6, 6))
    J[:, :3, :3] = J[:, 3:, 3:] = A
    J[:, :3, 3:] = C @ A
    return J


class _FramePose(_OnFrame, _DrakeMap):
    """Base of the maps on a frame's pose ``(R_WF, p_WF)`` and its LOCAL Jacobian (the frame's
    velocity ``(v, w)`` expressed in F, linear rows first, as Pinocchio's ``LOCAL`` frame
    Jacobian). Subclasses implement ``_residual(R, p, Jv, Jw)`` on the world pose and the world
    Jacobians ``Jv`` (of the origin), ``Jw`` (angular), ``(3, m)`` each, and ``_residuals`` on a
    batch of them, ``R (K, 3, 3)``, ``p (K, 3)``, ``Jv``, ``Jw (K, 3, m)`` (the same numbers; the
    batches, compiled or Drake's, evaluate the logarithms for all rows at once)."""

    _needs_translation = True

    def __init__(self, robot, frame: str, name: str):
        super().__init__(robot, name)
        self.frame = robot.plant.GetFrameByName(frame)
        self._body_name = self.frame.body().name()
        X_BF = self.frame.GetFixedPoseInBodyFrame()
        self._R_BF = np.ascontiguousarray(X_BF.rotation().matrix())
        self._p_BF = np.ascontiguousarray(X_BF.translation())
        self._origin = np.zeros((1, 3))

    @property
    def frame_offset(self) -> np.ndarray:
        """``p_BF (3,)`` m: the frame's origin in its body."""
        return self._p_BF

    def _residual(self, R, p, Jv, Jw) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def _residuals(self, R, p, Jv, Jw) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def _drake_pose(self, qp):
        """``R (3, 3)``, ``p (3,)``, ``Jv``, ``Jw (3, m)`` at plant positions ``qp`` by Drake's calls."""
        ctx = self._set_plant(qp)
        X = self._plant.CalcRelativeTransform(ctx, self._world, self.frame)
        J = self._plant.CalcJacobianSpatialVelocity(ctx, self._wrt, self.frame, np.zeros(3),
                                                    self._world, self._world)   # (6, m): w, v
        return X.rotation().matrix(), X.translation(), J[3:], J[:3]

    def _in_plant(self, qp):
        return self._residual(*self._drake_pose(qp))

    def _drake_batch(self, Qp):
        K, m = Qp.shape
        R, p = np.empty((K, 3, 3)), np.empty((K, 3))
        Jv, Jw = np.empty((K, 3, m)), np.empty((K, 3, m))
        for i, qp in enumerate(Qp):   # Drake's calls row by row, the logarithms once for all
            R[i], p[i], Jv[i], Jw[i] = self._drake_pose(qp)
        return self._residuals(R, p, Jv, Jw)

    def _compiled_in_plant(self, kernels, qp):
        b = kernels.tree.body(self._body_name)
        R, Jw = kernels.frame_rotation(qp, b, self._R_BF)
        if not self._needs_translation:
            return self._residual(R, None, None, Jw)
        pos, Jv = kernels.frame_points(qp, b, self._R_BF, self._p_BF, self._origin)
        return self._residual(R, pos[0], Jv, Jw)

    def _compiled_batch(self, kernels, Qp):
        b = kernels.tree.body(self._body_name)
        R, Jw = kernels.frame_rotation_batch(Qp, b, self._R_BF)
        if not self._needs_translation:
            return self._residuals(R, None, None, Jw)
        pos, Jv = kernels.frame_points_batch(Qp, b, self._R_BF, self._p_BF, self._origin)
        return self._residuals(R, pos[:, 0], Jv, Jw)


class FrameRotationError(_FramePose):
    """A frame's orientation error (rad) from a target ``R_target = R_WT``: the rotation vector
    ``r = log3(R_target^T R_WF(q)) (3,)`` (the rotation from T to F, in T's and F's axes), with
    ``J = Jlog3(R_target^T R_WF) J_w^F (3, n_q)``, ``J_w^F = R_WF^T J_w`` the frame's angular
    velocity Jacobian expressed in F (crocoddyl's ``ResidualModelFrameRotation``). Its via-point
    target is ``zeros(3)``. ``r`` is smooth while the error angle ``|r|`` stays below pi (at pi it
    jumps to ``-r``)."""

    dim = 3
    _needs_translation = False

    def __init__(self, robot, frame: str, R_target, name: str | None = None):
        super().__init__(robot, frame, name or f"{frame}_rotation")
        self.R_target = np.array(R_target, float).reshape(3, 3)

    def _residual(self, R, p, Jv, Jw):
        theta, r = log3_angle(self.R_target.T @ R)
        return r, jlog3(theta, r) @ (R.T @ Jw)

    def _residuals(self, R, p, Jv, Jw):
        theta, r = log3_angle_rows(self.R_target.T @ R)
        return r, jlog3_rows(theta, r) @ (np.swapaxes(R, 1, 2) @ Jw)


class FramePlacementError(_FramePose):
    """A frame's pose error from a target pose ``M_target = (R_target, p_target)`` (world): the
    twist ``r = log6(M_target^-1 M_WF(q)) (6,)``, linear part (m) first, then angular (rad), with
    ``J = Jlog6(M_target^-1 M_WF) J^F (6, n_q)``, ``J^F = [R_WF^T J_v; R_WF^T J_w]`` the frame's
    LOCAL Jacobian (Pinocchio's ``LOCAL``, linear rows first; crocoddyl's
    ``ResidualModelFramePlacement``). Its via-point target is ``zeros(6)``; smooth while the
    rotation error stays below pi."""

    dim = 6

    def __init__(self, robot, frame: str, R_target, p_target, name: str | None = None):
        super().__init__(robot, frame, name or f"{frame}_placement")
        self.R_target = np.array(R_target, float).reshape(3, 3)
        self.p_target = np.array(p_target, float).reshape(3)

    def _residual(self, R, p, Jv, Jw):
        Rt = self.R_target
        R_rel, p_rel = Rt.T @ R, Rt.T @ (p - self.p_target)
        theta, w, r = log6_parts(R_rel, p_rel)
        J_local = np.vstack([R.T @ Jv, R.T @ Jw])
        return r, jlog6(theta, w, p_rel) @ J_local

    def _residuals(self, R, p, Jv, Jw):
        Rt = self.R_target
        R_rel, p_rel = Rt.T @ R, (p - self.p_target) @ Rt   # rows Rt^T (p_k - p_target)
        theta, w, r = log6_parts_rows(R_rel, p_rel)
        RT = np.swapaxes(R, 1, 2)
        J_local = np.concatenate([RT @ Jv, RT @ Jw], axis=1)
        return r, jlog6_rows(theta, w, p_rel) @ J_local


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
# differences by tests/plants/test_derivatives.py (and turned into via-point examples in
# raico.planning.costs). A new task map class registers an example here.
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

def _frame_pose_target(robot, frame: str) -> tuple[np.ndarray, np.ndarray]:
    """A target pose near the frame's pose at the default posture: rotated by 0.5 rad about
    ``(1, -2, 3)`` and moved by ``(0.05, -0.03, 0.08)`` m (non-zero errors, far from pi)."""
    plant = robot.plant
    ctx = plant.CreateDefaultContext()
    plant.SetPositions(ctx, robot.P @ robot.default_q)
    X = plant.CalcRelativeTransform(ctx, plant.world_frame(), plant.GetFrameByName(frame))
    a = np.array([1.0, -2.0, 3.0]) / np.sqrt(14.0)
    K = _skew(a)
    turn = np.eye(3) + np.sin(0.5) * K + (1.0 - np.cos(0.5)) * K @ K
    return X.rotation().matrix() @ turn, X.translation() + np.array([0.05, -0.03, 0.08])


def _frame_rotation_example(robot) -> FrameRotationError:
    ee = _first_end_effector(robot)
    return FrameRotationError(robot, ee, _frame_pose_target(robot, ee)[0])


def _frame_placement_example(robot) -> FramePlacementError:
    ee = _first_end_effector(robot)
    return FramePlacementError(robot, ee, *_frame_pose_target(robot, ee))


register_taskmap_example("frame_rotation", _frame_rotation_example)
register_taskmap_example("frame_placement", _frame_placement_example)
