"""The MPC tick's preparation / feedback split (raico.planning.aico.shift.SplitTick, MPC(..., split=True)).

Theory (docs/mpc.md, "Preparation and feedback"): the split's controller for a window is the one the whole
tick computes at the prediction ``x_hat`` (the model's step under the control sent) instead of the
measurement ``x``, and its control is ``o_0 + O_0 x``. The gains ``O`` do not depend on the start. On a
linear-quadratic problem AICO's controller (alpha 0) does not depend on the trajectory it is linearized at,
so there the split's controls are the whole tick's for any disturbance; R-AICO's feedforward reads its
anchor (the trajectory linearized at), so its controls are the whole tick's where ``x = x_hat``.
"""

from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest

from raico.planning.aico import AICOOptions
from raico.planning.mpc import MPC
from tests.planning.test_mpc_kernels import _arm5, _need_kernels
from tests.planning.test_solvers_lq import make_lq
from tests.tolerance import close

pytestmark = pytest.mark.compiled   # reaches a C kernel


def _pair(pb, H, solver, opts, **kw):
    return MPC(pb, H, solver, opts, split=True, **kw), MPC(pb, H, solver, opts, **kw)


@pytest.mark.numerics
@pytest.mark.parametrize("theta", [math.inf, 0.1])
def test_on_lq_aico_split_controls_are_the_whole_ticks_under_disturbances(theta):
    pb, H = make_lq(seed=3, T=30), 20
    split, whole = _pair(pb, H, "aico", AICOOptions(process_noise=1e-9, theta=theta))
    rng = np.random.default_rng(0)
    x = pb.x0.copy()
    for _ in range(10):
        u, o, O = split.tick(x)
        uw, ow, Ow = whole.tick(x)
        assert close(u, uw, scale=1.0) and close(O, Ow, scale=1.0) and close(o, ow, scale=1.0)
        x = pb.dynamics.step(x, u) + 0.05 * rng.standard_normal(pb.n_x)
    assert np.all(np.isfinite(split.log.feedback_time[:10]))


@pytest.mark.numerics
def test_on_lq_raico_split_is_the_whole_tick_at_the_prediction():
    """R-AICO (alpha 1): with the plant the model, ``x = x_hat`` and the controls are the whole tick's; after
    a disturbance at tick 4 the split's controller is the whole tick's at ``x_hat`` (a whole-tick MPC fed
    ``x_hat`` there), its control ``o_0 + O_0 x``, and the gains the whole tick's at ``x``."""
    pb, H, opts = make_lq(seed=3, T=30), 20, {"alpha": 1.0, "process_noise": 1e-9}
    split, whole = _pair(pb, H, "raico", opts)
    at_hat = MPC(pb, H, "raico", opts)
    x = pb.x0.copy()
    for k in range(5):
        x_hat = x.copy()
        if k == 4:
            x = x + np.linspace(-0.05, 0.05, pb.n_x)     # the disturbance
        u, o, O = (a.copy() for a in split.tick(x))
        uw, _, Ow = whole.tick(x)
        _, oh, Oh = at_hat.tick(x_hat)
        assert close(o, oh, scale=1.0) and close(O, Oh, scale=1.0) and close(O, Ow, scale=1.0)
        assert close(u, o + O @ x, scale=1.0)
        if k < 4:
            assert close(u, uw, scale=1.0)
        x = pb.dynamics.step(x, u)
    assert not close(u, uw, scale=1.0)     # the anchor differs by design after the disturbance


@pytest.mark.numerics
@pytest.mark.parametrize("theta, iterations", [(math.inf, 1), (0.1, 1), (math.inf, 3)])
def test_split_with_clipped_controls_is_the_whole_tick_without_disturbance(theta, iterations):
    """arm5 (compiled, nonlinear) with its controls at the effort limit: the split clips the feedback's
    control as the whole tick's consistent controller does; with the plant the model both run alike (with
    several iterations per tick the earlier ones' rollouts start at the prediction)."""
    _need_kernels()
    pb = _arm5(60)
    split, whole = _pair(pb, 12, "raico", {"alpha": 1.0, "theta": theta}, iterations=iterations)
    split.prepare(pb.x0, 8)
    whole.prepare(pb.x0, 8)
    x, clipped = pb.x0.copy(), 0
    for _ in range(20):
        u = split.tick(x)[0].copy()
        assert close(u, whole.tick(x)[0], scale=1.0)
        clipped += int(np.any(np.abs(u) >= 1.2))
        x = pb.dynamics.step(x, u)
    assert clipped > 0
    assert close(split.log.cost[:20], whole.log.cost[:20])


def test_the_feedback_phase_allocates_nothing():
    """tracemalloc around the feedback phase between preparations (arm5, its effort box clipping): after a
    warm-up (tracemalloc's and numpy's first calls) no byte is allocated, not even a temporary."""
    _need_kernels()
    pb = _arm5(60)
    mpc = MPC(pb, 12, "raico", {"alpha": 1.0}, split=True)
    mpc.prepare(pb.x0, 8)
    x = pb.x0.copy()
    for _ in range(3):
        x = pb.dynamics.step(x, mpc.tick(x)[0])
    peaks = []
    tracemalloc.start()
    try:
        for _ in range(30):
            mpc.split.prepare()
            before = tracemalloc.get_traced_memory()[0]
            tracemalloc.reset_peak()
            mpc.split.feedback(x)
            peaks.append(tracemalloc.get_traced_memory()[1] - before)
    finally:
        tracemalloc.stop()
    assert max(peaks[10:]) <= 0, peaks


@pytest.mark.parametrize("kwargs, match", [
    ({"solver": "fddp"}, "no preparation / feedback split"),
    ({"solver": "raico", "options": {"alpha": 1.0, "schedule": "adaptive"}}, "fixed schedule"),
])
def test_bad_input(kwargs, match):
    with pytest.raises(ValueError, match=match):
        MPC(make_lq(seed=3, T=30), 10, split=True, **kwargs)


def test_a_split_tick_refuses_a_period_shorter_than_the_planning_step():
    pb = make_lq(seed=3, T=30)
    mpc = MPC(pb, 10, "aico", AICOOptions(process_noise=1e-9), split=True)
    with pytest.raises(ValueError, match="one tick per step"):
        mpc.tick(pb.x0, advance=False)
