"""The augmented Lagrangian's endgame (raico/planning/constraints.py, raico/planning/aico/bounds.py): in the budget's
last quarter, from an iterate beyond a plan's status tolerance, the multipliers step after every accepted iteration
and the penalty grows at the first update whose violation did not fall by ``DECREASE``; before it the penalty waits
``PATIENCE`` updates."""

from __future__ import annotations

import numpy as np
import pytest

from raico.planning.aico import AICOOptions, aico
from raico.planning.aico.bounds import in_endgame
from raico.planning.constraints import MU_GROWTH, PATIENCE, AugmentedLagrangian, StateBox
from raico.planning.problem import RANGE_STATUS_TOL, Status
from tests.planning.test_aico_robust import bounded_lq, bounded_qp_optimum


def _box(T: int = 3) -> AugmentedLagrangian:
    return AugmentedLagrangian([StateBox("range", [0], np.full((T + 1, 1), -1.0), np.full((T + 1, 1), 1.0), 1e-4)],
                               T, mu=2.0)


def test_the_endgame_is_the_budgets_last_quarter_beyond_the_status_tolerance():
    al, U = _box(), np.zeros((3, 1))
    out, edge, inside = (np.full((4, 2), x) for x in (1.5, 1.0 + 0.9 * RANGE_STATUS_TOL, 0.5))
    assert [it for it in range(1, 41) if in_endgame(it, 40, al, out, U)] == list(range(31, 41))
    assert in_endgame(1, 1, al, out, U) and not in_endgame(1, 2, al, out, U) and in_endgame(2, 2, al, out, U)
    # a plan within its status tolerance (not out-of-bounds) is left to the merit
    assert not in_endgame(40, 40, al, edge, U) and not in_endgame(40, 40, al, inside, U)


def _stalled_updates(endgame: bool) -> list[float]:
    """The penalty (over its start) after each of ``PATIENCE + 1`` updates at one iterate beyond its box: the
    violation never falls after the first."""
    T = 3
    al = _box(T)
    al.endgame = endgame
    X, U = np.full((T + 1, 2), 1.5), np.zeros((T, 1))
    out = []
    for _ in range(PATIENCE + 1):
        al.update(X, U)
        out.append(al.mu / al.mu0)
    return out


def test_the_penalty_grows_at_the_first_stalled_update_in_the_endgame_only():
    # the first update is the reference; the endgame grows at every later one, before it the PATIENCE-th grows
    assert _stalled_updates(True) == pytest.approx([MU_GROWTH ** k for k in range(PATIENCE + 1)])
    assert _stalled_updates(False) == pytest.approx([1.0] * PATIENCE + [MU_GROWTH])


@pytest.mark.numerics
def test_the_bounded_lq_optimum_is_kept_with_the_endgame():
    """The exact check: the bounded LQ problem's plan is the bounded QP's optimum (SLSQP) to 1e-4, inside the range
    to 1e-4, with a budget of 120 (converged long before its endgame) and of 48 (its endgame from iteration 37,
    where the run is still out of bounds with OpenBLAS's Haswell kernels and converges at 42). Not at 30: there the
    outcome depends on rounding (SkylakeX's kernels end inside, Haswell's 0.018 rad out), so the endgame does not
    guarantee a feasible plan at a short budget."""
    free, pb = bounded_lq(T=12)
    best = bounded_qp_optimum(pb)
    for n in (120, 48):
        res = aico(pb, AICOOptions(iterations=n, alpha=1.0, schedule="robust"))
        q, u = pb.bounds.violation(res.X, res.U)
        assert res.status is not Status.OUT_OF_BOUNDS and q <= 1e-4 and u == 0.0, (n, q, u, res.message)
        assert pb.cost(res.X, res.U) == pytest.approx(best, rel=1e-4), n
