"""Joint ranges as truncated-Gaussian (EP) messages (raico/planning/aico/truncated.py): the truncated normal's
moments against numerical integration (one-sided, far tails, narrow boxes), the sites' gradient against finite
differences, and R-AICO with the sites on the bounded LQ problem against the exact QP's feasible optimum."""

from __future__ import annotations

import math

import numpy as np
import pytest

from raico.planning.aico import AICOOptions, aico
from raico.planning.aico.truncated import TruncatedSites, truncated_moments
from raico.planning.constraints import StateBox
from raico.planning.solvers import SOLVERS, solve
from tests.planning.test_aico_robust import bounded_lq, bounded_qp_optimum
from tests.tolerance import REL, bound

CASES = [   # (mu, sigma, lo, hi)
    (0.0, 1.0, -1.0, 2.0),            # around the mean
    (0.0, 1.0, 0.0, np.inf),          # one-sided, at the mean
    (2.0, 0.1, -1.0, 1.0),            # the mean 10 sigma beyond the box
    (0.0, 1.0, 3.9, np.inf),          # one-sided just below the continued fraction's threshold
    (0.0, 1.0, 4.5, np.inf),          # ... and beyond it
    (0.0, 1.0, 30.0, np.inf),         # far tail (Q(30) ~ 5e-198)
    (0.0, 1.0, -np.inf, -30.0),       # mirrored
    (0.0, 1.0, 8.0, 9.0),             # two-sided in the tail
    (0.0, 1.0, -40.0, -38.0),         # two-sided in the far tail (Q(38) ~ 3e-316, below the normal range)
    (0.0, 1.0, 5.0, 5.05),            # narrow, in the tail
    (0.0, 1.0, -1e-3, 1e-3),          # narrow, at the mean
    (0.3, 2.0, -0.3, 0.3),            # a range narrow against a wide posterior
]


def integrated(mu: float, s: float, lo: float, hi: float) -> tuple[float, float]:
    """Mean and variance by adaptive quadrature of the density scaled to 1 at its mode in the box, moments
    about that mode (no underflow in the tails, no cancellation in the variance)."""
    from scipy.integrate import quad

    mode = min(max(mu, lo), hi)

    def f(x: float) -> float:
        return math.exp(-0.5 * ((x - mu) ** 2 - (mode - mu) ** 2) / s ** 2)

    kw = {"epsabs": 0.0, "epsrel": 1e-13, "limit": 200}
    Z = quad(f, lo, hi, **kw)[0]
    d = quad(lambda x: f(x) * (x - mode), lo, hi, **kw)[0] / Z
    v = quad(lambda x: f(x) * (x - mode - d) ** 2, lo, hi, **kw)[0] / Z
    return mode + d, v


@pytest.mark.numerics
@pytest.mark.filterwarnings("ignore::scipy.integrate.IntegrationWarning")   # a first moment of 0 has no relative accuracy
@pytest.mark.parametrize("case", CASES)
def test_truncated_moments_match_numerical_integration(case):
    """Mean to 1e-9 of the box's scale and variance to 1e-9 relative (the quadrature's own accuracy is about
    1e-13; the naive formulas lose every digit of the variance in the far tails: scipy's truncnorm returns a
    negative variance at a = 1000)."""
    m, v = truncated_moments(*(np.array([z]) for z in case))
    mi, vi = integrated(*case)
    scale = max(abs(mi), case[1])
    assert abs(m[0] - mi) <= REL * scale, (m, mi)
    assert abs(v[0] - vi) <= REL * vi, (v, vi)


@pytest.mark.numerics
def test_truncated_moments_far_tail_asymptotics():
    """Beyond quadrature's reach (a = 1000 sigma): the Mills ratio's series, mean ``a + 1/a - 2/a^3``, variance
    ``1/a^2 - 6/a^4`` (terms of order ``a^-5`` and ``a^-6`` left: 1e-15 and 1e-12 relative), and a vector of
    mixed cases equals the cases one by one."""
    a = 1000.0
    m, v = truncated_moments(np.array([0.0]), np.array([1.0]), np.array([a]), np.array([np.inf]))
    assert m[0] == pytest.approx(a + 1 / a - 2 / a ** 3, rel=REL)
    assert v[0] == pytest.approx(1 / a ** 2 - 6 / a ** 4, rel=1e-9)
    cols = [np.array(c) for c in zip(*CASES)]
    M, V = truncated_moments(*cols)
    for k, c in enumerate(CASES):
        mk, vk = truncated_moments(*(np.array([z]) for z in c))
        assert M[k] == mk[0] and V[k] == vk[0]


@pytest.mark.numerics
def test_site_gradient_matches_finite_differences():
    """The sites' model (``l_x = lam x - nu``, ``l_xx = diag(lam)``) is the gradient and Hessian of their value
    (central differences, exact for a quadratic up to rounding)."""
    rng = np.random.default_rng(3)
    T, n, m = 4, 3, 1
    box = StateBox("joint_range", np.array([0, 2]), np.full((T + 1, 2), -0.5), np.full((T + 1, 2), 0.5), 1e-4)
    sites = TruncatedSites([box], None)
    sites.lam[0][:] = rng.uniform(0.5, 2.0, (T + 1, 2))
    sites.nu[0][:] = rng.normal(size=(T + 1, 2))
    X, U = rng.uniform(-0.4, 0.4, (T + 1, n)), np.zeros((T, m))
    lx, lxx, _, _ = sites.model(X, U)
    h = 1e-5
    for t, i in [(1, 0), (3, 2), (4, 1)]:
        E = np.zeros_like(X)
        E[t, i] = h
        fd = (sites.value(X + E, U) - sites.value(X - E, U)) / (2 * h)
        assert fd == pytest.approx(lx[t, i], rel=1e-6, abs=1e-8)
        fd2 = (sites.value(X + E, U) - 2 * sites.value(X, U) + sites.value(X - E, U)) / h ** 2
        assert fd2 == pytest.approx(lxx[t, i, i], rel=1e-4, abs=1e-4)


def ep_solvers() -> list[str]:
    """The solvers that keep the ranges as EP messages with the robust schedule (by capability, not name)."""
    return [name for name, s in SOLVERS.items() if s.caps.range_messages and "robust" in s.caps.schedules]


@pytest.mark.numerics
@pytest.mark.compiled
@pytest.mark.parametrize("name", ep_solvers())
def test_ep_ranges_on_the_bounded_lq_problem(name):
    """The unconstrained optimum leaves the range [-0.3, 0.3]; with the ranges as EP sites at AICO's own
    temperature the plan is strictly inside (EP's fixed point: the marginal's mean is a truncated mean) and its
    cost above the QP's feasible optimum, measured 0.52 % above it: asserted within 1 %. Annealed to 1e-4 (an
    interior method's path) it is within 1e-4 of the optimum (measured 8.5e-6 below it, the range left by 3.3e-5
    rad: inside the constraints' 1e-4), in at most 60 iterations (measured 30; the augmented Lagrangian 31)."""
    free, pb = bounded_lq(T=12)
    qp = bounded_qp_optimum(pb)
    res = solve(pb, name, {"iterations": 200, "alpha": 1.0, "schedule": "robust", "ranges": "ep"})
    q, u = pb.bounds.violation(res.X, res.U)
    assert q == 0.0 and u == 0.0, (q, u, res.message)
    assert qp <= pb.cost(res.X, res.U) <= 1.01 * qp, (pb.cost(res.X, res.U) / qp, res.message)
    res = solve(pb, name, {"iterations": 200, "alpha": 1.0, "schedule": "robust", "ranges": "ep",
                           "ep_temperature_min": 1e-4})
    q, u = pb.bounds.violation(res.X, res.U)
    assert q <= 1e-4 and u == 0.0, (q, u, res.message)
    assert pb.cost(res.X, res.U) == pytest.approx(qp, rel=1e-4)
    assert res.iterations <= 60 and "EP updates" in res.message


@pytest.mark.numerics
@pytest.mark.compiled
def test_ep_ranges_compiled_and_python_sweeps_agree(monkeypatch):
    """The sites read the beliefs of the compiled sweeps as of the Python ones: the same plan to rounding."""
    from raico.planning.aico.sweeps import Sweeps

    _, pb = bounded_lq(T=12)
    opts = AICOOptions(iterations=15, alpha=1.0, schedule="robust", ranges="ep", tol_rel=0.0)
    a = aico(pb, opts)
    monkeypatch.setattr(Sweeps, "compiled", False)
    b = aico(pb, opts)
    assert a.iterations == b.iterations
    # 15 iterations of 13 steps of n^3 operations (n = 4), the sites' stiffness over the marginal (cond ~ 1e2):
    # measured 1e-10 of the states' scale
    assert np.abs(a.X - b.X).max() <= bound(15 * 13 * 4 ** 3, 1e2) * np.abs(a.X).max()


def test_ep_options_are_checked():
    with pytest.raises(ValueError, match="option ranges must be one of al, ep"):
        AICOOptions(ranges="truncated")
    with pytest.raises(ValueError, match="ep_temperature"):
        AICOOptions(ranges="ep", ep_temperature=0.0)
    with pytest.raises(ValueError, match="ep_damping"):
        AICOOptions(ranges="ep", ep_damping=1.5)
