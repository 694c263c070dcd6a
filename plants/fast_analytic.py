"""Fast analytic dynamics: Drake's own equations of motion compiled to vectorized numpy (SPEC §4).

``FastAnalyticDynamics(robot, dt)`` is a drop-in for :class:`plants.dynamics.AnalyticDynamics`:
same interface, same numbers up to rounding (~1e-15 relative), but ``linearize_trajectory`` is
vectorized over time (no Python loop over steps) and single points skip Drake's per-call cost.
The code comes from :mod:`plants.codegen` (derived from the Drake plant itself, self-checked
against Drake at build time, kept in memory per plant name).

Evaluation uses the formulas of ``AnalyticDynamics``: ``qddot = M_r^-1 (u - h_r)``,
``d qddot/d(q, v) = -M_r^-1 dID_r/d(q, v)`` at ``a = qddot``, ``d qddot/du = M_r^-1`` with
``M_r = P^T M P``, ``h_r = P^T h`` and ``dID_r = P^T dID [P 0; 0 P]``; with ``a`` an input of
the generated derivative code, ``d(M a)/dq`` is included. Everything not depending on ``a`` is
computed in a first pass (``M``, ``h``, ``dh/dv``, ...), the rest after the solve for ``a``.

Plants that are too big to read (the 26-joint Nao) or that use unsupported joints raise
``NotImplementedError``; :func:`make_fast_or_exact` then returns ``AnalyticDynamics``.
"""

from __future__ import annotations

import numpy as np

from plants.codegen.derive import compiled_dynamics
from plants.dynamics import AnalyticDynamics, SemiImplicitEuler


class FastAnalyticDynamics(SemiImplicitEuler):
    """Drop-in for :class:`plants.dynamics.AnalyticDynamics` on the compiled symbolic dynamics.

    Same contract and numbers: semi-implicit Euler with step ``dt``, controls are torques,
    ``qddot = M_r^-1 (u - h_r)``, ``d qddot/d(q, v) = -M_r^-1 dID_r/d(q, v)`` at
    ``a = qddot``, ``d qddot/du = M_r^-1``. ``linearize_trajectory`` (and the batched
    ``qddot_trajectory``, ``step_trajectory``) evaluate all time steps in one pass of numpy
    operations; single-point calls run the generated code on Python floats.
    Raises ``NotImplementedError`` for plants it does not compile (see
    :func:`plants.codegen.derive.derive`).
    """

    def __init__(self, robot, dt: float):
        self.robot = robot
        self.dt = float(dt)
        self.n_q = robot.n_q
        self.n_x = 2 * robot.n_q
        self.n_u = robot.n_q
        self.P = np.asarray(robot.P, float)
        self._code = compiled_dynamics(robot)
        m = self._code.m
        if self.P.shape != (m, self.n_q):
            raise ValueError(f"P has shape {self.P.shape}, the plant has {m} positions")
        self._identity = m == self.n_q and np.array_equal(self.P, np.eye(m))

    # -- coordinates --------------------------------------------------------------------------
    def _plant(self, z: np.ndarray) -> np.ndarray:
        """Planning ``(..., n)`` -> plant ``(..., m)``."""
        return z if self._identity else z @ self.P.T

    def _reduce_M(self, M: np.ndarray) -> np.ndarray:
        return M if self._identity else self.P.T @ M @ self.P

    def _reduce_h(self, h: np.ndarray) -> np.ndarray:
        return h if self._identity else h @ self.P

    def _reduce_D(self, D: np.ndarray) -> np.ndarray:
        """``dID/d(qp, vp) (..., m, 2m)`` -> ``dID_r/d(q, v) (..., n, 2n)``."""
        if self._identity:
            return D
        m, P = self._code.m, self.P
        return np.concatenate([P.T @ D[..., :m] @ P, P.T @ D[..., m:] @ P], axis=-1)

    # -- single points (generated code on Python floats) --------------------------------------
    def _mh_point(self, q, v):
        m, mm = self._code.m, self._code.m * self._code.m
        qp, vp = self._plant(np.asarray(q, float)), self._plant(np.asarray(v, float))
        out = self._code.sca["mh"]([*qp.tolist(), *vp.tolist()], [0.0] * (mm + m))
        return self._reduce_M(np.array(out[:mm]).reshape(m, m)), self._reduce_h(np.array(out[mm:]))

    def _derivatives_point(self, q, v, u):
        """``a (n,)``, ``dqddot/d(q, v) (n, 2n)``, ``M_r^-1 (n, n)``."""
        code = self._code
        m, mm = code.m, code.m * code.m
        qp, vp = self._plant(np.asarray(q, float)), self._plant(np.asarray(v, float))
        out, carry = [0.0] * (mm + m), [0.0] * code.n_carry
        code.sca["first"]([*qp.tolist(), *vp.tolist()], out, carry)
        Mr = self._reduce_M(np.array(out[:mm]).reshape(m, m))
        hr = self._reduce_h(np.array(out[mm:]))
        Mr_inv = np.linalg.inv(Mr)
        a = Mr_inv @ (np.asarray(u, float) - hr)
        D = code.sca["second"]([*self._plant(a).tolist(), *carry], [0.0] * (2 * mm))
        D = np.array(D).reshape(m, 2 * m)
        return a, -(Mr_inv @ self._reduce_D(D)), Mr_inv

    # -- batches (generated code on (T,) arrays) ----------------------------------------------
    def _mh_batch(self, Q, V):
        code = self._code
        m, mm, T = code.m, code.m * code.m, Q.shape[0]
        xs = np.empty((2 * m, T))
        xs[:m], xs[m:] = self._plant(Q).T, self._plant(V).T
        out = code.vec["mh"](xs, np.empty((mm + m, T)))
        return self._reduce_M(out[:mm].T.reshape(T, m, m)), self._reduce_h(out[mm:].T)

    def _derivatives_batch(self, Q, V, U):
        """``a (T, n)``, ``dqddot/d(q, v) (T, n, 2n)``, ``M_r^-1 (T, n, n)``."""
        code = self._code
        m, mm, T = code.m, code.m * code.m, Q.shape[0]
        xs = np.empty((2 * m, T))
        xs[:m], xs[m:] = self._plant(Q).T, self._plant(V).T
        out, carry = np.empty((mm + m, T)), [None] * code.n_carry  # carried arrays: no copies
        code.vec["first"](xs, out, carry)
        Mr = self._reduce_M(out[:mm].T.reshape(T, m, m))
        hr = self._reduce_h(out[mm:].T)
        Mr_inv = np.linalg.inv(Mr)
        a = np.einsum("tij,tj->ti", Mr_inv, U - hr)
        D = code.vec["second"]([*self._plant(a).T, *carry], np.empty((2 * mm, T)))
        D = D.T.reshape(T, m, 2 * m)
        return a, -(Mr_inv @ self._reduce_D(D)), Mr_inv

    def _assemble(self, X, U, a, F, Mr_inv):
        """``A, a, B`` of semi-implicit Euler from ``qddot`` and its derivatives (batched)."""
        n, dt = self.n_q, self.dt
        lead = X.shape[:-1]
        A = np.empty((*lead, 2 * n, 2 * n))
        flat = A.reshape(-1, 4 * n * n)  # a view: diagonal entries by stride
        np.multiply(F, dt, out=A[..., n:, :])  # dv'/dx = dt F + [0 I]
        flat[:, 2 * n * n + n::2 * n + 1] += 1.0
        np.multiply(A[..., n:, :], dt, out=A[..., :n, :])  # dq'/dx = [I 0] + dt dv'/dx
        flat[:, 0:2 * n * n:2 * n + 1] += 1.0
        B = np.empty((*lead, 2 * n, n))
        np.multiply(Mr_inv, dt, out=B[..., n:, :])
        np.multiply(B[..., n:, :], dt, out=B[..., :n, :])
        # f(x, u) - A x - B u, simplified: with r = qddot - F x - M_r^-1 u the velocity rows
        # are dt r and the position rows dt^2 r (no cancellation against the state)
        if X.ndim == 1:
            r = a - F @ X - Mr_inv @ U
        else:
            r = a - np.einsum("tij,tj->ti", F, X) - np.einsum("tij,tj->ti", Mr_inv, U)
        aff = np.concatenate([(dt * dt) * r, dt * r], axis=-1)
        return A, aff, B

    # -- the AnalyticDynamics interface --------------------------------------------------------
    def qddot(self, q: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Joint accelerations ``(n_q,)`` (rad/s^2) for torques ``u (n_q,)`` (N m)."""
        Mr, hr = self._mh_point(q, v)
        return np.linalg.solve(Mr, np.asarray(u, float) - hr)

    def inverse_dynamics(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """Torques ``(n_q,)`` that produce accelerations ``a`` (computed torque)."""
        Mr, hr = self._mh_point(q, v)
        return Mr @ np.asarray(a, float) + hr

    def qddot_derivatives(self, q, v, u) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``qddot``, ``d/dq``, ``d/dv`` ``(n_q, n_q)`` and ``d/du`` ``(n_q, n_q)``."""
        a, F, Mr_inv = self._derivatives_point(q, v, u)
        return a, F[:, :self.n_q], F[:, self.n_q:], Mr_inv

    def linearize(self, x, u):
        x, u = np.asarray(x, float), np.asarray(u, float)
        n = self.n_q
        a, F, Mr_inv = self._derivatives_point(x[:n], x[n:], u)
        return self._assemble(x, u, a, F, Mr_inv)

    def linearize_trajectory(self, X: np.ndarray, U: np.ndarray):
        """``(A (T, n_x, n_x), a (T, n_x), B (T, n_x, n_u))`` along ``X (T, n_x)``, ``U (T, n_u)``,
        every time step in the same numpy operations."""
        X, U = self._check_batch(X, U)
        n = self.n_q
        a, F, Mr_inv = self._derivatives_batch(X[:, :n], X[:, n:], U)
        return self._assemble(X, U, a, F, Mr_inv)

    # -- batched extras -----------------------------------------------------------------------
    def qddot_trajectory(self, Q: np.ndarray, V: np.ndarray, U: np.ndarray) -> np.ndarray:
        """:meth:`qddot` at T points at once: ``(T, n_q)`` from ``Q, V, U (T, n_q)``."""
        Mr, hr = self._mh_batch(np.asarray(Q, float), np.asarray(V, float))
        return np.linalg.solve(Mr, (np.asarray(U, float) - hr)[..., None])[..., 0]

    def step_trajectory(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """:meth:`step` at T points at once (not a rollout): ``(T, n_x)``."""
        X, U = self._check_batch(X, U)
        n = self.n_q
        v1 = X[:, n:] + self.dt * self.qddot_trajectory(X[:, :n], X[:, n:], U)
        return np.concatenate([X[:, :n] + self.dt * v1, v1], axis=1)

    def _check_batch(self, X, U):
        X, U = np.asarray(X, float), np.asarray(U, float)
        if X.ndim != 2 or U.ndim != 2 or X.shape[0] != U.shape[0] or X.shape[1] != self.n_x \
                or U.shape[1] != self.n_u:
            raise ValueError(f"X {X.shape}, U {U.shape}: expected (T, {self.n_x}), (T, {self.n_u})")
        return X, U


def make_fast_or_exact(robot, dt: float) -> FastAnalyticDynamics | AnalyticDynamics:
    """:class:`FastAnalyticDynamics` when the robot's plant compiles, else ``AnalyticDynamics``."""
    try:
        return FastAnalyticDynamics(robot, dt)
    except NotImplementedError:
        return AnalyticDynamics(robot, dt)
