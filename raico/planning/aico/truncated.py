"""Joint ranges and velocity limits as truncated-Gaussian messages (expectation propagation), AICO's own route
to inequality constraints: :class:`TruncatedSites`, selected by ``AICOOptions.ranges = "ep"``.

Each bounded coordinate ``x_t[i]`` with ``lo <= x_t[i] <= hi`` has a Gaussian site ``N[x | nu, lam]`` (cost
``1/2 lam x^2 - nu x``, in the cost's units) added to the task message of step ``t``. After an accepted
iteration the belief's marginal of ``x_t[i]`` (mean: the iterate; precision ``p = 1 / [B_t^-1]_ii`` from the
sweeps' belief ``B_t``, which holds the site) gives the cavity ``p_c = p - lam``, ``m_c = (p x - nu) / p_c``; the
posterior ``exp(-cost / temperature)`` of the cavity truncated to ``[lo, hi]`` has the moments
:func:`truncated_moments`, and the site is the matched Gaussian over the cavity (damped). At EP's fixed point the
marginal's mean is the truncated one: inside the range; its distance from the optimum grows with the
temperature (an interior method whose barrier is the posterior's width). The other hard constraints (effort
limits, torques, collisions) stay in the augmented Lagrangian ``rest``.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from scipy.special import erfcx, ndtr

if TYPE_CHECKING:
    from raico.planning.aico.sweeps import Sweeps

SQRT2 = math.sqrt(2.0)
SQRT_2_PI = math.sqrt(2.0 / math.pi)
NARROW = 0.5     # a box over which the log-density varies by less than this: Gauss-Legendre quadrature
TAIL = 4.0       # a one-sided bound this many sigmas beyond the mean: the continued fraction
CF_DEPTH = 80    # the continued fraction's depth (double precision from TAIL on)
GROWTH = 10.0    # a site's precision grows by at most this factor (of itself or its cavity's) per update
ANNEAL = 10.0    # the temperature's fall at a feasible stationary point, down to its floor
_GL_X, _GL_W = np.polynomial.legendre.leggauss(32)


def _upper_tail(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance of a standard normal conditioned on ``x > a`` (``a >= 0``): ``lambda = phi(a) / Q(a)``
    from ``erfcx``; beyond ``TAIL`` the variance ``c1 (2 c2 - c1)`` from the Mills ratio's continued fraction
    (``c_k = 1 / (a + (k+1) c_{k+1})``, ``lambda = a + c1``), which has no cancellation."""
    lam = SQRT_2_PI / erfcx(a / SQRT2)
    var = 1.0 + a * lam - lam * lam
    far = a >= TAIL
    if np.any(far):
        af = a[far]
        c = np.zeros_like(af)
        for k in range(CF_DEPTH, 2, -1):
            c = 1.0 / (af + k * c)          # c_{k-1}
        c2 = c
        c1 = 1.0 / (af + 2.0 * c2)
        lam[far], var[far] = af + c1, c1 * (2.0 * c2 - c1)
    return lam, var


def truncated_moments(mu: np.ndarray, sigma: np.ndarray, lo: np.ndarray, hi: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance of ``N(mu, sigma^2)`` truncated to ``[lo, hi]`` (arrays of one shape; ``-inf``/``inf``:
    one-sided), stable in the far tails: a box beyond the mean is mirrored to the upper tail and taken as the
    difference of two one-sided tails (:func:`_upper_tail`, weights ``Q(b)/Q(a)`` from ``erfcx``); a box narrow
    against the density's curvature by 32-point Gauss-Legendre quadrature; a box around the mean directly."""
    mu, sigma, lo, hi = np.broadcast_arrays(*(np.asarray(z, dtype=float) for z in (mu, sigma, lo, hi)))
    a, b = (lo - mu) / sigma, (hi - mu) / sigma
    flip = a + b < 0.0                         # mirror: the box's far side in the upper tail
    a, b = np.where(flip, -b, a), np.where(flip, -a, b)
    m, v = np.empty(a.shape), np.empty(a.shape)
    with np.errstate(invalid="ignore", over="ignore"):
        spread = 0.5 * np.where(a > 0.0, (b - a) * (b + a), b * b)   # the log-density's range over the box
        narrow = np.isfinite(b) & (spread < NARROW)
    inside = (a <= 0.0) & ~narrow
    tail = (a > 0.0) & ~narrow
    if np.any(inside):
        ai, bi = a[inside], b[inside]
        pa, pb = np.exp(-0.5 * ai * ai) / math.sqrt(2 * math.pi), np.exp(-0.5 * bi * bi) / math.sqrt(2 * math.pi)
        Z = ndtr(bi) - ndtr(ai)
        apa = np.where(np.isfinite(ai), np.nan_to_num(ai) * pa, 0.0)
        bpb = np.where(np.isfinite(bi), np.nan_to_num(bi) * pb, 0.0)
        mi = (pa - pb) / Z
        m[inside], v[inside] = mi, 1.0 + (apa - bpb) / Z - mi * mi
    if np.any(tail):
        at, bt = a[tail], b[tail]
        ma, va = _upper_tail(at)
        fin = np.isfinite(bt)
        mb, vb = np.zeros_like(bt), np.zeros_like(bt)
        r = np.zeros_like(bt)
        if np.any(fin):
            mb[fin], vb[fin] = _upper_tail(bt[fin])
            x, y = at[fin] / SQRT2, bt[fin] / SQRT2
            r[fin] = np.exp(-(y - x) * (y + x)) * erfcx(y) / erfcx(x)    # Q(b) / Q(a)
        m[tail] = (ma - r * mb) / (1.0 - r)
        v[tail] = (va - r * vb) / (1.0 - r) - r * (mb - ma) ** 2 / (1.0 - r) ** 2
    if np.any(narrow):
        an, bn = a[narrow], b[narrow]
        c, h = 0.5 * (an + bn), 0.5 * (bn - an)
        x = c[:, None] + h[:, None] * _GL_X[None, :]
        logw = -0.5 * (x - c[:, None]) * (x + c[:, None])              # -(x^2 - c^2) / 2: no overflow
        w = _GL_W[None, :] * np.exp(logw - logw.max(axis=1, keepdims=True))
        w /= w.sum(axis=1, keepdims=True)
        d = np.sum(w * (x - c[:, None]), axis=1)
        m[narrow] = c + d
        v[narrow] = np.sum(w * (x - c[:, None] - d[:, None]) ** 2, axis=1)
    m = np.where(flip, -m, m)
    return mu + sigma * m, sigma * sigma * np.maximum(v, 0.0)


class TruncatedSites:
    """The ranges' EP sites (``lam, nu (T+1, k)`` per box, in the cost's units) as hard constraints of the
    sweeps (the interface of :class:`raico.planning.constraints.AugmentedLagrangian`: ``model``, ``value``,
    ``violation``, ``update``), with the augmented Lagrangian ``rest`` of the other constraints (or ``None``).
    ``sweeps``: the run's :class:`raico.planning.aico.sweeps.Sweeps` (its beliefs' precisions), set by the caller;
    ``temperature``: the posterior ``exp(-cost / temperature)`` (1: AICO's own); ``damping``: the share of the
    new site in the update; ``floor``: the temperature :meth:`anneal` lowers it to (``None``: no annealing).
    :meth:`step_sites` moves the sites (every accepted iteration), :meth:`update` also
    the rest's multipliers (where the merit settled)."""

    def __init__(self, boxes: list, rest, temperature: float = 1.0, damping: float = 0.5,
                 floor: float | None = None):
        self.boxes, self.rest = boxes, rest
        self.temperature, self.damping = float(temperature), float(damping)
        self.floor = self.temperature if floor is None else min(float(floor), self.temperature)
        self.sweeps: Sweeps | None = None
        self.lam = [np.zeros_like(c.lo) for c in boxes]
        self.nu = [np.zeros_like(c.lo) for c in boxes]
        self.last_violation = math.inf
        self.updates = 0

    @property
    def y(self) -> list:
        """Like the augmented Lagrangian's multipliers: ``None`` where a box's sites are all zero."""
        own = [lam if lam.any() else None for lam in self.lam]
        return own + (list(self.rest.y) if self.rest is not None else [])

    def value(self, X: np.ndarray, U: np.ndarray) -> float:
        """The sites' cost ``1/2 lam x^2 - nu x`` up to a constant, taken ``0`` at the point ``r`` of the box
        nearest the site's mean (``>= 0`` inside the box: a site's update moves the merit by no more than its
        change in the box), plus the rest's terms."""
        s = self.rest.value(X, U) if self.rest is not None else 0.0
        for c, lam, nu in zip(self.boxes, self.lam, self.nu):
            on = lam > 0
            if on.any():
                x, lo, hi = X[:, c.idx][on], c.lo[on], c.hi[on]
                r = np.clip(nu[on] / lam[on], lo, hi)
                d = x - r
                s += float(np.sum(0.5 * lam[on] * d * d + (lam[on] * r - nu[on]) * d))
        return s

    def model(self, X: np.ndarray, U: np.ndarray) -> tuple | None:
        """The sites' gradient and Hessian at ``X`` (``l_x = lam x - nu``, ``l_xx = diag(lam)``) plus the rest's
        model, as :meth:`raico.planning.constraints.AugmentedLagrangian.model`; ``None``: nothing to add."""
        rest = self.rest.model(X, U) if self.rest is not None else None
        if rest is None and not any(lam.any() for lam in self.lam):
            return None
        (K, n), (T, m) = X.shape, U.shape
        lx, lxx, lu, luu = rest if rest is not None else (np.zeros((K, n)), np.zeros((K, n, n)),
                                                          np.zeros((T, m)), np.zeros((T, m, m)))
        for c, lam, nu in zip(self.boxes, self.lam, self.nu):
            lx[:, c.idx] += lam * X[:, c.idx] - nu
            lxx[:, c.idx, c.idx] += lam
        return lx, lxx, lu, luu

    def violation(self, X: np.ndarray, U: np.ndarray) -> float:
        """The largest violation in units of each row's tolerance (<= 1: feasible), the rest's included."""
        v = self.rest.violation(X, U) if self.rest is not None else 0.0
        for c in self.boxes:
            G = c.values(X, U)
            with np.errstate(invalid="ignore"):
                v = max(v, float(np.nanmax(np.where(np.isneginf(G), 0.0, G) / c.tol, initial=0.0)))
        return v

    def step_sites(self, X: np.ndarray, U: np.ndarray) -> None:
        """One damped EP update of every site: the marginals' means the accepted iterate ``X`` (the Laplace
        approximation at it; the beliefs' own means, a Newton step from the last linearization, were measured
        to wander on crocoddyl's Kinova), their precisions the sweeps' last beliefs' (which hold the sites)."""
        P = self._marginal_precisions()
        tau, d = self.temperature, self.damping
        for k, c in enumerate(self.boxes):
            bounded = np.isfinite(c.lo) | np.isfinite(c.hi)
            bounded[0] = False
            p, lam, nu, x = P[:, c.idx], self.lam[k], self.nu[k], X[:, c.idx]
            pc = p - lam
            ok = bounded & (pc > 0) & np.isfinite(x)
            if not ok.any():
                continue
            mc = (p[ok] * x[ok] - nu[ok]) / pc[ok]
            mt, vt = truncated_moments(mc, np.sqrt(tau / pc[ok]), c.lo[ok], c.hi[ok])
            vt = np.maximum(vt, 1e-300)
            lam_new = np.maximum(tau / vt - pc[ok], 0.0)
            nu_new = np.where(lam_new > 0, tau * mt / vt - pc[ok] * mc, 0.0)
            cap = GROWTH * np.maximum(lam[ok], pc[ok])   # one update stiffens a site by at most GROWTH
            over = lam_new > cap
            if over.any():      # the capped site keeps the matched mean
                mean = nu_new[over] / lam_new[over]
                lam_new[over] = cap[over]
                nu_new[over] = cap[over] * mean
            lam[ok] = (1.0 - d) * lam[ok] + d * lam_new
            nu[ok] = (1.0 - d) * nu[ok] + d * nu_new
        self.updates += 1
        self.last_violation = self.violation(X, U)

    def update(self, X: np.ndarray, U: np.ndarray) -> None:
        """Where the merit settled: colder (:meth:`anneal`), the sites' EP update and the rest's multiplier step."""
        if self.rest is not None:
            self.rest.update(X, U)
        self.anneal()
        self.step_sites(X, U)

    def anneal(self) -> bool:
        """At a feasible stationary point: the temperature falls by ``ANNEAL`` (not below ``floor``); ``True``
        where it was at its floor already (the run may stop)."""
        if self.temperature <= self.floor * (1.0 + 1e-12):
            return True
        self.temperature = max(self.floor, self.temperature / ANNEAL)
        return False

    def force_growth(self) -> None:
        """A stationary point outside the ranges: the temperature falls tenfold (the sites tighten), the rest's
        penalty grows."""
        self.temperature /= 10.0
        if self.rest is not None:
            self.rest.force_growth()

    def _marginal_precisions(self) -> np.ndarray:
        """``1 / diag(B_t^-1)`` ``(T+1, n)`` of the beliefs ``B_t = S_t^-1 + V_t^-1 + R_t`` of the sweeps' last
        linearization without R-AICO's proximal term (the posterior, not the step: one more backward and forward
        pass, where the sweeps do not relinearize; with it where that pass fails numerically)."""
        sw = self.sweeps
        if sw is None:
            raise RuntimeError("the sites need the run's sweeps (TruncatedSites.sweeps)")
        n, alpha = sw.n, sw.alpha
        strip = bool(alpha) and not sw.relocate
        if strip:
            saved = sw.RA.copy()
            sw.RA[:, np.arange(n), np.arange(n)] -= 2.0 * alpha
            sw.RA[:, :, n] -= 2.0 * alpha * sw.Xprev
            sw.alpha = 0.0
        try:
            if strip:
                sw.sweep()
            sw.beliefs()
        except (ArithmeticError, RuntimeError, np.linalg.LinAlgError):
            if not strip:
                raise
            sw.RA[:], sw.alpha = saved, alpha
            strip = False
            sw.sweep()
            sw.beliefs()
        B = sw.SA[:, :, :n] + sw.VA[:, :, :n] + sw.RA[:, :, :n]
        if strip:
            sw.RA[:], sw.alpha = saved, alpha
        B = 0.5 * (B + np.swapaxes(B, 1, 2))
        return 1.0 / np.diagonal(np.linalg.inv(B), axis1=1, axis2=2)


def truncated_ranges(al, temperature: float, damping: float, floor: float | None = None):  # noqa: ANN001, ANN201
    """The state boxes (joint ranges, velocity limits) of the augmented Lagrangian ``al`` as EP sites, its other
    constraints left in it (``None`` if none is left); ``None`` where ``al`` is."""
    from raico.planning.constraints import AugmentedLagrangian, StateBox

    if al is None:
        return None
    boxes = [c for c in al.constraints if isinstance(c, StateBox)]
    others = [c for c in al.constraints if not isinstance(c, StateBox)]
    if not boxes:
        return al
    rest = AugmentedLagrangian(others, al.T, al.mu0) if others else None
    if rest is not None:
        rest.mu = al.mu
    return TruncatedSites(boxes, rest, temperature, damping, floor)
