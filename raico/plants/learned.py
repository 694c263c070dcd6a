"""Learned dynamics: ``qddot = GP mean(q, qdot, u)`` with the analytic models' step.

State ``x = (q, qdot)`` (rad, rad/s, ``n_x = 2 n_q``), control ``u`` (N m, ``n_u``), GP inputs
``(q, qdot, u)`` of size ``d = n_x + n_u`` and outputs ``qddot`` (rad/s^2, ``n_q``). One step of
``dt`` s is semi-implicit Euler, ``qdot' = qdot + dt qddot``, ``q' = q + dt qdot'``
(``raico.plants.dynamics.SemiImplicitEuler``). The linearization ``(A, a, B)`` uses the GP mean's
analytic input gradients, so it is exact at the point (``a = f(x, u) - A x - B u``);
``linearize_trajectory`` makes one GP call for all steps. ``predict_variance`` gives the GP's
latent variance of each ``qddot`` and its gradients for the uncertainty cost (thesis eq. 4.3).
Non-finite inputs give NaN outputs, never an exception. A fit of a robot with continuous joints stores a
``raico.plants.gp.AngleInputGP``: its GP reads those angles as ``(sin, cos)`` and its gradients in ``(q, qdot, u)``
come through the chain rule, so the linearization below is unchanged (and exact at the point).
"""

from __future__ import annotations

import ctypes
from collections.abc import Mapping

import numpy as np

from raico.plants.codegen import c_backend
from raico.plants.dynamics import SemiImplicitEuler, stepped_rollout
from raico.plants.gp import POINT_MAX_INPUTS, AngleInputGP, GPBase, GPModel, _point_lib


class LearnedDynamics(SemiImplicitEuler):
    """Dynamics model (``raico.plants.dynamics.Dynamics``) whose accelerations are a GP's mean."""

    def __init__(self, model: GPBase | AngleInputGP, n_q: int, dt: float):
        if model.D != n_q or model.d <= 2 * n_q:
            raise ValueError(f"GP with {model.d} inputs and {model.D} outputs does not fit a robot with {n_q} joints")
        self.model = model
        self.n_q = int(n_q)
        self.n_x = 2 * self.n_q
        self.n_u = model.d - self.n_x
        self.dt = float(dt)
        self._I = np.eye(self.n_q)

    def qddot(self, q: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray:
        """GP mean accelerations ``(n_q,)`` (rad/s^2) at one state and control (NaN if not finite);
        the compiled one-point path (rollouts step one point at a time)."""
        return self.model.point_mean_with_gradients(np.concatenate([q, v, u]))[0]

    def step_batch(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """Next states ``(T, n_x)`` for states ``X (T, n_x)`` and controls ``U (T, n_u)``."""
        return self._euler(X, self.model.predict_mean(np.hstack([X, U])))

    def _euler(self, X: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        n, dt = self.n_q, self.dt
        v1 = X[:, n:] + dt * qdd
        return np.hstack([X[:, :n] + dt * v1, v1])

    def linearize(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A (n_x, n_x), a (n_x,), B (n_x, n_u))`` at ``(x, u)``: ``linearize_trajectory`` for one
        point, the GP's mean and gradient in one compiled call (``GPBase.point_mean_with_gradients``;
        the sweeps relinearize one point at a time)."""
        x, u = np.asarray(x, float).reshape(-1), np.asarray(u, float).reshape(-1)
        n, nx, dt = self.n_q, self.n_x, self.dt
        mean, F = self.model.point_mean_with_gradients(np.concatenate([x, u]))   # (n,), (n, nx + nu)
        A = np.empty((nx, nx))
        np.multiply(F[:, :nx], dt, out=A[n:])                 # dv'/dx = [0, I] + dt F_x
        A[n:, n:] += self._I
        np.multiply(A[n:], dt, out=A[:n])                     # dq'/dx = [I, 0] + dt dv'/dx
        A[:n, :n] += self._I
        B = np.empty((nx, self.n_u))
        np.multiply(F[:, nx:], dt, out=B[n:])                 # dv'/du = dt F_u
        np.multiply(B[n:], dt, out=B[:n])
        v1 = x[n:] + dt * mean
        a = np.concatenate([x[:n] + dt * v1, v1])
        a -= A @ x
        a -= B @ u
        return A, a, B

    def linearize_trajectory(self, X: np.ndarray, U: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``A (T, n_x, n_x)``, ``a (T, n_x)``, ``B (T, n_x, n_u)`` along ``X (T, n_x)``, ``U (T, n_u)`` (one GP call).

        With ``F = d qddot / d(x, u)`` from the GP: ``dv'/dx = [0, I] + dt F_x``,
        ``dq'/dx = [I, 0] + dt dv'/dx``, ``dv'/du = dt F_u``, ``dq'/du = dt dv'/du``."""
        X, U = np.asarray(X, float), np.asarray(U, float)
        n, nx, dt, T = self.n_q, self.n_x, self.dt, X.shape[0]
        mean, F = self.model.mean_with_gradients(np.hstack([X, U]))  # (T, n), (T, n, nx + nu)
        dv_dx = dt * F[:, :, :nx]
        dv_dx[:, :, n:] += np.eye(n)
        dv_du = dt * F[:, :, nx:]
        A = np.empty((T, nx, nx))
        A[:, n:] = dv_dx
        A[:, :n] = dt * dv_dx
        A[:, :n, :n] += np.eye(n)
        B = np.concatenate([dt * dv_du, dv_du], axis=1)
        a = self._euler(X, mean) - np.einsum("tij,tj->ti", A, X) - np.einsum("tij,tj->ti", B, U)
        return A, a, B

    def controller_rollout(self, x0: np.ndarray, o: np.ndarray, O: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``X (T+1, n_x)``, ``U (T, n_u)`` of ``u_t = o_t + O_t x_t`` from ``x0``: the problem's rollout
        (``raico.planning.problem.Problem.controller_rollout``) in one compiled call
        (``GPBase.controller_rollout``), else stepping ``step`` in Python. NaN propagates."""
        x0 = np.asarray(x0, float).reshape(-1)
        out = self.model.controller_rollout(x0, o, O, self.dt)
        if out is not None:
            return out
        return stepped_rollout(self, x0, o, O)

    def c_linearizer(self) -> tuple[int, int, object] | None:
        """``(function address, context address, keep-alive)`` of the compiled ``linearize`` (the AICO
        sweep kernel relinearizes through it without Python), or ``None`` without a C compiler."""
        return self.model.point_linearizer(self.dt)

    def point_variance(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``predict_variance`` at one state ``x (n_x,)`` and control ``u (n_u,)``: ``(n_q,)``,
        ``(n_q, n_x)``, ``(n_q, n_u)`` (``GPModel.point_predict_with_gradients``, compiled)."""
        _, var, _, dvar = self.model.point_predict_with_gradients(np.concatenate([x, u]))
        return var, dvar[:, :self.n_x], dvar[:, self.n_x:]

    def predict_variance(self, X: np.ndarray, U: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """GP latent variance of ``qddot`` ``(T, n_q)`` ((rad/s^2)^2) and its gradients ``(T, n_q, n_x)``, ``(T, n_q, n_u)``."""
        _, var, _, dvar = self.model.predict_with_gradients(np.hstack([np.asarray(X, float), np.asarray(U, float)]))
        return var, dvar[:, :, :self.n_x], dvar[:, :, self.n_x:]


class ResidualDynamics(LearnedDynamics):
    """The model file's dynamics plus a GP of what it misses: ``qddot = f_model(q, qdot, u) + GP mean``.

    ``base``: the robot's analytic model (``raico.plants.fast_analytic.make_fast_or_exact``, semi-implicit
    Euler of the same ``dt``); the GP was fitted to ``qddot_executed - f_model`` (``raico.stages.fit``,
    ``--residual``). A step is linear in ``qddot``, so the linearization is the base's plus the GP
    mean's: ``dv'/dx += dt F_x``, ``dq'/dx += dt^2 F_x`` (and ``F_u`` for ``B``), exact at the point.
    The variance (the uncertainty term) is the GP's alone: the model file adds none. The one-point
    linearization and the rollout are compiled (:class:`ResidualKernel`, also ``k`` steps per control step:
    :meth:`substep_kernel`) where the base is the compiled model file and the GP an exact or sparse one
    (not ``AngleInputGP``); else the sweeps call ``linearize`` and the rollout steps in Python."""

    compiled = True   # the compiled kernel where it builds (False: the Python path, for comparisons)

    def __init__(self, model: GPBase | AngleInputGP, base, dt: float):
        super().__init__(model, base.n_q, dt)
        if abs(base.dt - self.dt) > 1e-12:
            raise ValueError(f"the base model's step {base.dt} s differs from {dt} s")
        self.base = base
        self._kernels: dict[int, ResidualKernel] = {}

    def __getstate__(self):  # the compiled kernels hold ctypes pointers: rebuilt on first use
        d = dict(self.__dict__)
        d["_kernels"] = {}
        return d

    def substep_kernel(self, k: int = 1) -> ResidualKernel | None:
        """The compiled model of ``k`` steps per control step (:class:`ResidualKernel`), or ``None`` (no C
        compiler, a base without compiled code, an ``AngleInputGP``); rebuilt when the GP's arrays change."""
        model, get = self.model, getattr(self.base, "_compiled", None)
        if not self.compiled or not isinstance(model, GPBase) or get is None or model.d > POINT_MAX_INPUTS:
            return None
        base_c, gp_lib, lib = get(), _point_lib(), _residual_lib()
        if base_c is None or gp_lib is None or lib is None or getattr(base_c, "n", None) != self.n_q:
            return None
        pc = model._point_arrays()
        kern = self._kernels.get(k)
        if kern is None:
            kern = self._kernels[k] = ResidualKernel(lib, base_c, gp_lib, pc, model, self.dt, k)
        elif kern._keep[2] is not pc:
            kern.refresh(pc, model)
        return kern

    def qddot(self, q: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``f_model + GP mean`` ``(n_q,)`` (rad/s^2) at one state and control (NaN if not finite)."""
        x = np.concatenate([q, v, u])
        if not np.all(np.isfinite(x)):
            return np.full(self.n_q, np.nan)
        return self.base.qddot(q, v, u) + self.model.point_mean_with_gradients(x)[0]

    def step_batch(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """Next states ``(T, n_x)`` for states ``X (T, n_x)`` and controls ``U (T, n_u)``."""
        n = self.n_q
        base = np.array([self.base.qddot(x[:n], x[n:], u) for x, u in zip(X, U)]).reshape(-1, n)
        return self._euler(X, base + self.model.predict_mean(np.hstack([X, U])))

    def _add_gp(self, A: np.ndarray, B: np.ndarray, F: np.ndarray) -> None:
        """Add the GP mean's part ``F = d mean / d(x, u)`` (``(..., n_q, n_x + n_u)``) to ``A``, ``B`` in place."""
        n, nx, dt = self.n_q, self.n_x, self.dt
        A[..., n:, :] += dt * F[..., :nx]
        A[..., :n, :] += dt * dt * F[..., :nx]
        B[..., n:, :] += dt * F[..., nx:]
        B[..., :n, :] += dt * dt * F[..., nx:]

    def linearize(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A, a, B)`` at ``(x, u)``: the base model's plus the GP mean's (class docstring)."""
        x, u = np.asarray(x, float).reshape(-1), np.asarray(u, float).reshape(-1)
        A, _, B = self.base.linearize(x, u)
        A, B = np.array(A, float), np.array(B, float)
        _, F = self.model.point_mean_with_gradients(np.concatenate([x, u]))
        self._add_gp(A, B, F)
        return A, self.step(x, u) - A @ x - B @ u, B

    def linearize_trajectory(self, X: np.ndarray, U: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``A (T, n_x, n_x)``, ``a (T, n_x)``, ``B (T, n_x, n_u)`` along ``X (T, n_x)``, ``U (T, n_u)``: the
        base's batch plus the GP's mean and gradient at every step in one call. A step is the base's plus
        ``(dt^2 m, dt m)``, so ``a = a_base + (dt^2, dt) (m - F (x, u))`` (no step of its own)."""
        X, U = np.asarray(X, float), np.asarray(U, float)
        A, a, B = self.base.linearize_trajectory(X, U)
        A, a, B = np.array(A, float), np.array(a, float), np.array(B, float)
        Z = np.hstack([X, U])
        mean, F = self.model.mean_with_gradients(Z)
        self._add_gp(A, B, F)
        r = mean - np.einsum("tij,tj->ti", F, Z)
        n, dt = self.n_q, self.dt
        a[:, n:] += dt * r
        a[:, :n] += dt * dt * r
        return A, a, B

    def controller_rollout(self, x0: np.ndarray, o: np.ndarray, O: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``X (T+1, n_x)``, ``U (T, n_u)`` of ``u_t = o_t + O_t x_t`` from ``x0``: compiled where
        :meth:`substep_kernel` is, else stepped in Python."""
        x0 = np.asarray(x0, float).reshape(-1)
        kern = self.substep_kernel(1)
        return stepped_rollout(self, x0, o, O) if kern is None else kern.rollout(x0, o, O)

    def c_linearizer(self) -> tuple[int, int, object] | None:
        """The compiled linearization of the sum (:meth:`substep_kernel`), or ``None`` (the sweeps call
        :meth:`linearize`)."""
        kern = self.substep_kernel(1)
        return None if kern is None else kern.linearizer()


# -- the compiled residual step (residual_step.c) -----------------------------------------------------------------


#: The compiled ``residual_step`` (``None`` without a C compiler or with ``RAICO_NO_C``).
_residual_lib = c_backend.CompiledLibrary("residual_step", lambda: c_backend.c_source(__file__, "residual_step.c"), {
    "res_work_size": ([ctypes.c_long] * 2, ctypes.c_long),
    "res_linearize": ([ctypes.c_void_p] * 6, ctypes.c_int),
    "res_step": ([ctypes.c_void_p] * 4, ctypes.c_int),
    "res_rollout": ([ctypes.c_void_p, ctypes.c_long] + [ctypes.c_void_p] * 4, ctypes.c_int),
    "res_linearize_address": (None, ctypes.c_void_p)}, flags=(*c_backend.CFLAGS, "-O3"))


class _ResCtx(ctypes.Structure):
    _fields_ = [*((k, ctypes.c_void_p) for k in ("base_qdd", "base_lin", "base_ctx", "gp_point", "gp_mean")),
                *((k, ctypes.c_long) for k in ("N", "d", "nq", "k")),
                *((k, ctypes.c_void_p) for k in ("Zs", "weights", "sf2", "inv_ell", "x_mean", "x_std", "y_mean",
                                                 "y_std")),
                ("dt", ctypes.c_double), ("work", ctypes.c_void_p)]


class ResidualKernel:
    """The model file plus the residual GP stepped ``k`` times per control step, compiled (``residual_step.c``):
    one control step's linearization (``res_linearize``, the AICO sweep kernel's ``lin_t``), step and rollout,
    the formulas of :meth:`ResidualDynamics.linearize` chained as ``SubstepDynamics.linearize`` (equal to
    rounding). Built by :meth:`ResidualDynamics.substep_kernel`, which refreshes it in place when the GP's arrays
    were replaced (an online update): its context keeps its address, so a sweep kernel holding it reads the new
    GP. Not thread-safe (one work array)."""

    def __init__(self, lib, base_c, gp_lib, pc: dict, gp, dt: float, k: int):
        nq, d = gp.D, gp.d
        self.lib, self.k, self.nx, self.nu = lib, int(k), 2 * nq, d - 2 * nq
        self.work = np.empty(lib.res_work_size(nq, d))
        addr = ctypes.cast
        self.ctx = _ResCtx(addr(base_c.lib.dyn_qddot, ctypes.c_void_p).value, base_c.lin_address,
                           base_c.ctx_address, addr(gp_lib.gp_point, ctypes.c_void_p).value,
                           addr(gp_lib.gp_point_mean, ctypes.c_void_p).value,
                           gp.Z.shape[0], d, nq, self.k, *pc["ptrs"][:4], *pc["stat_ptrs"], float(dt),
                           self.work.ctypes.data)
        self._keep = (base_c, gp_lib, pc)
        self.address = ctypes.addressof(self.ctx)
        self._x, self._u, self._xn = np.empty(self.nx), np.empty(self.nu), np.empty(self.nx)
        self._A, self._a, self._B = np.empty((self.nx, self.nx)), np.empty(self.nx), np.empty((self.nx, self.nu))

    def refresh(self, pc: dict, gp) -> None:
        """Point the context at the GP's arrays ``pc`` (``GPBase._point_arrays``) of now, in place."""
        self.ctx.N = gp.Z.shape[0]
        for name, ptr in zip(("Zs", "weights", "sf2", "inv_ell", "x_mean", "x_std", "y_mean", "y_std"),
                             (*pc["ptrs"][:4], *pc["stat_ptrs"])):
            setattr(self.ctx, name, ptr)
        self._keep = (*self._keep[:2], pc)

    def linearizer(self) -> tuple[int, int, object]:
        """``(address of res_linearize, address of its context, keep-alive)`` (``c_linearizer``'s form)."""
        return self.lib.res_linearize_address(), self.address, self

    def linearize(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A, a, B)`` of one control step at ``(x, u)`` (new arrays)."""
        self._x[:], self._u[:] = x, u
        self.lib.res_linearize(self.address, *(z.ctypes.data for z in (self._x, self._u, self._A, self._a, self._B)))
        return self._A.copy(), self._a.copy(), self._B.copy()

    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """One control step ``(n_x,)`` from ``x`` with ``u`` held (a new array)."""
        self._x[:], self._u[:] = x, u
        self.lib.res_step(self.address, *(z.ctypes.data for z in (self._x, self._u, self._xn)))
        return self._xn.copy()

    def rollout(self, x0: np.ndarray, o: np.ndarray, O: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``X (T+1, n_x)``, ``U (T, n_u)`` of ``u_t = o_t + O_t x_t`` from ``x0`` (NaN propagates)."""
        T = np.shape(o)[0]
        o, O = np.ascontiguousarray(o, dtype=float), np.ascontiguousarray(O, dtype=float)
        if o.shape != (T, self.nu) or O.shape != (T, self.nu, self.nx) or np.shape(x0) != (self.nx,):
            raise ValueError(f"rollout expects x0 ({self.nx},), o (T, {self.nu}), O (T, {self.nu}, {self.nx})")
        X, U = np.empty((T + 1, self.nx)), np.empty((T, self.nu))
        X[0] = x0
        self.lib.res_rollout(self.address, T, o.ctypes.data, O.ctypes.data, X.ctypes.data, U.ctypes.data)
        return X, U


RESIDUAL_KEY = "residual"  # in a fit's stored arrays: 1 when the GP models f_true - f_model (ResidualDynamics)


def build_learned(robot, dt: float, params: Mapping[str, np.ndarray] | None) -> LearnedDynamics:
    """``LearnedDynamics`` of ``robot`` (anything with ``n_q``) from ``GPModel.to_arrays()`` output, step ``dt`` s;
    a residual fit's arrays (``RESIDUAL_KEY`` set) give :class:`ResidualDynamics` on the robot's analytic model.

    Bad input (no params, inconsistent arrays, ``dt`` not positive) raises ``ValueError``."""
    if params is None:
        raise ValueError("learned dynamics need params (the arrays of a fitted GP)")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive number of seconds, got {dt}")
    gp_arrays = {k: v for k, v in params.items() if k != RESIDUAL_KEY}
    if is_residual(params):
        from raico.plants.fast_analytic import make_fast_or_exact

        return ResidualDynamics(GPModel.from_arrays(gp_arrays), make_fast_or_exact(robot, dt), dt)
    return LearnedDynamics(GPModel.from_arrays(gp_arrays), robot.n_q, dt)


def is_residual(params: Mapping[str, np.ndarray]) -> bool:
    """Whether a fit's stored arrays are a residual GP's."""
    return bool(np.asarray(params.get(RESIDUAL_KEY, 0)).item())


def example_params(robot, n_points: int = 40, seed: int = 0) -> dict[str, np.ndarray]:
    """A small GP over ``(q, qdot, u)`` of ``robot`` fitted to a smooth synthetic acceleration
    (fixed hyperparameters, no optimization): valid ``params`` for tests and the harness."""
    rng = np.random.default_rng(seed)
    n = robot.n_q
    q = robot.default_q + 0.3 * rng.standard_normal((n_points, n))
    X = np.hstack([q, rng.standard_normal((n_points, n)), 2.0 * rng.standard_normal((n_points, n))])
    Y = np.sin(q) + 0.3 * X[:, n:2 * n] * np.cos(X[:, 2 * n:]) + 0.5 * X[:, 2 * n:]
    d = X.shape[1]
    model = GPModel(X, Y, np.full((n, d), 2.0), np.ones(n), np.full(n, 1e-4))
    return model.to_arrays()
