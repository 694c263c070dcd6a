"""Fast analytic dynamics: Drake's own equations of motion compiled to vectorized numpy.

``FastAnalyticDynamics(robot, dt)`` is a drop-in for :class:`raico.plants.dynamics.AnalyticDynamics`:
same interface, same numbers up to rounding (~1e-15 relative), but ``linearize_trajectory`` is
vectorized over time (no Python loop over steps) and single points skip Drake's per-call cost.
The code comes from :mod:`raico.plants.codegen` (derived from the Drake plant itself, self-checked
against Drake at build time, kept in memory per plant name). Evaluation uses the formulas of
``AnalyticDynamics`` (``qddot = M_r^-1 (u - h_r)`` and its derivatives through ``dID``).

Plants that are too big to read (the 26-joint Nao) or that use unsupported joints raise
``NotImplementedError``. :func:`make_fast_or_exact` takes this route for plants of up to
``SYMBOLIC_MAX_POSITIONS`` (5) positions, :class:`TreeAnalyticDynamics` for larger ones (and where
this route fails), ``AnalyticDynamics`` where neither builds.

Compiled route (speed only): the generated functions are also emitted as C
(:mod:`raico.plants.codegen.c_backend`), built once per plant with ``gcc`` and called through ``ctypes``;
the AICO sweep kernel calls ``dyn_linearize`` directly (:meth:`FastAnalyticDynamics.c_linearizer`).
Without ``gcc`` (or with ``RAICO_NO_C=1``) the numpy code runs.

:class:`TreeAnalyticDynamics` is the same model with the generated code replaced by the tree
kernels of :mod:`raico.plants.codegen.rbd` (Newton-Euler and its analytical derivatives in C): exact
derivatives for the Nao and for arms of 6 or more joints. The formulas, the C driver and the tree
route in detail: docs/kernels.md, "Fast analytic dynamics".
"""

from __future__ import annotations

import ctypes
from typing import Literal

import numpy as np

from raico.plants.codegen import c_backend
from raico.plants.codegen.derive import compiled_dynamics
from raico.plants.dynamics import AnalyticDynamics, GravityTorques, SemiImplicitEuler, stepped_rollout

_DRIVER_C = c_backend.c_source(__file__, "fast_analytic_driver.c")  # the C beside this module


class _DynCtx(ctypes.Structure):
    _fields_ = [("n", ctypes.c_int), ("identity", ctypes.c_int), ("dt", ctypes.c_double),
                ("P", ctypes.POINTER(ctypes.c_double))]


_P = ctypes.POINTER(ctypes.c_double)


# The dynamics libraries at -O3 (later flags win): the derivative loops vectorize; contraction and
# reassociation stay off, so every number is the -O2 build's, bit for bit (tests/plants/test_fastdyn.py).
DYN_FLAGS = (*c_backend.CFLAGS, "-O3")


class _CompiledStep:
    """The C twin of a :class:`FastAnalyticDynamics` (one library per generated plant code).

    Single points go through preallocated buffers whose addresses are computed once (``ctypes``
    argument conversion costs more than the C code)."""

    def __init__(self, code, n: int, dt: float, P: np.ndarray, identity: bool, name: str):
        if not 1 <= n <= code.m:   # the driver's work arrays are sized by the plant's positions
            raise ValueError(f"dyn_{name}: {n} planning coordinates, the compiled driver takes 1 to {code.m}")
        c_backend.check_shapes(f"dyn_{name}", P=(P, (code.m, n)))
        header = (f"#include <math.h>\n#include <string.h>\n#define MP {code.m}\n"
                  f"#define NCARRY {code.n_carry}\n")
        lib = c_backend.load_library(header + code.c_source + _DRIVER_C, f"dyn_{name}", flags=DYN_FLAGS)
        self.lib = lib
        self.n = n
        N = 2 * n
        self._P = np.ascontiguousarray(P, dtype=float)
        self.ctx = _DynCtx(n, int(identity), float(dt), self._P.ctypes.data_as(_P))
        vp, i = ctypes.c_void_p, ctypes.c_int
        for f, args in (("dyn_step", [vp] * 4), ("dyn_linearize", [vp] * 6),
                        ("dyn_linearize_batch", [vp, i] + [vp] * 5),
                        ("dyn_controller_rollout", [vp, i] + [vp] * 5), ("dyn_qddot", [vp] * 4),
                        ("dyn_mh", [vp] * 4), ("dyn_derivatives", [vp] * 6)):
            getattr(lib, f).restype = ctypes.c_int
            getattr(lib, f).argtypes = args
        lib.dyn_linearize_address.restype = ctypes.c_void_p
        self.lin_address = lib.dyn_linearize_address()
        self.ctx_address = ctypes.addressof(self.ctx)
        # point buffers: x, u, next state, A, a, B
        self._x, self._u, self._xn = np.empty(N), np.empty(n), np.empty(N)
        self._A, self._a, self._B = np.empty((N, N)), np.empty(N), np.empty((N, n))
        self._addr = [b.ctypes.data for b in (self._x, self._u, self._xn, self._A, self._a, self._B)]

    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        self._x[:] = x
        self._u[:] = u
        ax, au, axn = self._addr[:3]
        self.lib.dyn_step(self.ctx_address, ax, au, axn)
        return self._xn.copy()

    def linearize(self, x: np.ndarray, u: np.ndarray):
        self._x[:] = x
        self._u[:] = u
        ax, au, _, aA, aa, aB = self._addr
        self.lib.dyn_linearize(self.ctx_address, ax, au, aA, aa, aB)
        return self._A.copy(), self._a.copy(), self._B.copy()

    def mh(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``M_r (n, n)``, ``h_r (n,)`` at ``x = (q, v)``."""
        self._x[:] = x
        Mr, hr = np.empty((self.n, self.n)), np.empty(self.n)
        self.lib.dyn_mh(self.ctx_address, self._addr[0], Mr.ctypes.data, hr.ctypes.data)
        return Mr, hr

    def derivatives(self, x: np.ndarray, u: np.ndarray):
        """``qddot (n,)``, ``d qddot/d(q, v) (n, 2n)``, ``M_r^-1 (n, n)``."""
        n = self.n
        self._x[:] = x
        self._u[:] = u
        a, F, Mi = np.empty(n), np.empty((n, 2 * n)), np.empty((n, n))
        self.lib.dyn_derivatives(self.ctx_address, self._addr[0], self._addr[1], a.ctypes.data,
                                 F.ctypes.data, Mi.ctypes.data)
        return a, F, Mi

    def linearize_trajectory(self, X: np.ndarray, U: np.ndarray):
        N, n, T = 2 * self.n, self.n, np.shape(X)[0]
        X = np.ascontiguousarray(X, dtype=float)
        U = np.ascontiguousarray(U, dtype=float)
        c_backend.check_shapes("dyn_linearize_batch", X=(X, (T, N)), U=(U, (T, n)))
        A, a, B = np.empty((T, N, N)), np.empty((T, N)), np.empty((T, N, n))
        self.lib.dyn_linearize_batch(self.ctx_address, T, X.ctypes.data, U.ctypes.data,
                                     A.ctypes.data, a.ctypes.data, B.ctypes.data)
        return A, a, B

    def controller_rollout(self, x0: np.ndarray, o: np.ndarray, O: np.ndarray):
        T, N, n = np.shape(o)[0], 2 * self.n, self.n
        x0 = np.ascontiguousarray(x0, dtype=float)
        o = np.ascontiguousarray(o, dtype=float)
        O = np.ascontiguousarray(O, dtype=float)
        c_backend.check_shapes("dyn_controller_rollout", x0=(x0, (N,)), o=(o, (T, n)), O=(O, (T, n, N)))
        X, U = np.empty((T + 1, N)), np.empty((T, n))
        self.lib.dyn_controller_rollout(self.ctx_address, T, x0.ctypes.data, o.ctypes.data,
                                        O.ctypes.data, X.ctypes.data, U.ctypes.data)
        return X, U


class FastAnalyticDynamics(SemiImplicitEuler):
    """Drop-in for :class:`raico.plants.dynamics.AnalyticDynamics` on the compiled symbolic dynamics.

    Same contract and numbers: semi-implicit Euler with step ``dt``, controls are torques,
    ``qddot = M_r^-1 (u - h_r)``, ``d qddot/d(q, v) = -M_r^-1 dID_r/d(q, v)`` at
    ``a = qddot``, ``d qddot/du = M_r^-1``. ``linearize_trajectory`` (and the batched
    ``qddot_trajectory``, ``step_trajectory``) evaluate all time steps in one pass of numpy
    operations; single-point calls run the generated code on Python floats.
    Raises ``NotImplementedError`` for plants it does not compile (see
    :func:`raico.plants.codegen.derive.derive`).
    """

    _KERNEL_PREFIX = ""  # name prefix of the compiled step's library

    def __init__(self, robot, dt: float, code=None):
        """``code``: the dynamics code (default: generated from the plant's symbolic model)."""
        self.robot = robot
        self.dt = float(dt)
        self.n_q = robot.n_q
        self.n_x = 2 * robot.n_q
        self.n_u = robot.n_q
        self.P = np.asarray(robot.P, float)
        self._code = compiled_dynamics(robot) if code is None else code
        m = self._code.m
        if self.P.shape != (m, self.n_q):
            raise ValueError(f"P has shape {self.P.shape}, the plant has {m} positions")
        self._identity = m == self.n_q and np.array_equal(self.P, np.eye(m))
        self._c: _CompiledStep | None | Literal[False] = None   # built on first use; False: unavailable

    # -- the compiled twin ----------------------------------------------------------------------
    def _compiled(self) -> _CompiledStep | None:
        if self._c is None:
            try:
                self._c = _CompiledStep(self._code, self.n_q, self.dt, self.P, self._identity,
                                        self._KERNEL_PREFIX + getattr(self.robot, "name", "plant"))
            except (c_backend.CompileUnavailable, OSError):
                self._c = False
        return self._c or None

    def c_linearizer(self) -> tuple[int, int, object] | None:
        """``(address of dyn_linearize, address of its context, keep-alive)`` for compiled
        callers (the AICO sweep kernel), or ``None`` without the compiled route."""
        c = self._compiled()
        return None if c is None else (c.lin_address, c.ctx_address, c)

    def __getstate__(self):  # the ctypes handle does not pickle; rebuilt on first use
        d = dict(self.__dict__)
        d["_c"] = None
        return d

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
        c = self._compiled()
        if c is not None:
            return c.mh(np.concatenate([np.asarray(q, float), np.asarray(v, float)]))
        m, mm = self._code.m, self._code.m * self._code.m
        qp, vp = self._plant(np.asarray(q, float)), self._plant(np.asarray(v, float))
        out = self._code.sca["mh"]([*qp.tolist(), *vp.tolist()], [0.0] * (mm + m))
        return self._reduce_M(np.array(out[:mm]).reshape(m, m)), self._reduce_h(np.array(out[mm:]))

    def _derivatives_point(self, q, v, u):
        """``a (n,)``, ``dqddot/d(q, v) (n, 2n)``, ``M_r^-1 (n, n)``."""
        c = self._compiled()
        if c is not None:
            return c.derivatives(np.concatenate([np.asarray(q, float), np.asarray(v, float)]), u)
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

    def step(self, x, u):
        """One semi-implicit Euler step ``(n_x,)`` (compiled when available)."""
        c = self._compiled()
        if c is not None:
            return c.step(x, u)
        return super().step(x, u)

    def controller_rollout(self, x0: np.ndarray, o: np.ndarray, O: np.ndarray):
        """``X (T+1, n_x)``, ``U (T, n_u)`` of ``u_t = o_t + O_t x_t`` from ``x0`` (the same as
        :func:`raico.planning.problem.controller_rollout` on this model; compiled when available)."""
        c = self._compiled()
        if c is not None:
            return c.controller_rollout(x0, o, O)
        return stepped_rollout(self, x0, o, O)

    def linearize(self, x, u):
        x, u = np.asarray(x, float), np.asarray(u, float)
        c = self._compiled()
        if c is not None:
            return c.linearize(x, u)
        n = self.n_q
        a, F, Mr_inv = self._derivatives_point(x[:n], x[n:], u)
        return self._assemble(x, u, a, F, Mr_inv)

    def linearize_trajectory(self, X: np.ndarray, U: np.ndarray):
        """``(A (T, n_x, n_x), a (T, n_x), B (T, n_x, n_u))`` along ``X (T, n_x)``, ``U (T, n_u)``,
        every time step in the same numpy operations."""
        X, U = self._check_batch(X, U)
        c = self._compiled()
        if c is not None:
            return c.linearize_trajectory(X, U)
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


class _TreeCode:
    """The tree kernels (:mod:`raico.plants.codegen.rbd`) in the place of the generated code: the same
    three functions ``gen_mh``, ``gen_first``, ``gen_second`` for the C driver (C only)."""

    def __init__(self, kernels):
        self.kernels = kernels
        self.m = kernels.m
        self.n_carry = 2 * kernels.m
        from raico.plants.codegen.rbd import tree_source

        self.c_source = tree_source(kernels.tree, header=False)


class TreeAnalyticDynamics(FastAnalyticDynamics):
    """:class:`FastAnalyticDynamics` on the plant's kinematic tree instead of generated symbolic
    code: for plants too large for :mod:`raico.plants.codegen.derive` (the 26-joint Nao). ``M`` from
    the composite inertias, ``ID`` by Newton-Euler, ``dID/d(q, v)`` by its analytical derivatives
    (Carpentier and Mansard 2018), all in C (:mod:`raico.plants.codegen.rbd`, checked against Drake's
    AutoDiffXd when built), with the formulas of :class:`raico.plants.dynamics.AnalyticDynamics` on top
    (the driver of this module; ``M_r^-1`` from a Cholesky factor).
    Needs the compiled route: raises ``NotImplementedError`` without it.
    """

    _KERNEL_PREFIX = "tree_"

    def __init__(self, robot, dt: float):
        from raico.plants.codegen.rbd import tree_kernels

        super().__init__(robot, dt, code=_TreeCode(tree_kernels(robot)))
        if self._compiled() is None:
            raise NotImplementedError(f"{robot.name}: the tree route needs a C compiler")

    def qddot_trajectory(self, Q: np.ndarray, V: np.ndarray, U: np.ndarray) -> np.ndarray:
        return np.stack([self.qddot(q, v, u) for q, v, u in zip(Q, V, U)])

    def step_trajectory(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        X, U = self._check_batch(X, U)
        return np.stack([self.step(x, u) for x, u in zip(X, U)])


# Plants with more positions than this go to the kinematic-tree route first. The symbolic derivation
# grows quickly with the chain: on a first load (2-core machine) arm5 (5 joints) takes 12 s with its
# C build, biorob 4 s, the 6-joint UR5 10 s, and the 6-joint Kinova, the 7-joint xArm7 and Panda
# give up after 26-31 s (too large to compile), on every process since a failure is not cached;
# the tree kernels build in 2.5-3.5 s for all of them and load in 0.03 s from the disk cache. The
# built-in pendulum (1), arm5 and biorob (5) keep the symbolic route (the Nao, 26, took the tree
# route already).
SYMBOLIC_MAX_POSITIONS = 5


def make_fast_or_exact(robot, dt: float) -> FastAnalyticDynamics | AnalyticDynamics:
    """:class:`FastAnalyticDynamics` when the robot's plant has at most
    ``SYMBOLIC_MAX_POSITIONS`` positions and compiles symbolically; else the compiled
    kinematic-tree model :class:`TreeAnalyticDynamics` (the Nao, 6- and 7-joint arms); else the
    symbolic route for a larger plant (its numpy code runs without a C compiler); else
    ``AnalyticDynamics`` (AutoDiffXd)."""
    small = robot.plant.num_positions() <= SYMBOLIC_MAX_POSITIONS
    if small:
        try:
            return FastAnalyticDynamics(robot, dt)
        except NotImplementedError:
            pass
    try:
        return TreeAnalyticDynamics(robot, dt)
    except NotImplementedError as e:
        why = str(e)
    if not small:
        try:
            return FastAnalyticDynamics(robot, dt)
        except NotImplementedError:
            pass
    if getattr(robot, "spec", None) is not None:  # a model file's robot: say why it is slower (the built-in plants compile)
        import sys

        print(f"raico: note: {robot.name}: no compiled dynamics ({why}): Drake's own evaluation (AutoDiffXd) "
              "is used, slower", file=sys.stderr)
    return AnalyticDynamics(robot, dt)


class TreeGravityTorques(GravityTorques):
    """:class:`raico.plants.dynamics.GravityTorques` on the robot's compiled tree (:mod:`raico.plants.codegen.rbd`,
    checked against Drake when built): ``g(q) = P^T ID(P q, 0, 0)`` and ``dg/dq = P^T dID/dq P``, the
    inverse dynamics at rest and its analytical derivatives in one pass in C (Drake's gravity forces and
    AutoDiffXd Jacobian to rounding, tests/planning/test_task_messages.py); Drake's route for non-finite ``q``."""

    def __init__(self, robot, kernels):
        super().__init__(robot)
        self._k = kernels

    def value(self, q: np.ndarray) -> np.ndarray:
        """``g(q)`` alone: the inverse dynamics at rest, no derivatives (the same numbers as
        :meth:`value_and_jacobian`'s value)."""
        if not np.all(np.isfinite(q)):
            return super().value(q)
        return self.P.T @ self._k.gravity(self.P @ np.asarray(q, float), jacobian=False)[0]

    def value_and_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if not np.all(np.isfinite(q)):
            return super().value_and_jacobian(q)
        g, G = self._k.gravity(self.P @ np.asarray(q, float))
        return self.P.T @ g, self.P.T @ G @ self.P


def gravity_torques(robot) -> GravityTorques:
    """The robot's gravity-compensating torques: on its compiled tree where that builds
    (:class:`TreeGravityTorques`), else Drake's (:class:`raico.plants.dynamics.GravityTorques`, equal to rounding,
    slower) where the plant has no tree kernels (a joint or force element the generator does not handle,
    no C compiler). Any other error is a fault and is raised."""
    from raico.plants.codegen.rbd import tree_kernels

    try:
        return TreeGravityTorques(robot, tree_kernels(robot))
    except (NotImplementedError, c_backend.CompileUnavailable):
        return GravityTorques(robot)
