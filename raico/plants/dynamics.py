"""Discrete-time dynamics models with one interface.

Contract (shared by every model and every solver):

- state ``x = (q, qdot)`` of size ``n_x = 2 * n_q`` (planning coordinates, rad and rad/s),
  control ``u`` of size ``n_u`` (joint accelerations in rad/s^2 for pseudo-dynamics,
  joint torques in N m for analytic and learned models);
- one step of ``dt`` seconds: ``x_{t+1} = f(x_t, u_t)``;
- linearization around ``(x, u)``: ``f(x', u') ~ A x' + a + B u'`` with
  ``a = f(x, u) - A x - B u`` (so the affine model is exact at the point);
- along a trajectory: ``X`` of shape ``(T, n_x)`` and ``U`` of shape ``(T, n_u)`` give
  ``A (T, n_x, n_x)``, ``a (T, n_x)``, ``B (T, n_x, n_u)``, step ``t`` linearized at
  ``(X[t], U[t])``.

Discretization of the analytic models is semi-implicit (symplectic) Euler,
``qdot' = qdot + dt * qddot(q, qdot, u)``, ``q' = q + dt * qdot'``: with ``qddot = u``
it is exactly the thesis's backward-Euler pseudo-dynamics (appendix C.2), so both
models share one time convention.

Models are built by name with :func:`raico.plants.dynamics_registry.make_dynamics`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Dynamics(Protocol):
    """What every dynamics model offers (see the module docstring for shapes; read-only here)."""

    @property
    def n_x(self) -> int: ...

    @property
    def n_u(self) -> int: ...

    @property
    def dt(self) -> float: ...

    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Next state ``(n_x,)`` from state ``(n_x,)`` and control ``(n_u,)``."""
        ...

    def linearize(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A (n_x, n_x), a (n_x,), B (n_x, n_u))`` at ``(x, u)``."""
        ...

    def linearize_trajectory(
        self, X: np.ndarray, U: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A (T, n_x, n_x), a (T, n_x), B (T, n_x, n_u))`` along ``X (T, n_x)``, ``U (T, n_u)``."""
        ...


def rollout(dyn: Dynamics, x0: np.ndarray, U: np.ndarray) -> np.ndarray:
    """States ``(T+1, n_x)`` from ``x0`` under the open-loop controls ``U (T, n_u)``."""
    X = np.empty((U.shape[0] + 1, dyn.n_x))
    X[0] = x0
    for t in range(U.shape[0]):
        X[t + 1] = dyn.step(X[t], U[t])
    return X


class _TrajectoryByPoints:
    """Mixin: linearize a trajectory point by point (models override when they batch)."""

    def linearize_trajectory(self, X: np.ndarray, U: np.ndarray):
        parts = [self.linearize(x, u) for x, u in zip(X, U)]  # type: ignore[attr-defined]
        return (np.stack([p[0] for p in parts]), np.stack([p[1] for p in parts]),
                np.stack([p[2] for p in parts]))


@dataclass
class LinearDynamics(_TrajectoryByPoints):
    """Time-invariant affine model ``x' = A x + a + B u`` (LQ tests, references)."""

    A: np.ndarray
    a: np.ndarray
    B: np.ndarray
    dt: float = 1.0

    @property
    def n_x(self) -> int:
        return self.A.shape[0]

    @property
    def n_u(self) -> int:
        return self.B.shape[1]

    def step(self, x, u):
        return self.A @ x + self.a + self.B @ u

    def linearize(self, x, u):
        return self.A.copy(), self.a.copy(), self.B.copy()

    def linearize_trajectory(self, X, U):
        T = X.shape[0]
        return (np.broadcast_to(self.A, (T, *self.A.shape)).copy(),
                np.broadcast_to(self.a, (T, *self.a.shape)).copy(),
                np.broadcast_to(self.B, (T, *self.B.shape)).copy())


# Appendix C's three discretizations of qddot = u: A = [[I, dt I], [0, I]] for all; B's position block is
# dt^2 times this coefficient (its velocity block is dt I). Backward Euler (C.2, q' = q + dt qdot') is the
# thesis's choice and raico's default; Heun (C.3, q' = q + dt/2 (qdot + qdot')) is exact for an acceleration
# held over the step; Euler (C.1, q' = q + dt qdot) leaves the position one step behind the control.
PSEUDO_SCHEMES = {"backward-euler": 1.0, "euler": 0.0, "heun": 0.5}


class PseudoDynamics(LinearDynamics):
    """Thesis pseudo-dynamics: controls are joint accelerations (appendix C).

    ``A = [[I, dt I], [0, I]]``, ``B = [[c dt^2 I], [dt I]]``, ``a = 0`` with ``c`` of
    :data:`PSEUDO_SCHEMES`: 1 for backward Euler (C.2, the default and the thesis's), 0 for Euler
    (C.1), 1/2 for Heun (C.3).
    """

    def __init__(self, n_q: int, dt: float, scheme: str = "backward-euler"):
        if scheme not in PSEUDO_SCHEMES:
            raise ValueError(f"unknown pseudo-dynamics scheme '{scheme}': choose one of {', '.join(PSEUDO_SCHEMES)}")
        I = np.eye(n_q)
        Z = np.zeros((n_q, n_q))
        A = np.block([[I, dt * I], [Z, I]])
        c = PSEUDO_SCHEMES[scheme]
        B = np.vstack([c * dt * dt * I, dt * I])  # c = 1: exactly the former dt * dt * I (1.0 * dt == dt)
        super().__init__(A=A, a=np.zeros(2 * n_q), B=B, dt=dt)
        self.n_q = n_q
        self.scheme = scheme


def stepped_rollout(dynamics, x0: np.ndarray, o: np.ndarray, O: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roll ``u_t = o_t + O_t x_t`` out on ``dynamics`` (its ``step``) from ``x0``: ``X (T+1, n_x)``,
    ``U (T, n_u)``, one Python step at a time (the reference loop the compiled rollouts equal).

    Non-finite states propagate (NaN) instead of raising; callers check the result.
    """
    T = o.shape[0]
    X = np.empty((T + 1, np.shape(x0)[0]))
    U = np.empty(o.shape)
    X[0] = x0
    step = dynamics.step
    with np.errstate(all="ignore"):
        for t in range(T):
            U[t] = o[t] + O[t] @ X[t]
            X[t + 1] = step(X[t], U[t])
    return X, U


class SemiImplicitEuler:
    """The analytic models' step: ``qdot' = qdot + dt qddot(q, qdot, u)``, ``q' = q + dt qdot'``."""

    n_q: int
    dt: float
    qddot: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]   # each model's own (rad/s^2)

    def step(self, x, u):
        n = self.n_q
        q, v = x[:n], x[n:]
        v1 = v + self.dt * self.qddot(q, v, u)
        return np.concatenate([q + self.dt * v1, v1])


class AnalyticDynamics(SemiImplicitEuler, _TrajectoryByPoints):
    """Drake forward dynamics of a robot, semi-implicit Euler with step ``dt``; controls are torques.

    Coupled joints (Nao) use the reduced model ``M_r = P^T M P``, ``h_r = P^T h``:
    ``qddot = M_r^-1 (u - h_r(q, qdot))`` with ``h = C qdot - tau_g + D qdot`` (joint damping D; gravity and damping come from
    Drake's force elements).
    Derivatives are exact: with ``ID(q, v, a) = M_r(q) a + h_r(q, v)`` differentiated by
    Drake's AutoDiffXd at ``a = qddot``, ``d qddot/d(q, v) = -M_r^-1 d ID/d(q, v)`` and
    ``d qddot/d u = M_r^-1``.
    """

    def __init__(self, robot, dt: float):
        from pydrake.autodiffutils import AutoDiffXd  # noqa: F401  (registers the scalar type)
        from pydrake.multibody.tree import MultibodyForces_

        self.robot = robot
        self.dt = float(dt)
        self.n_q = robot.n_q
        self.n_x = 2 * robot.n_q
        self.n_u = robot.n_q
        self.P = robot.P
        plant = robot.plant
        self._plant = plant
        self._ctx = plant.CreateDefaultContext()
        self._plant_ad = plant.ToAutoDiffXd()
        self._ctx_ad = self._plant_ad.CreateDefaultContext()
        self._forces = MultibodyForces_[float](plant)
        self._forces_ad = MultibodyForces_[AutoDiffXd](self._plant_ad)
        self._vdot0 = np.zeros(plant.num_velocities())

    # -- float evaluation -------------------------------------------------------------
    def _h_and_Mr(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        plant, ctx, P = self._plant, self._ctx, self.P
        plant.SetPositions(ctx, P @ q)
        plant.SetVelocities(ctx, P @ v)
        plant.CalcForceElementsContribution(ctx, self._forces)
        h = plant.CalcInverseDynamics(ctx, self._vdot0, self._forces)
        M = plant.CalcMassMatrix(ctx)
        return P.T @ h, P.T @ M @ P

    def qddot(self, q: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Joint accelerations ``(n_q,)`` (rad/s^2) for torques ``u (n_q,)`` (N m).

        Non-finite inputs give NaN (a diverging rollout stays a result; Drake would abort)."""
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v)) and np.all(np.isfinite(u))):
            return np.full(self.n_q, np.nan)
        h, Mr = self._h_and_Mr(q, v)
        return np.linalg.solve(Mr, u - h)

    def inverse_dynamics(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """Torques ``(n_q,)`` that produce accelerations ``a`` (computed torque)."""
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            return np.full(self.n_q, np.nan)
        h, Mr = self._h_and_Mr(q, v)
        return Mr @ a + h

    # -- derivatives ------------------------------------------------------------------
    def qddot_derivatives(self, q, v, u) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``qddot``, ``d/dq``, ``d/dv`` ``(n_q, n_q)`` and ``d/du`` ``(n_q, n_q)`` (NaN if not finite)."""
        from pydrake.autodiffutils import ExtractGradient, InitializeAutoDiff

        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v)) and np.all(np.isfinite(u))):
            nan = np.full((self.n_q, self.n_q), np.nan)
            return np.full(self.n_q, np.nan), nan, nan.copy(), nan.copy()

        h, Mr = self._h_and_Mr(q, v)
        Mr_inv = np.linalg.inv(Mr)
        a = Mr_inv @ (u - h)
        n, P = self.n_q, self.P
        qv = InitializeAutoDiff(np.concatenate([q, v])).reshape(-1)
        plant, ctx = self._plant_ad, self._ctx_ad
        plant.SetPositions(ctx, P @ qv[:n])
        plant.SetVelocities(ctx, P @ qv[n:])
        plant.CalcForceElementsContribution(ctx, self._forces_ad)
        tau = plant.CalcInverseDynamics(ctx, P @ a, self._forces_ad)
        dID = ExtractGradient(P.T @ tau)  # (n, 2n)
        dqv = -Mr_inv @ dID
        return a, dqv[:, :n], dqv[:, n:], Mr_inv

    def linearize(self, x, u):
        n, dt = self.n_q, self.dt
        a, Fq, Fv, Fu = self.qddot_derivatives(x[:n], x[n:], u)
        I = np.eye(n)
        dv_dx = dt * np.hstack([Fq, Fv]) + np.hstack([np.zeros((n, n)), I])
        dv_du = dt * Fu
        dq_dx = np.hstack([I, np.zeros((n, n))]) + dt * dv_dx
        A = np.vstack([dq_dx, dv_dx])
        B = np.vstack([dt * dv_du, dv_du])
        return A, self.step(x, u) - A @ x - B @ u, B



class GravityTorques:
    """The joint torques that hold a robot still against gravity: ``g(q) = -P^T tau_g(P q)`` (N m,
    ``(n_q,)``), with ``tau_g`` Drake's generalized gravity forces (``M qddot + C v = tau + tau_g``);
    its Jacobian ``dg/dq (n_q, n_q)`` exact, by Drake's AutoDiffXd. At rest, ``u = g(q)`` gives
    ``qddot = 0`` (joint damping is zero at ``v = 0``): crocoddyl's ``ResidualModelControlGrav``
    measures the control against it."""

    def __init__(self, robot):
        from pydrake.autodiffutils import AutoDiffXd  # noqa: F401  (registers the scalar type)

        self.robot, self.P, self.n_q = robot, robot.P, robot.n_q
        self._plant = robot.plant
        self._ctx = self._plant.CreateDefaultContext()
        self._plant_ad = self._plant.ToAutoDiffXd()
        self._ctx_ad = self._plant_ad.CreateDefaultContext()

    def value(self, q: np.ndarray) -> np.ndarray:
        """``g(q) (n_q,)`` at planning positions ``q (n_q,)`` (NaN where ``q`` is not finite)."""
        if not np.all(np.isfinite(q)):
            return np.full(self.n_q, np.nan)
        self._plant.SetPositions(self._ctx, self.P @ q)
        return -self.P.T @ self._plant.CalcGravityGeneralizedForces(self._ctx)

    def value_and_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``g(q) (n_q,)`` and ``dg/dq (n_q, n_q)``."""
        from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff

        if not np.all(np.isfinite(q)):
            return np.full(self.n_q, np.nan), np.full((self.n_q, self.n_q), np.nan)
        qa = InitializeAutoDiff(np.asarray(q, float)).reshape(-1)
        self._plant_ad.SetPositions(self._ctx_ad, self.P @ qa)
        g = -self.P.T @ self._plant_ad.CalcGravityGeneralizedForces(self._ctx_ad)
        return ExtractValue(g).reshape(-1), ExtractGradient(g)

    def values(self, Q: np.ndarray) -> np.ndarray:
        """Rows ``Q (K, n_q)`` -> ``G (K, n_q)``, without the Jacobians (a cost alone)."""
        Q = np.atleast_2d(Q)
        return np.array([self.value(q) for q in Q]).reshape(len(Q), self.n_q)

    def values_and_jacobians(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rows ``Q (K, n_q)`` -> ``G (K, n_q)``, ``dG (K, n_q, n_q)``."""
        Q = np.atleast_2d(Q)
        out = [self.value_and_jacobian(q) for q in Q]
        return np.array([o[0] for o in out]).reshape(len(Q), self.n_q), \
            np.array([o[1] for o in out]).reshape(len(Q), self.n_q, self.n_q)


class ActuatedDynamics:
    """An underactuated robot's model: controls are the motors' commands ``u (n_act,)`` (N m or N), the joint
    torques ``S @ u`` with ``S (n_q, n_act)`` selecting the actuated joints (``raico.plants.robot.Robot.S``); the
    unactuated joints get none. Wraps any torque-controlled model ``inner`` (analytic or learned):
    ``f(x, u) = inner.f(x, S u)``, so ``B = B_inner S`` and ``a`` is the inner model's (``B_inner S u = B u``).
    The uncertainty term's variance gradients are mapped alike (``dvar/du = dvar/dtau S``)."""

    def __init__(self, inner, S: np.ndarray):
        self.inner = inner
        self.S = np.asarray(S, float)
        if self.S.shape[0] != inner.n_u:
            raise ValueError(f"S is {self.S.shape}, the model takes {inner.n_u} torques")
        self.n_x, self.n_u, self.dt = inner.n_x, self.S.shape[1], inner.dt
        self.n_q = getattr(inner, "n_q", self.n_x // 2)
        self.robot = getattr(inner, "robot", None)

    def torques(self, u: np.ndarray) -> np.ndarray:
        """Joint torques ``(..., n_q)`` of motor commands ``u (..., n_act)``."""
        return np.asarray(u, float) @ self.S.T

    def step(self, x, u):
        return self.inner.step(x, self.torques(u))

    def qddot(self, q, v, u):
        return self.inner.qddot(q, v, self.torques(u))

    def linearize(self, x, u):
        A, a, B = self.inner.linearize(x, self.torques(u))
        return A, a, B @ self.S

    def linearize_trajectory(self, X, U):
        A, a, B = self.inner.linearize_trajectory(X, self.torques(U))
        return A, a, B @ self.S

    def controller_rollout(self, x0, o, O):
        """``X (T+1, n_x)``, ``U (T, n_act)`` of ``u_t = o_t + O_t x_t``: the inner model's rollout of the
        torque controller ``S o_t + S O_t x_t`` (its compiled one where it has one)."""
        own = getattr(self.inner, "controller_rollout", None)
        if own is None:
            return stepped_rollout(self, np.asarray(x0, float), o, O)
        X, tau = own(np.asarray(x0, float), self.torques(o), np.einsum("ij,tjk->tik", self.S, O))
        return X, tau @ self.S   # S has orthonormal columns: S^T S u = u

    def inverse_dynamics(self, q, v, a):
        """The motor commands ``(n_act,)`` closest (least squares) to the torques that give ``a``."""
        return self.S.T @ self.inner.inverse_dynamics(q, v, a)

    def predict_variance(self, X, U):
        var, dx, du = self.inner.predict_variance(X, self.torques(U))
        return var, dx, du @ self.S

    def point_variance(self, x, u):
        var, dx, du = self.inner.point_variance(x, self.torques(u))
        return var, dx, du @ self.S

    @property
    def model(self):
        """The inner learned model's GP (the uncertainty term reads its output scale)."""
        return self.inner.model


class SubstepDynamics:
    """A model stepped ``k`` times per control step: ``x_{t+1} = f^k(x_t, u_t)`` with ``f`` the inner model of
    step ``dt / k`` and ``u_t`` held over the ``k`` substeps (a zero-order hold, as an execution applies it).
    A coarse control step (PILCO's 0.1 s) then keeps the inner integrator's accuracy. The linearization is
    the chain rule through the substeps, exact at the point: ``A = A_k ... A_1``,
    ``B = sum_i A_k ... A_{i+1} B_i`` and ``a = f^k(x, u) - A x - B u``. The uncertainty term's variance is
    the inner model's at the step's start ``(x_t, u_t)``."""

    def __init__(self, inner, k: int):
        if int(k) < 1:
            raise ValueError(f"substeps must be >= 1, got {k}")
        self.inner, self.k = inner, int(k)
        self.n_x, self.n_u, self.dt = inner.n_x, inner.n_u, inner.dt * self.k
        self.n_q = getattr(inner, "n_q", self.n_x // 2)
        self.robot = getattr(inner, "robot", None)

    def step(self, x, u):
        for _ in range(self.k):
            x = self.inner.step(x, u)
        return x

    def linearize(self, x, u):
        x = np.asarray(x, float)
        A, B = np.eye(self.n_x), np.zeros((self.n_x, self.n_u))
        xi = x
        for _ in range(self.k):
            Ai, ai, Bi = self.inner.linearize(xi, u)
            A, B = Ai @ A, Ai @ B + Bi
            xi = Ai @ xi + ai + Bi @ u   # the inner model's step (its affine model is exact at the point)
        return A, xi - A @ x - B @ u, B

    def linearize_trajectory(self, X, U):
        X, U = np.asarray(X, float), np.asarray(U, float)
        T = X.shape[0]
        A = np.broadcast_to(np.eye(self.n_x), (T, self.n_x, self.n_x)).copy()
        B = np.zeros((T, self.n_x, self.n_u))
        Xi = X
        for _ in range(self.k):
            Ai, ai, Bi = self.inner.linearize_trajectory(Xi, U)
            A, B = Ai @ A, Ai @ B + Bi
            Xi = np.einsum("tij,tj->ti", Ai, Xi) + ai + np.einsum("tij,tj->ti", Bi, U)
        return A, Xi - np.einsum("tij,tj->ti", A, X) - np.einsum("tij,tj->ti", B, U), B

    def _kernel(self):
        """The inner model's compiled ``k`` substeps (its ``substep_kernel``: the model file plus a residual
        GP), or ``None``."""
        get = getattr(self.inner, "substep_kernel", None)
        return None if get is None else get(self.k)

    def c_linearizer(self):
        """The compiled linearization of the ``k`` substeps (the sweep kernel's), or ``None`` (the sweeps
        call :meth:`linearize`)."""
        kern = self._kernel()
        return None if kern is None else kern.linearizer()

    def controller_rollout(self, x0, o, O):
        """``X (T+1, n_x)``, ``U (T, n_u)`` of ``u_t = o_t + O_t x_t`` held over each step's substeps
        (compiled where the inner model compiles its substeps, else stepped in Python)."""
        x0 = np.asarray(x0, float)
        kern = self._kernel()
        return stepped_rollout(self, x0, o, O) if kern is None else kern.rollout(x0.reshape(-1), o, O)

    def inverse_dynamics(self, q, v, a):
        return self.inner.inverse_dynamics(q, v, a)

    def predict_variance(self, X, U):
        return self.inner.predict_variance(X, U)

    def point_variance(self, x, u):
        return self.inner.point_variance(x, u)

    @property
    def model(self):
        """The inner learned model's GP (the uncertainty term reads its output scale)."""
        return self.inner.model
