"""AICO and R-AICO: approximate inference control with Gaussian messages (SPEC §6).

One implementation: R-AICO is AICO with ``alpha > 0`` (thesis §3.5, Algorithm 1).

Model per iteration (shapes: ``n = n_x``, ``m = n_u``):

- dynamics linearized ``x_{t+1} ~ A_t x_t + a_t + B_t u_t`` with process noise ``Q = q I``;
- task messages ``N[x_t | r_t, R_t]`` (cost ``1/2 x^T R x - r^T x``), plus the R-AICO term
  ``alpha ||x_t - x_t^[n-1]||^2`` (``R += 2 alpha I``, ``r += 2 alpha x_t^[n-1]``) at every
  step, ``x^[n-1]`` being the trajectory the iteration started from;
- control prior ``N[u_t | h_t, H_t]`` from the control terms at the current controls, so
  with controls marginalized ``x_{t+1} | x_t ~ N(A x + a + B H^-1 h, Qbar)`` with
  ``Qbar = Q + B H^-1 B^T``.

Messages (SPEC §6): forward (moment form ``s_t, S_t``; stored as precision ``S_t^-1`` and
``S_t^-1 s_t``), backward in canonical form ``V_t^-1, V_t^-1 v_t`` (no inverse of ``A``,
``V_T^-1 = 0``), belief ``B_t = S_t^-1 + V_t^-1 + R_t``, ``b_t = B_t^-1 (...)``; start
``S_0 = start_variance I`` around ``x0``. With ``P' = V_{t+1}^-1 + R_{t+1}`` (precision)
the backward step uses ``V* = (Q + P'^-1)^-1 = (I + q P')^-1 P'`` and
``M = B^T V* B + H``; by Woodbury ``(P'^-1 + Qbar)^-1 = V* - V* B M^-1 B^T V*``, so the
message and the controller (thesis eq. 3.6, appendix D)
``o_t = M^-1 (B^T V* (m' - a_t) + h_t)``, ``O_t = -M^-1 B^T V* A_t`` share one
factorization and never invert a possibly singular ``P'``.

Algorithm 1: the dynamics and the task messages are linearized along the whole trajectory
at once at the start of an iteration; during the forward (t = 1..T) and backward
(t = T-1..0) sweeps a time step is relinearized at its belief and repeated while
``||b_t - x_t|| > theta`` (at most ``max_repeats`` times; the point moves by
``belief_rate (b_t - x_t)``, plain AICO's learning rate). After the sweeps the controller
is rolled out on the true planning dynamics (``dynamics.step``) to give the next
trajectory and the reported cost.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

from plants.dynamics import rollout
from stages.plan.problem import (
    Callback,
    IterationRecord,
    OptionsBase,
    Problem,
    Result,
    check_range,
    controller_rollout,
    is_diverged,
    single_threaded_blas,
)


@dataclass(frozen=True)
class AICOOptions(OptionsBase):
    """Options of AICO / R-AICO (frozen; ``from_dict`` rejects unknown keys).

    Attributes:
        iterations: maximum number of iterations (>= 1).
        alpha: R-AICO regularization ``alpha^[1]`` (>= 0; 0 is plain AICO), per (state unit)^2.
        gamma: ``alpha^[n] = alpha^[n-1] gamma`` (> 0).
        theta: relinearization threshold on ``||b_t - x_t||`` (state units; ``inf``: never
            relinearize within the sweeps; then the forward sweep is skipped, as it cannot
            change the controller, and run once at the end for the beliefs).
        max_repeats: cap on the repeats of one time step within a sweep (>= 0); when it is
            reached the step keeps its last linearization.
        belief_rate: plain AICO's learning rate on the belief (state) update: a repeat moves
            the linearization point ``x_t += rate (b_t - x_t)``, in (0, 1].
        process_noise: ``q`` in ``Q = q I`` (> 0).
        start_variance: ``S_0 = start_variance I`` (tight prior around ``x0``, > 0).
        tol: converged when the relative cost change of two iterations is below ``tol``.
        divergence_factor: diverged when the cost exceeds this times the initial cost.
    """

    iterations: int = 100
    alpha: float = 0.0
    gamma: float = 1.0
    theta: float = 0.1
    max_repeats: int = 3
    belief_rate: float = 1.0
    process_noise: float = 1e-9
    start_variance: float = 1e-10
    tol: float = 1e-9
    divergence_factor: float = 1e6

    def validate(self) -> None:
        check_range("iterations", self.iterations, lo=1, integer=True)
        check_range("alpha", self.alpha, lo=0.0)
        check_range("gamma", self.gamma, lo=0.0, lo_open=True)
        check_range("theta", self.theta, lo=0.0, lo_open=True)
        check_range("max_repeats", self.max_repeats, lo=0, integer=True)
        check_range("belief_rate", self.belief_rate, lo=0.0, hi=1.0, lo_open=True)
        check_range("process_noise", self.process_noise, lo=0.0, lo_open=True)
        check_range("start_variance", self.start_variance, lo=0.0, lo_open=True)
        check_range("tol", self.tol, lo=0.0)
        check_range("divergence_factor", self.divergence_factor, lo=1.0, lo_open=True)
        if not math.isfinite(self.alpha) or not math.isfinite(self.gamma):
            raise ValueError("options alpha and gamma must be finite")


class NumericalError(RuntimeError):
    """A factorization failed or a message became non-finite."""


# -- small dense linear algebra with little call overhead ---------------------------------
def _chol(M: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of the symmetric positive-definite ``M``."""
    c, info = lapack.dpotrf(M, lower=1)
    if info != 0:
        raise NumericalError(f"Cholesky failed (info={info})")
    return c


def _tri_inv(L: np.ndarray) -> np.ndarray:
    """Inverse of a lower-triangular matrix."""
    Li, info = lapack.dtrtri(L, lower=1)
    if info != 0:
        raise NumericalError(f"triangular inverse failed (info={info})")
    return Li


def _solve_chol(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``M^-1 b`` from the lower Cholesky factor ``L`` of ``M``; ``b (k,)`` or ``(k, r)``."""
    x, info = lapack.dpotrs(L, b, lower=1)
    if info != 0:
        raise NumericalError(f"Cholesky solve failed (info={info})")
    return x


def _sym(M: np.ndarray) -> np.ndarray:
    return 0.5 * (M + M.T)


def _is_constant(Z: np.ndarray) -> bool:
    """Whether the stacked array ``Z (T, ...)`` holds the same entry at every step."""
    return bool(np.array_equal(Z, np.broadcast_to(Z[0], Z.shape)))


class _Sweeps:
    """Message state and per-step updates of one AICO run (arrays indexed by time).

    Layout (to keep the per-step work in few dense operations): a message and its
    linear term share one array, ``[P | p]`` of shape ``(n, n+1)``:
    ``SA[t] = [S_t^-1 | S_t^-1 s_t]`` (forward), ``VA[t] = [V_t^-1 | V_t^-1 v_t]``
    (backward), ``RA[t] = [R_t | r_t]`` (task); ``C[t] = [[B_t, A_t, -a_t], [0, 0, 1]]``
    ``(n+1, m+n+1)``, so that ``[V* | V* m'] C[t] = [V* B | V* A | V*(m' - a)]``;
    ``a_eff[t] = a_t + B_t H_t^-1 h_t`` is the mean drift under the control prior.
    """

    def __init__(self, problem: Problem, opts: AICOOptions):
        self.p = problem
        self.o = opts
        T, n, m = problem.T, problem.n_x, problem.n_u
        self.T, self.n, self.m = T, n, m
        self.q = opts.process_noise
        self.I = np.eye(n)
        # relinearization within the sweeps needs the beliefs, hence the forward messages;
        # without it (theta = inf) the forward messages cannot change the controller.
        self.relocate = math.isfinite(opts.theta) and opts.max_repeats > 0
        self.SA = np.zeros((T + 1, n, n + 1))
        self.SA[0, :, :n] = self.I / opts.start_variance
        self.SA[0, :, n] = problem.x0 / opts.start_variance
        self.VA = np.zeros((T + 1, n, n + 1))                  # V_T^-1 = 0 (end)
        # per-iteration linearization, buffers reused across iterations
        self.C = np.zeros((T, n + 1, m + n + 1))
        self.C[:, n, m + n] = 1.0
        self.RA = np.empty((T + 1, n, n + 1))
        self._lx = np.empty((T + 1, n))
        self.Qbar = np.empty((T, n, n))
        self.b = np.full((T + 1, n), np.nan)
        self.o_ = np.zeros((T, m))
        self.O_ = np.zeros((T, m, n))
        self.repeats = 0

    # -- linearization -----------------------------------------------------------------
    def linearize_all(self, X: np.ndarray, U: np.ndarray, Xprev: np.ndarray,
                      alpha: float) -> None:
        """Dynamics, control and task messages along ``X (T+1, n)``, ``U (T, m)`` at once."""
        p, T, n, m = self.p, self.T, self.n, self.m
        self.X = X.copy()
        self.U = U
        self.Xprev = Xprev
        self.alpha = alpha
        A, a, B = p.dynamics.linearize_trajectory(X[:-1], U)
        self.H, self.h = p.quadratize_controls(U)
        C = self.C
        C[:, :n, :m] = B
        C[:, :n, m:m + n] = A
        C[:, :n, m + n] = a
        np.negative(C[:, :n, m + n], out=C[:, :n, m + n])
        self._check_finite(C, self.H, self.h)
        self._control_marginals()
        RA, lx = self.RA, self._lx
        R = RA[:, :, :n]
        p.state_derivatives(X, out=(lx, R))                    # R = l_xx
        np.einsum("kij,kj->ki", R, X, out=RA[:, :, n])
        RA[:, :, n] -= lx                                       # r = l_xx x - l_x
        if alpha:
            diag = RA.reshape(T + 1, n * (n + 1))[:, ::n + 2]  # R[:, i, i] (a view)
            diag += 2.0 * alpha
            RA[:, :, n] += 2.0 * alpha * Xprev
        self._check_finite(RA)

    def _control_marginals(self) -> None:
        """``Qbar_t = q I + B_t H_t^-1 B_t^T`` and ``a_eff_t = a_t + B_t H_t^-1 h_t`` for all t."""
        n, m, C = self.n, self.m, self.C
        B = C[:, :n, :m]
        const_H = _is_constant(self.H)
        try:
            if const_H:
                np.linalg.cholesky(self.H[0])
                self.Hinv = np.broadcast_to(np.linalg.inv(self.H[0]), self.H.shape)
            else:
                np.linalg.cholesky(self.H)
                self.Hinv = np.linalg.inv(self.H)
        except np.linalg.LinAlgError as e:
            raise NumericalError("control Hessian H_t is not positive definite") from e
        if const_H and _is_constant(B):
            BHi = B[0] @ self.Hinv[0]
            self.Qbar[:] = BHi @ B[0].T + self.q * self.I
            self.a_eff = self.h @ BHi.T - C[:, :n, m + n]
        else:
            BHi = B @ self.Hinv
            np.matmul(BHi, np.swapaxes(B, -1, -2), out=self.Qbar)
            self.Qbar += self.q * self.I
            self.a_eff = np.einsum("tij,tj->ti", BHi, self.h) - C[:, :n, m + n]

    def relinearize(self, t: int) -> None:
        """Relinearize step ``t`` (dynamics if ``t < T``, task message) at ``self.X[t]``."""
        p, x, n, m = self.p, self.X[t], self.n, self.m
        if t < self.T:
            A, a, B = p.dynamics.linearize(x, self.U[t])
            self._check_finite(A, a, B)
            Ct = self.C[t]
            Ct[:n, :m], Ct[:n, m:m + n], Ct[:n, m + n] = B, A, -a
            BHi = B @ self.Hinv[t]
            self.Qbar[t] = BHi @ B.T + self.q * self.I
            self.a_eff[t] = a + BHi @ self.h[t]
        R, r = p.quadratize_states(x[None, :], np.array([t]))
        self._check_finite(R, r)
        self.RA[t, :, :n] = R[0] + 2.0 * self.alpha * self.I
        self.RA[t, :, n] = r[0] + 2.0 * self.alpha * self.Xprev[t]
        self.repeats += 1

    @staticmethod
    def _check_finite(*arrs: np.ndarray) -> None:
        """Raise ``NumericalError`` on NaN or inf (or sums overflowing to them)."""
        for z in arrs:
            if not math.isfinite(float(np.sum(z))):
                raise NumericalError("non-finite linearization or task message")

    # -- messages -----------------------------------------------------------------------
    def forward(self, t: int) -> None:
        """Forward message ``[S_t^-1 | S_t^-1 s_t]`` at ``t >= 1`` from step ``t-1``:
        ``P = S^-1 + R``, ``s_t = A P^-1 (S^-1 s + r) + a_eff``, ``S_t = A P^-1 A^T + Qbar``."""
        n, m = self.n, self.m
        Ct = self.C[t - 1]
        Pa = self.SA[t - 1] + self.RA[t - 1]
        L = _chol(Pa[:, :n])
        rhs = np.empty((n, n + 1))
        rhs[:, :n] = Ct[:n, m:m + n].T
        rhs[:, n] = Pa[:, n]
        Y, info = lapack.dtrtrs(L, rhs, lower=1)              # L^-1 [A^T | p]
        if info != 0:
            raise NumericalError(f"triangular solve failed (info={info})")
        W = Y[:, :n]                                           # A P^-1 A^T = W^T W
        Ci = _tri_inv(_chol(W.T @ W + self.Qbar[t - 1]))      # S_t = C C^T
        Sinv = Ci.T @ Ci
        out = self.SA[t]
        out[:, :n] = Sinv
        out[:, n] = Sinv @ (W.T @ Y[:, n] + self.a_eff[t - 1])

    def _vstar(self, Pa: np.ndarray) -> np.ndarray:
        """``[V* | V* m']`` from ``Pa = [P' | p']``: ``V* = (q I + P'^-1)^-1 = (I + q P')^-1 P'``.

        With ``s = q ||[P' | p']||_F >= q lambda_max(P')``: the Neumann series
        ``sum_k (-q P')^k [P' | p']`` truncated after ``K <= 3`` terms when
        ``s^(K+1) <= 1e-16`` (relative truncation error), else a Cholesky factorization of
        the well-conditioned ``I + q P'``.
        """
        q, n = self.q, self.n
        flat = Pa.reshape(-1)
        s = q * math.sqrt(float(flat @ flat))
        P = Pa[:, :n]
        if s <= 1e-4:
            K = 1 if s <= 1e-8 else (2 if s <= 10 ** (-16 / 3) else 3)
            term, out = Pa, Pa
            for _ in range(K):
                term = (-q) * (P @ term)
                out = out + term
            return out
        Ei = _tri_inv(_chol(self.I + q * P))
        return Ei.T @ (Ei @ Pa)

    def backward(self, t: int) -> None:
        """Backward message ``[V_t^-1 | V_t^-1 v_t]`` and the controller ``o_t, O_t``
        (``t <= T-1``), with ``P' = V_{t+1}^-1 + R_{t+1}`` and ``M = B^T V* B + H``.

        By Woodbury ``(P'^-1 + Qbar)^-1 = V* - V* B M^-1 B^T V*``, hence
        ``V_t^-1 = A^T V* A - (B^T V* A)^T M^-1 B^T V* A = A^T V* A + (B^T V* A)^T O_t`` and
        ``V_t^-1 v_t = A^T V*(m' - a_eff) - ... = A^T V*(m' - a) - (B^T V* A)^T o_t`` (the
        ``h`` terms of ``a_eff`` and of ``o_t`` cancel exactly).
        """
        n, m = self.n, self.m
        Ct = self.C[t]
        G = self._vstar(self.VA[t + 1] + self.RA[t + 1]) @ Ct   # [V*B | V*A | V*(m'-a)]
        F = Ct[:n, :m + n].T @ G                                # [B A]^T G, (m+n, m+n+1)
        LM = _chol(F[:m, :m] + self.H[t])
        rhs = F[:m, m:]                                         # [B^T V* A | B^T V*(m'-a)]
        rhs[:, n] += self.h[t]
        Zm = _solve_chol(LM, rhs)                               # [-O_t | o_t]
        self.O_[t] = -Zm[:, :n]
        self.o_[t] = Zm[:, n]
        Y = F[m:, m:] - F[:m, m:m + n].T @ Zm                   # [V_t^-1 | V_t^-1 v_t]
        out = self.VA[t]
        out[:, :n] = 0.5 * (Y[:, :n] + Y[:, :n].T)
        out[:, n] = Y[:, n]

    def belief(self, t: int) -> np.ndarray:
        """Belief mean ``b_t (n,)`` from ``B_t = S_t^-1 + V_t^-1 + R_t``."""
        n = self.n
        Ba = self.SA[t] + self.VA[t] + self.RA[t]
        b = _solve_chol(_chol(Ba[:, :n]), Ba[:, n])
        self.b[t] = b
        return b

    def settle(self, t: int, redo=None) -> None:
        """Algorithm 1 at step ``t`` (message already updated): while the belief is more than
        ``theta`` from the linearization point, move the point towards it, relinearize step
        ``t``, redo the message ``redo(t)`` if it depends on step ``t``, and repeat."""
        o = self.o
        x = self.X[t]
        for _ in range(o.max_repeats):
            d = self.belief(t) - x
            if not math.sqrt(float(d @ d)) > o.theta:
                return
            x += o.belief_rate * d
            self.relinearize(t)
            if redo is not None:
                redo(t)
        self.belief(t)

    def sweep(self) -> None:
        """One forward (t = 1..T) and one backward (t = T-1..0) sweep with relinearization;
        without relinearization (``theta = inf``) only the backward sweep."""
        if self.relocate:
            for t in range(1, self.T + 1):
                self.forward(t)
                self.settle(t)        # the forward message at t does not depend on step t
            for t in range(self.T - 1, -1, -1):
                self.backward(t)
                self.settle(t, self.backward)
        else:
            for t in range(self.T - 1, -1, -1):
                self.backward(t)
        if not (np.all(np.isfinite(self.o_)) and np.all(np.isfinite(self.O_))):
            raise NumericalError("non-finite controller")

    def beliefs(self) -> np.ndarray:
        """Belief means ``(T+1, n)`` at the current linearization (``theta = inf`` mode:
        computed once, with a forward sweep and no relinearization)."""
        if not self.relocate:
            for t in range(1, self.T + 1):
                self.forward(t)
            for t in range(self.T + 1):
                self.belief(t)
        return self.b.copy()


def aico(problem: Problem, options: AICOOptions | None = None, *,
         X_init: np.ndarray | None = None, U_init: np.ndarray | None = None,
         callback: Callback | None = None) -> Result:
    """Plan with AICO (``alpha = 0``) or R-AICO (``alpha > 0``).

    Args:
        problem: the planning problem (needs a positive-definite control cost).
        options: ``AICOOptions`` (defaults if ``None``).
        X_init: initial trajectory ``(T+1, n_x)`` to linearize at (default: ``x0`` at every
            step, thesis §3.4; if only ``U_init`` is given, its rollout).
        U_init: initial controls ``(T, n_u)`` (default zeros).
        callback: called after each iteration with ``(record, X, U)``.

    Returns:
        ``Result``; a run whose cost becomes non-finite or explodes, or whose messages
        fail numerically, ends with status ``"diverged"`` (no exception).
    """
    with single_threaded_blas():
        return _aico(problem, options or AICOOptions(), X_init, U_init, callback)


def _aico(problem: Problem, opts: AICOOptions, X_init, U_init, callback) -> Result:
    T, n_u = problem.T, problem.n_u
    U = np.zeros((T, n_u)) if U_init is None else np.array(U_init, dtype=float)
    with np.errstate(all="ignore"):
        X0_roll = rollout(problem.dynamics, problem.x0, U)
    initial_cost = problem.cost(X0_roll, U)
    if U.shape != (T, n_u):
        raise ValueError(f"U_init has shape {U.shape}, expected {(T, n_u)}")
    if X_init is None:
        X = np.tile(problem.x0, (T + 1, 1)) if U_init is None else X0_roll
    else:
        X = np.array(X_init, dtype=float)
        if X.shape != (T + 1, problem.n_x) or not np.all(np.isfinite(X)):
            raise ValueError(f"X_init must be finite with shape {(T + 1, problem.n_x)}")
    _check_control_cost(problem)
    sw = _Sweeps(problem, opts)
    history: list[IterationRecord] = []
    best = (X, U, U.copy(), np.zeros((T, n_u, problem.n_x)))  # last finite (X, U, o, O)
    status, message = "max-iterations", f"reached {opts.iterations} iterations"
    alpha = float(opts.alpha)
    start = time.perf_counter()
    reference = initial_cost
    for it in range(1, opts.iterations + 1):
        t0 = time.perf_counter()
        sw.repeats = 0
        cost, err = math.inf, None
        try:
            with np.errstate(all="ignore"):
                sw.linearize_all(X, U, X, alpha)
                sw.sweep()
        except (NumericalError, ArithmeticError, np.linalg.LinAlgError) as e:
            err = f"{type(e).__name__}: {e}"
        else:
            try:   # a model may raise on the exploding states of a diverging rollout
                Xn, Un = controller_rollout(problem.dynamics, problem.x0, sw.o_, sw.O_)
                cost = problem.cost(Xn, Un)
            except (ArithmeticError, ValueError, RuntimeError) as e:
                err = f"rollout failed: {type(e).__name__}: {e}"
        now = time.perf_counter()
        rec = IterationRecord(it, cost, now - t0, now - start, alpha, 0.0, sw.repeats)
        history.append(rec)
        if it == 1 and not (math.isfinite(reference) and reference > 0):
            reference = cost
        if err is not None or is_diverged(cost, reference, opts.divergence_factor):
            status = "diverged"
            message = (f"iteration {it}: " + (err or f"cost {cost:.3g} not finite or above "
                       f"{opts.divergence_factor:g} x initial cost {reference:.3g}"))
            break
        X, U = Xn, Un
        best = (X, U, sw.o_.copy(), sw.O_.copy())
        if callback is not None:
            callback(rec, X, U)
        if it > 1 and abs(history[-2].cost - cost) <= opts.tol * max(abs(history[-2].cost),
                                                                     1e-300):
            status, message = "converged", f"relative cost change below tol={opts.tol:g}"
            break
        alpha *= opts.gamma
    X, U, o, O = best
    beliefs = None
    if status != "diverged":
        try:
            with np.errstate(all="ignore"):
                beliefs = sw.beliefs()
        except (NumericalError, ArithmeticError):
            beliefs = None
    return Result(X=X, U=U, o=o, O=O, status=status, history=history,
                  iterations=len(history), message=message, initial_cost=initial_cost,
                  beliefs=beliefs, solver="raico" if opts.alpha > 0 else "aico")


def _check_control_cost(problem: Problem) -> None:
    """AICO marginalizes the controls: their cost Hessian must be positive definite."""
    _, luu = problem.control_derivatives(np.zeros((1, problem.n_u)))
    if np.any(np.linalg.eigvalsh(luu[0]) <= 0):
        raise ValueError("AICO needs a positive-definite control cost (add a ControlCost "
                         "with weight > 0)")
