"""A state target per step (``StateTarget`` with ``(T+1, n_x)`` targets) and its targets in an MPC window
(raico.planning.mpc.follow_references): the term's derivatives against differences, the compiled task
messages against the Python term, the window's targets at each tick the problem's at the absolute steps, and
the shifted warm start plus one iteration the exact solve of the window with those targets (LQ)."""

from __future__ import annotations

import copy
import ctypes

import numpy as np
import pytest

from raico.planning import kernels
from raico.planning.aico import AICOOptions, aico
from raico.planning.costs import ControlCost, StateTarget
from raico.planning.mpc import MPC, follow_references, window_times
from raico.planning.problem import Problem
from raico.plants.dynamics import PseudoDynamics
from tests.planning.test_solvers_lq import exact_solution, make_lq
from tests.tolerance import close

pytestmark = pytest.mark.compiled   # reaches a C kernel


def _reference_term(rng, T: int, n: int) -> StateTarget:
    return StateTarget(rng.standard_normal((T + 1, n)), None, 3.0, rng.uniform(0.5, 2.0, n), name="ref")


@pytest.mark.numerics
def test_per_step_target_derivatives_and_compiled_rows():
    rng = np.random.default_rng(1)
    nq, T = 3, 5
    term = _reference_term(rng, T, 2 * nq)
    assert term.per_step
    pb = Problem(PseudoDynamics(nq, 0.01), np.zeros(2 * nq), T, [term], [ControlCost(1e-2)])
    X = rng.standard_normal((T + 1, 2 * nq))
    idx = np.arange(T + 1)
    lx, lxx = term.derivatives(X, idx)
    h = 1e-6
    for t in (0, 3, T):
        fd = np.array([(term.value((X[t] + h * e)[None], idx[t:t + 1])[0]
                        - term.value((X[t] - h * e)[None], idx[t:t + 1])[0]) / (2 * h) for e in np.eye(2 * nq)])
        assert close(lx[t], fd, rel=1e-6)   # central differences of a quadratic: rounding only (h^2 term is 0)
        # the same term with step t's target alone
        fixed = StateTarget(term.target[t], None, 3.0, np.diag(term.C), name="fixed")
        g, G = fixed.derivatives(X[t:t + 1])
        assert close(lx[t], g[0]) and close(lxx[t], G[0])
    compiled = kernels.compile_task_set(pb)
    if compiled is None:
        pytest.skip("the compiled task messages are not built here")
    fn, ctx, keep = compiled
    ev = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p, ctypes.c_void_p,
                          ctypes.c_void_p)(fn)

    def rows(t: int) -> tuple[np.ndarray, np.ndarray]:
        g, G = np.empty(2 * nq), np.empty((2 * nq, 2 * nq))
        ev(ctx, t, np.ascontiguousarray(X[t]).ctypes.data, g.ctypes.data, G.ctypes.data)
        return g, G

    for t in range(T + 1):
        g, G = rows(t)
        assert close(g, lx[t]) and close(G, lxx[t])
    term.target[2] += 1.0          # read in place: a refilled target is what the kernel sees
    lx2, _ = term.derivatives(X, idx)
    assert close(rows(2)[0], lx2[2]) and not close(lx2[2], lx[2])
    keep.append(None)


def test_window_targets_follow_the_absolute_steps():
    rng = np.random.default_rng(2)
    pb, H = make_lq(seed=1, T=12), 5
    ref = _reference_term(rng, pb.T, pb.n_x)
    pb = Problem(pb.dynamics, pb.x0, pb.T, [*pb.state_terms, ref], list(pb.control_terms))
    mpc = MPC(pb, H, "aico", AICOOptions(process_noise=1e-9))
    w = mpc.window.state_terms[-1]
    assert w.target.shape == (H + 1, pb.n_x) and w.target is not ref.target
    for k in (0, 4, 7, 9, 11):
        mpc._set_tick(k)
        expect = ref.target[[min(k + j, pb.T) for j in range(H + 1)]]   # past the end: the last one
        assert np.array_equal(w.target, expect)
    buf = np.zeros((3, 2))
    follow_references([(type("T", (), {"target": buf})(), np.arange(10.0).reshape(5, 2))], 3)
    assert np.array_equal(buf, [[6, 7], [8, 9], [8, 9]])


def _cold_window(pb: Problem, H: int, k: int, x: np.ndarray) -> Problem:
    """The window problem at tick ``k`` built by hand: fresh copies, the per-step targets sliced."""
    terms = []
    for t in pb.state_terms:
        c = copy.copy(t)
        c._set_times(window_times(t.times, pb.T, H, k))
        if getattr(t, "per_step", False):
            c.target = t.target[[min(k + j, pb.T) for j in range(H + 1)]]
        terms.append(c)
    return Problem(pb.dynamics, x, H, terms, list(pb.control_terms))


@pytest.mark.numerics
def test_shifted_warm_start_with_per_step_targets_is_the_cold_solve_lq():
    rng = np.random.default_rng(4)
    base, H = make_lq(seed=3, T=30), 20
    pb = Problem(base.dynamics, base.x0, base.T, [*base.state_terms, _reference_term(rng, base.T, base.n_x)],
                 list(base.control_terms))
    opts = AICOOptions(process_noise=1e-9, theta=float("inf"))
    mpc = MPC(pb, H, "aico", opts)
    x = pb.x0.copy()
    for k in range(4):
        u, _, _ = mpc.tick(x)
        cold = aico(_cold_window(pb, H, k, x), AICOOptions(iterations=5, process_noise=1e-9))
        assert close(mpc.O, cold.O, scale=1.0) and close(mpc.o, cold.o, scale=1.0)
        assert close(mpc.X, cold.X, scale=1.0) and close(u, cold.U[0], scale=1.0)
        Xe, Ue = exact_solution(_cold_window(pb, H, k, x))
        assert np.max(np.abs(mpc.U - Ue)) < 1e-5      # AICO's process-noise floor, as the LQ tests bound it
        x = pb.dynamics.step(x, u) + 0.05 * rng.standard_normal(pb.n_x)


def test_fddp_refuses_a_per_step_target():
    rng = np.random.default_rng(5)
    base = make_lq(seed=1, T=10)
    pb = Problem(base.dynamics, base.x0, base.T, [_reference_term(rng, base.T, base.n_x)], list(base.control_terms))
    with pytest.raises(ValueError, match="per step"):
        MPC(pb, 5, "fddp")


def test_crocoddyl_refuses_a_per_step_target():
    pytest.importorskip("crocoddyl")
    from raico.planning.crocoddyl.costs import items_state
    from raico.planning.crocoddyl.model import NotExpressible

    term = _reference_term(np.random.default_rng(6), 4, 2)
    with pytest.raises(NotExpressible, match="per step"):
        items_state(term, None, 0, None, None, None)
