"""iLQG baseline (Tassa, Erez, Todorov 2012, "Synthesis and stabilization of complex
behaviors through online trajectory optimization").

- derivatives: dynamics ``A_t, B_t`` along the trajectory (``linearize_trajectory``),
  cost gradients and Gauss-Newton Hessians of the terms (``l_x, l_xx, l_u, l_uu``; the
  cross term ``l_ux`` is zero);
- backward pass with ``mu`` added to ``V_xx`` (state regularization):
  ``Q_uu = l_uu + B^T (V_xx + mu I) B``, ``Q_ux = B^T (V_xx + mu I) A``, gains
  ``k = -Q_uu^-1 Q_u``, ``K = -Q_uu^-1 Q_ux``; a non-positive-definite ``Q_uu``
  increases ``mu`` and restarts the pass;
- Levenberg-Marquardt schedule: increase ``Delta = max(Delta_0, Delta Delta_0)``,
  ``mu = max(mu_min, mu Delta)``; decrease ``Delta = min(1/Delta_0, Delta/Delta_0)``,
  ``mu = mu Delta`` (0 if that falls below ``mu_min``);
- backtracking line search over ``step_sizes`` on the feed-forward term only,
  ``u = u_bar + step_size k + K (x - x_bar)``; accept when actual / expected reduction > 0;
- stop: relative cost reduction of an accepted step < ``tol_rel`` (converged; the test
  ``cost_decrease_below`` of ``raico.planning.driver``, which runs the iterations), gradient
  ``mean_t max_i |k_ti| / (|u_ti| + 1) < tol_grad`` with ``mu < 1e-5`` (converged), or
  ``mu > mu_max`` (status ``"max-iterations"``: no descent step could be found); the last
  two are the solver's own stop reasons (``_ILQGStep``).

Control limits enter as the ``ControlLimit`` penalty term (no clamping / box QP).
Initial controls are zero.
"""

from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass, field

import numpy as np

from raico.planning.driver import Iterate, Status, Step, Stop, cost_decrease_below, drive
from raico.planning.problem import (
    Callback,
    IterationRecord,
    OptionsBase,
    Problem,
    Result,
    check_range,
    single_threaded_blas,
)
from raico.plants.codegen import c_backend
from raico.plants.codegen.c_backend import check_shapes
from raico.plants.dynamics import rollout
from raico.plants.lazy import LazyModule

lapack = LazyModule("scipy.linalg.lapack")  # imported at first use


def _default_step_sizes() -> tuple[float, ...]:
    return tuple(float(a) for a in 10.0 ** np.linspace(0.0, -3.0, 11))


@dataclass(frozen=True)
class ILQGOptions(OptionsBase):
    """Options of iLQG (frozen; ``from_dict`` rejects unknown keys).

    Attributes:
        iterations: maximum number of iterations (>= 1).
        mu0: initial regularization ``mu`` (>= 0).
        delta0: ``Delta_0`` of the Levenberg-Marquardt schedule (> 1).
        mu_min, mu_max: regularization limits.
        step_sizes: line-search step sizes, tried in order (each in (0, 1]).
        tol_rel: converged when an accepted step lowers the cost by less than this, relative.
        tol_grad: converged when the normalized feed-forward gradient is below this.
        divergence_factor: diverged when the cost exceeds this times the initial cost.
    """

    iterations: int = 100
    mu0: float = 1.0
    delta0: float = 2.0
    mu_min: float = 1e-6
    mu_max: float = 1e10
    step_sizes: tuple = field(default_factory=_default_step_sizes)
    tol_rel: float = 1e-7
    tol_grad: float = 1e-4
    divergence_factor: float = 1e6

    def validate(self) -> None:
        check_range("iterations", self.iterations, lo=1, integer=True)
        check_range("mu0", self.mu0, lo=0.0)
        check_range("delta0", self.delta0, lo=1.0, lo_open=True)
        check_range("mu_min", self.mu_min, lo=0.0, lo_open=True)
        check_range("mu_max", self.mu_max, lo=self.mu_min, lo_open=True)
        check_range("tol_rel", self.tol_rel, lo=0.0)
        check_range("tol_grad", self.tol_grad, lo=0.0)
        check_range("divergence_factor", self.divergence_factor, lo=1.0, lo_open=True)
        step_sizes = tuple(float(a) for a in np.atleast_1d(np.asarray(self.step_sizes, dtype=float)))
        if not step_sizes or any(not (0.0 < a <= 1.0) for a in step_sizes):
            raise ValueError(f"option step_sizes must be a non-empty list in (0, 1], got {step_sizes}")
        object.__setattr__(self, "step_sizes", step_sizes)


class NotPD(Exception):
    """Q_uu was not positive definite at some step."""


# The compiled backward pass is used up to this state dimension: its plain loops beat numpy's per-call
# overhead on the arms (T = 1000, n_x = 10: 4 ms against 56 ms a pass) but lose to BLAS on the Nao
# (n_x = 50: 37 ms against 14 ms); measured crossover near n_x = 30 (one run, this 2-core machine).
COMPILED_MAX_N = 24


#: The compiled backward pass (``ilqg_backward.c``), or ``None`` (``RAICO_NO_C``, no ``gcc``); a failed build raises.
c_backward_lib = c_backend.CompiledLibrary("ilqg_backward", lambda: c_backend.c_source(__file__, "ilqg_backward.c"), {
    "ilqg_backward": ([ctypes.c_long] * 3 + [ctypes.c_void_p] * 6 + [ctypes.c_double] + [ctypes.c_void_p] * 3,
                      ctypes.c_int)})


def lq_backward(A, B, lx, lxx, lu, luu, mu: float, *, compiled: bool = True):
    """Backward pass. Shapes: ``A (T,n,n)``, ``B (T,n,m)``, ``lx (T+1,n)``, ``lxx (T+1,n,n)``,
    ``lu (T,m)``, ``luu (T,m,m)``. Returns ``k (T,m)``, ``K (T,m,n)``, ``dV (2,)``; compiled
    (``ilqg_backward.c``, the same formulas, equal to rounding) where a C compiler is available."""
    if np.ndim(B) != 3 or min(np.shape(B)) < 1:
        raise ValueError(f"ilqg backward pass: B must have shape (T, n, m) with T, n, m >= 1, got {np.shape(B)}")
    T, n, m = B.shape
    check_shapes("ilqg backward pass", A=(A, (T, n, n)), lx=(lx, (T + 1, n)), lxx=(lxx, (T + 1, n, n)),
                 lu=(lu, (T, m)), luu=(luu, (T, m, m)))
    lib = c_backward_lib() if compiled and n <= COMPILED_MAX_N else None
    if lib is not None:
        arrs = [np.ascontiguousarray(z, dtype=float) for z in (A, B, lx, lxx, lu, luu)]
        k, K, dV = np.empty((T, m)), np.empty((T, m, n)), np.empty(2)
        rc = lib.ilqg_backward(T, n, m, *(z.ctypes.data for z in arrs), float(mu), k.ctypes.data, K.ctypes.data,
                               dV.ctypes.data)
        if rc < 0:
            raise MemoryError(f"ilqg_backward: no work buffer for n = {n}, m = {m}")
        if rc > 0:
            raise NotPD
        return k, K, dV
    k = np.zeros((T, m))
    K = np.zeros((T, m, n))
    dV = np.zeros(2)
    Vx, Vxx = lx[T].copy(), lxx[T].copy()
    for t in range(T - 1, -1, -1):
        At, Bt = A[t], B[t]
        Qx = lx[t] + At.T @ Vx
        Qu = lu[t] + Bt.T @ Vx
        VA = Vxx @ At
        Qxx = lxx[t] + At.T @ VA
        BtV = Bt.T @ Vxx
        Quu = luu[t] + BtV @ Bt
        Qux = BtV @ At
        BtVr = BtV + mu * Bt.T if mu else BtV
        QuuF = luu[t] + BtVr @ Bt
        Qux_r = Qux + mu * Bt.T @ At if mu else Qux
        L, info = lapack.dpotrf(0.5 * (QuuF + QuuF.T), lower=1)
        if info != 0 or not np.all(np.isfinite(L)):
            raise NotPD
        rhs = np.empty((m, n + 1))
        rhs[:, 0] = Qu
        rhs[:, 1:] = Qux_r
        sol, info = lapack.dpotrs(L, rhs, lower=1)
        kt, Kt = -sol[:, 0], -sol[:, 1:]
        k[t], K[t] = kt, Kt
        dV += (kt @ Qu, 0.5 * kt @ Quu @ kt)
        KtQuu = Kt.T @ Quu
        Vx = Qx + KtQuu @ kt + Kt.T @ Qu + Qux.T @ kt
        Vxx = Qxx + KtQuu @ Kt + Kt.T @ Qux + Qux.T @ Kt
        Vxx = 0.5 * (Vxx + Vxx.T)
    return k, K, dV


def _forward(problem: Problem, X, U, k, K, step_size: float):
    """Rollout of ``u = U + step_size k + K (x - X)``: ``X (T+1, n)``, ``U (T, m)``, cost.

    Written as ``u_t = o_t + K_t x_t`` with ``o_t = U_t + step_size k_t - K_t X_t`` and rolled out by
    ``Problem.controller_rollout`` (the model's compiled loop where it has one)."""
    o = U + step_size * k - np.einsum("tij,tj->ti", K, X[:-1])
    try:   # a model may raise on the exploding states of a bad step
        with np.errstate(all="ignore"):
            Xn, Un = problem.controller_rollout(o, K)
            if not (np.all(np.isfinite(Xn)) and np.all(np.isfinite(Un))):
                return Xn, Un, math.inf
            return Xn, Un, problem.cost(Xn, Un)
    except (ArithmeticError, ValueError, RuntimeError):
        return np.full(X.shape, np.nan), np.full(U.shape, np.nan), math.inf


class _LM:
    """Levenberg-Marquardt schedule of ``mu`` (Tassa et al. 2012, Sec. II-F)."""

    def __init__(self, o: ILQGOptions):
        self.o, self.mu, self.delta = o, float(o.mu0), 1.0

    def increase(self) -> None:
        o = self.o
        self.delta = max(o.delta0, self.delta * o.delta0)
        self.mu = max(o.mu_min, self.mu * self.delta)

    def decrease(self) -> None:
        o = self.o
        self.delta = min(1.0 / o.delta0, self.delta / o.delta0)
        self.mu = self.mu * self.delta if self.mu * self.delta > o.mu_min else 0.0


def ilqg(problem: Problem, options: ILQGOptions | None = None, *,
         U_init: np.ndarray | None = None, callback: Callback | None = None) -> Result:
    """Plan with iLQG from zero controls (or ``U_init (T, n_u)``).

    Returns a ``Result``; the controller is ``u_t = U_t + K_t (x_t - X_t)``, i.e.
    ``o_t = U_t - K_t X_t``, ``O_t = K_t``, with gains from a backward pass at the final
    trajectory. A non-finite initial rollout ends with status ``"diverged"``.
    """
    with single_threaded_blas():
        return _ilqg(problem, options or ILQGOptions(), U_init, callback)


def _ilqg(problem: Problem, opts: ILQGOptions, U_init, callback) -> Result:
    T, n, m = problem.T, problem.n_x, problem.n_u
    U = np.zeros((T, m)) if U_init is None else np.array(U_init, dtype=float)
    if U.shape != (T, m):
        raise ValueError(f"U_init has shape {U.shape}, expected {(T, m)}")
    try:
        with np.errstate(all="ignore"):
            X = rollout(problem.dynamics, problem.x0, U)
        J = problem.cost(X, U)
    except (ArithmeticError, ValueError, RuntimeError):
        X, J = np.full((T + 1, n), np.nan), math.inf
    if not math.isfinite(J):
        history = [IterationRecord(1, math.inf, 0.0, 0.0, 0.0, float(opts.mu0))]
        return _result(X, U, np.zeros((T, m, n)), Status.DIVERGED, history,
                       "initial rollout is not finite", J, X)
    st = _ILQGStep(problem, opts, J, np.zeros((T, m, n)))
    out = drive(st, Iterate(X, U), opts, initial_cost=J, reference_cost=J,
                test=cost_decrease_below, callback=callback)
    X0 = X
    X, U, K = out.last_finite.X, out.last_finite.U, st.K
    if not st.gains_at_final and out.status is not Status.DIVERGED:
        K = _final_gains(problem, X, U, st.lm.mu, K)
    return _result(X, U, K, out.status, out.history, out.message, J, X0)


class _ILQGStep:
    """One iLQG iteration (a ``driver.StepFn``): backward pass at the current trajectory
    (``mu`` raised until ``Q_uu`` is positive definite), gradient test, line search.

    State: the ``mu`` schedule ``lm``, the cost ``J`` of the current trajectory, its
    derivatives (``None`` once it moved), the last gains ``K (T, n_u, n_x)`` and whether
    they were computed unregularized at the current trajectory (``gains_at_final``).
    Stop reasons: ``mu > mu_max`` (max-iterations), gradient below ``tol_grad`` with
    ``mu < 1e-5`` (converged), a numerical failure (diverged).
    """

    def __init__(self, problem: Problem, opts: ILQGOptions, J: float, K: np.ndarray):
        self.problem, self.o, self.J, self.K = problem, opts, J, K
        self.lm = _LM(opts)
        self.derivs = None
        self.gains_at_final = False

    def __call__(self, it: int, cur: Iterate) -> Step:
        o, lm, J = self.o, self.lm, self.J
        try:
            if self.derivs is None:
                self.derivs = _derivatives(self.problem, cur.X, cur.U)
            k, K_new, dV, stuck = _regularized_backward(self.derivs, lm)
        except (ArithmeticError, np.linalg.LinAlgError) as e:
            return Step(cur, math.inf, mu=lm.mu, moved=False,
                        stop=Stop(Status.DIVERGED, f"{type(e).__name__}: {e}"))
        if stuck:
            return Step(cur, J, mu=lm.mu, moved=False, stop=self._mu_limit())
        self.K, self.gains_at_final = K_new, lm.mu == 0.0
        gnorm = float(np.mean(np.max(np.abs(k) / (np.abs(cur.U) + 1.0), axis=1)))
        if gnorm < o.tol_grad and lm.mu < 1e-5:
            lm.decrease()
            return Step(cur, J, mu=lm.mu, moved=False,
                        stop=Stop(Status.CONVERGED, f"gradient {gnorm:.2e} below tol_grad"))
        accepted, Xn, Un, Jn, step_size = _line_search(self.problem, cur.X, cur.U, J, k, K_new,
                                                   dV, o.step_sizes)
        if not accepted:
            lm.increase()
            stop = self._mu_limit() if lm.mu > o.mu_max else None
            return Step(cur, J, mu=lm.mu, moved=False, stop=stop)
        lm.decrease()
        self.J, self.derivs, self.gains_at_final = Jn, None, False
        return Step(Iterate(Xn, Un), Jn, step=step_size, mu=lm.mu)

    def _mu_limit(self) -> Stop:
        return Stop(Status.MAX_ITERATIONS, f"mu > mu_max={self.o.mu_max:g}: no descent step")


def _derivatives(problem: Problem, X: np.ndarray, U: np.ndarray):
    """``(A, B, l_x, l_xx, l_u, l_uu)`` along the trajectory (shapes as in ``lq_backward``)."""
    A, _, B = problem.dynamics.linearize_trajectory(X[:-1], U)
    problem.set_nominal(X, U)
    lx, lxx = problem.state_derivatives(X)
    lu, luu = problem.control_derivatives(U)
    out = (np.asarray(A, float), np.asarray(B, float), lx, lxx, lu, luu)
    if not all(np.all(np.isfinite(z)) for z in out):
        raise FloatingPointError("non-finite derivatives")
    return out


def _regularized_backward(derivs, lm: _LM):
    """Backward pass, raising ``mu`` until ``Q_uu`` is positive definite.

    Returns ``(k, K, dV, stop)``; ``stop`` is True when ``mu`` exceeded ``mu_max``.
    """
    while True:
        try:
            A, B, lx, lxx, lu, luu = derivs
            k, K, dV = lq_backward(A, B, lx, lxx, lu, luu, lm.mu)
            return k, K, dV, False
        except NotPD:
            lm.increase()
            if lm.mu > lm.o.mu_max:
                return None, None, None, True


def _line_search(problem, X, U, J, k, K, dV, step_sizes):
    """Backtracking over ``step_sizes``; returns ``(accepted, X, U, J, step_size)``.

    A step is accepted when actual / expected reduction > 0. When the expected reduction
    is below the cost's rounding level (``64 eps |J|``) the ratio is noise: the step is
    then accepted unless it raises the cost beyond that level.
    """
    floor = 64.0 * np.finfo(float).eps * max(abs(J), np.finfo(float).tiny)
    for step_size in step_sizes:
        Xn, Un, Jn = _forward(problem, X, U, k, K, step_size)
        if not math.isfinite(Jn):
            continue
        expected = -step_size * (dV[0] + step_size * dV[1])
        actual = J - Jn
        if expected <= floor:
            if actual >= -floor:
                return True, Xn, Un, Jn, step_size
            continue
        if actual / expected > 0:
            return True, Xn, Un, Jn, step_size
    return False, X, U, J, 0.0


def _final_gains(problem, X, U, mu, K_fallback):
    """Feedback gains from one backward pass at the final trajectory, unregularized
    (``mu = 0``) when ``Q_uu`` allows it, else with the current ``mu``."""
    try:
        derivs = _derivatives(problem, X, U)
    except (ArithmeticError, np.linalg.LinAlgError):
        return K_fallback
    A, B, lx, lxx, lu, luu = derivs
    for m in (0.0, mu):
        try:
            return lq_backward(A, B, lx, lxx, lu, luu, m)[1]
        except NotPD:
            continue
    return K_fallback


def _result(X, U, K, status: Status, history, message, initial_cost, X_initial=None) -> Result:
    o = U - np.einsum("tij,tj->ti", K, X[:-1])
    return Result(X=X, U=U, o=o, O=K, status=status, history=history,
                  iterations=len(history), message=message, initial_cost=initial_cost,
                  solver="ilqg", X_initial=X_initial)
