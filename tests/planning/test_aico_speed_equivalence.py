"""The optimized AICO / R-AICO sweeps equal a literal reference implementation.

``raico.planning.aico`` skips work that cannot change a result (relinearizing what does not
depend on the state, recomputing unchanged beliefs and backward messages, shared LTI
matrices), batches task-map evaluations and uses fused BLAS/LAPACK kernels. ``Reference``
below is Algorithm 1 written straight from the formulas, with dense ``np.linalg.solve``
and no shortcuts: it recomputes every message, belief and linearization. Both must give
the same trajectories, controllers, costs, beliefs and relinearization counts (up to
floating-point rounding) on small nonlinear problems.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from raico.planning.aico import AICOOptions, aico
from raico.planning.costs import ControlCost, ControlLimit, StateTarget, ViaPoint
from raico.planning.problem import Problem, controller_rollout
from raico.plants.dynamics import PseudoDynamics
from tests.tolerance import assert_close
from tests.toys import PlanarArm

pytestmark = [pytest.mark.compiled, pytest.mark.numerics]   # reaches a C kernel: run under the sanitizers too

N_Q, T, DT = 3, 40, 0.02


class CoupledPendulums:
    """Nonlinear test model: ``qddot_i = u_i - k sin(q_i + q_{i-1} / 2) - c v_i``, semi-implicit
    Euler (the time convention of ``raico.plants.dynamics``)."""

    def __init__(self, n_q: int, dt: float, k: float = 3.0, c: float = 0.5):
        self.n_q, self.n_x, self.n_u, self.dt, self.k, self.c = n_q, 2 * n_q, n_q, dt, k, c
        self.S = np.eye(n_q) + 0.5 * np.eye(n_q, k=-1)  # argument of the sine: S q

    def _qddot(self, q, v, u):
        return u - self.k * np.sin(self.S @ q) - self.c * v

    def step(self, x, u):
        n, dt = self.n_q, self.dt
        v1 = x[n:] + dt * self._qddot(x[:n], x[n:], u)
        return np.concatenate([x[:n] + dt * v1, v1])

    def linearize(self, x, u):
        n, dt = self.n_q, self.dt
        Fq = -self.k * np.cos(self.S @ x[:n])[:, None] * self.S
        dv = np.hstack([dt * Fq, (1.0 - dt * self.c) * np.eye(n)])     # dv'/dx
        A = np.vstack([np.hstack([np.eye(n), np.zeros((n, n))]) + dt * dv, dv])
        B = np.vstack([dt * dt * np.eye(n), dt * np.eye(n)])
        return A, self.step(x, u) - A @ x - B @ u, B

    def linearize_trajectory(self, X, U):
        parts = [self.linearize(x, u) for x, u in zip(X, U)]
        return tuple(np.stack([p[i] for p in parts]) for i in range(3))


def make_problem(dynamics: str = "pendulums", limits: bool = False) -> Problem:
    dyn = CoupledPendulums(N_Q, DT) if dynamics == "pendulums" else PseudoDynamics(N_Q, DT)
    x0 = np.concatenate([[0.3, 0.4, 0.2], np.zeros(N_Q)])
    arm = PlanarArm([0.5, 0.5, 0.5])
    state = [ViaPoint(arm, [0.2, 1.2], [T // 2], weight=1e4, name="via"),
             ViaPoint(arm, arm.value_and_jacobian(x0[:N_Q])[0], [T], weight=1e4, name="home"),
             ViaPoint(arm, [0.6, 0.9], None, weight=1.0, precision=[1.0, 3.0], name="every_step"),
             StateTarget(np.zeros(2 * N_Q), [T], weight=1.0,
                         precision=np.r_[np.zeros(N_Q), np.ones(N_Q)], name="rest")]
    control = [ControlCost(1e-2)] + ([ControlLimit(-2.0, 2.0, 1e4)] if limits else [])
    return Problem(dyn, x0, T, state, control)


# -- the reference: Algorithm 1 from the formulas, nothing skipped --------------------------
class Reference:
    """AICO with dense solves (``n = n_x``, ``m = n_u``); messages in the moment forms of ``raico.planning.aico``'s docstring:
    forward ``S^-1, S^-1 s``, backward ``V^-1, V^-1 v``, task ``R, r``."""

    def __init__(self, p: Problem, o: AICOOptions):
        self.p, self.o, n, Tn = p, o, p.n_x, p.T
        self.I, self.q = np.eye(n), o.process_noise
        self.Sinv, self.Ss = np.zeros((Tn + 1, n, n)), np.zeros((Tn + 1, n))
        self.Sinv[0], self.Ss[0] = self.I / o.start_variance, p.x0 / o.start_variance
        self.Vinv, self.Vv = np.zeros((Tn + 1, n, n)), np.zeros((Tn + 1, n))
        self.b = np.zeros((Tn + 1, n))
        self.ctl_o, self.ctl_O = np.zeros((Tn, p.n_u)), np.zeros((Tn, p.n_u, n))
        self.A, self.a = np.zeros((Tn, n, n)), np.zeros((Tn, n))
        self.B = np.zeros((Tn, n, p.n_u))
        self.R, self.r = np.zeros((Tn + 1, n, n)), np.zeros((Tn + 1, n))

    def linearize(self, t):
        if t < self.p.T:
            self.A[t], self.a[t], self.B[t] = self.p.dynamics.linearize(self.X[t], self.U[t])
        R, r = self.p.quadratize_states(self.X[t][None], np.array([t]))
        self.R[t] = R[0] + 2 * self.alpha * self.I
        self.r[t] = r[0] + 2 * self.alpha * self.Xprev[t]

    def qbar(self, t):
        """Controls marginalized: ``Qbar_t`` and the drift ``a_t + B_t H_t^-1 h_t``."""
        BHi = self.B[t] @ np.linalg.inv(self.H[t])
        return self.q * self.I + BHi @ self.B[t].T, self.a[t] + BHi @ self.h[t]

    def forward(self, t):
        A, P = self.A[t - 1], self.Sinv[t - 1] + self.R[t - 1]
        Qb, aeff = self.qbar(t - 1)
        S = A @ np.linalg.solve(P, A.T) + Qb
        s = A @ np.linalg.solve(P, self.Ss[t - 1] + self.r[t - 1]) + aeff
        self.Sinv[t] = np.linalg.inv(S)
        self.Ss[t] = self.Sinv[t] @ s

    def backward(self, t):
        A, B, I, q = self.A[t], self.B[t], self.I, self.q
        Pp, pp = self.Vinv[t + 1] + self.R[t + 1], self.Vv[t + 1] + self.r[t + 1]
        Vs, Vm = np.linalg.solve(I + q * Pp, Pp), np.linalg.solve(I + q * Pp, pp)  # V*, V* m'
        M = B.T @ Vs @ B + self.H[t]
        self.ctl_o[t] = np.linalg.solve(M, B.T @ (Vm - Vs @ self.a[t]) + self.h[t])
        self.ctl_O[t] = -np.linalg.solve(M, B.T @ Vs @ A)
        # Woodbury: K = (P'^-1 + Qbar)^-1 = V* - V* B M^-1 B^T V*, K m' from V* m'
        K = Vs - Vs @ B @ np.linalg.solve(M, B.T @ Vs)
        Km = Vm - Vs @ B @ np.linalg.solve(M, B.T @ Vm)
        self.Vinv[t] = A.T @ K @ A
        self.Vv[t] = A.T @ (Km - K @ self.qbar(t)[1])

    def belief(self, t):
        self.b[t] = np.linalg.solve(self.Sinv[t] + self.Vinv[t] + self.R[t],
                                    self.Ss[t] + self.Vv[t] + self.r[t])
        return self.b[t]

    def settle(self, t, redo=None):
        o = self.o
        for _ in range(o.max_repeats):
            d = self.belief(t) - self.X[t]
            if not np.linalg.norm(d) > o.theta:
                return
            self.X[t] += o.belief_rate * d
            self.linearize(t)
            self.repeats += 1
            if redo:
                redo(t)
        self.belief(t)

    def run(self) -> dict:
        """Iterations from ``x_t = x0``, ``u = 0``: X, U, o, O, per-iteration costs and
        repeats, and the beliefs of the last sweep."""
        p, o, Tn = self.p, self.o, self.p.T
        X, U = np.tile(p.x0, (Tn + 1, 1)), np.zeros((Tn, p.n_u))
        relocate = math.isfinite(o.theta) and o.max_repeats > 0
        costs, repeats, self.alpha = [], [], o.alpha
        for _ in range(o.iterations):
            self.X, self.Xprev, self.U, self.repeats = X.copy(), X, U, 0
            self.H, self.h = p.quadratize_controls(U)
            for t in range(Tn + 1):
                self.linearize(t)
            if relocate:
                for t in range(1, Tn + 1):
                    self.forward(t)
                    self.settle(t)
            for t in range(Tn - 1, -1, -1):
                self.backward(t)
                if relocate:
                    self.settle(t, self.backward)
            X, U = controller_rollout(p.dynamics, p.x0, self.ctl_o, self.ctl_O)
            costs.append(p.cost(X, U))
            repeats.append(self.repeats)
            self.alpha *= o.gamma
        if not relocate:
            for t in range(1, Tn + 1):
                self.forward(t)
            for t in range(Tn + 1):
                self.belief(t)
        return dict(X=X, U=U, o=self.ctl_o, O=self.ctl_O, costs=np.array(costs),
                    repeats=repeats, beliefs=self.b)


CASES = {
    "raico-nonlinear": ("pendulums", False, dict(alpha=1.0, iterations=6)),
    "raico-nonlinear-limits": ("pendulums", True, dict(alpha=0.5, gamma=0.8, iterations=5,
                                                       theta=0.02)),
    "aico-nonlinear-rate": ("pendulums", False, dict(alpha=0.0, iterations=4, theta=0.01,
                                                     belief_rate=0.6, max_repeats=2)),
    "raico-nonlinear-theta-inf": ("pendulums", False, dict(alpha=1.0, iterations=4,
                                                           theta=math.inf)),
    "raico-lti": ("pseudo", False, dict(alpha=1.0, iterations=6, theta=0.02)),
    "aico-lti-limits": ("pseudo", True, dict(alpha=0.0, iterations=4, theta=0.01)),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_optimized_sweeps_equal_the_reference(case):
    dynamics, limits, opts = CASES[case]
    options = AICOOptions(tol_rel=0.0, **opts)
    ref = Reference(make_problem(dynamics, limits), options).run()
    res = aico(make_problem(dynamics, limits), options)
    assert res.status == "max-iterations", res.message
    reps = [h.repeats for h in res.history]
    assert reps == ref["repeats"]
    if math.isfinite(options.theta):
        assert sum(reps) > 0          # the relinearization path is exercised
    np.testing.assert_allclose(res.costs, ref["costs"], rtol=1e-9)
    for key, got in (("X", res.X), ("U", res.U), ("o", res.o), ("O", res.O),
                     ("beliefs", res.beliefs)):
        want = ref[key]
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-8 * np.abs(want).max(),
                                   err_msg=key)


def test_point_derivatives_and_memo_equal_the_batched_terms():
    """Per-step task messages (only the active terms) equal the batched ones, and the memo
    of the last task-map batch returns what a fresh evaluation does."""
    p = make_problem()
    rng = np.random.default_rng(0)
    X = p.x0 + 0.3 * rng.standard_normal((T + 1, 2 * N_Q))
    lx, lxx = p.state_derivatives(X)
    active = p.active_state_terms()
    assert [t.name for t in active[T // 2]] == ["via", "every_step"]
    assert [t.name for t in active[T]] == ["home", "every_step", "rest"]
    for t in (0, 7, T // 2, T):
        g, G = p.point_state_derivatives(X[t], t, active[t])
        assert_close(g, lx[t], scale=1.0)
        assert_close(G, lxx[t], scale=1.0)
        g_all, _ = p.point_state_derivatives(X[t], t)          # inactive terms add nothing
        assert_close(g_all, g, scale=1.0)
    c1 = p.cost(X, np.zeros((T, N_Q)))                          # fills the memo at X
    lx2, lxx2 = p.state_derivatives(X)                          # ... and hits it
    fresh = make_problem()
    np.testing.assert_array_equal(lx2, fresh.state_derivatives(X)[0])
    np.testing.assert_array_equal(lxx2, lxx)
    X2 = X.copy()
    X2[5, 0] += 1e-3                                            # a changed row misses it
    c2 = p.cost(X2, np.zeros((T, N_Q)))
    assert c2 != c1 and c2 == fresh.cost(X2, np.zeros((T, N_Q)))
    assert c1 == fresh.cost(X, np.zeros((T, N_Q)))
    np.testing.assert_array_equal(p.state_derivatives(X2)[0], fresh.state_derivatives(X2)[0])
