"""One derivative harness: analytic derivatives against central finite differences.

Finite differences are only an oracle here; no planner uses them. The pieces:

- :func:`numdiff_jacobian` (one point) and :func:`numdiff_rows` (row-wise batches): central
  differences ``(f(x + eps e_j) - f(x - eps e_j)) / (2 eps)``;
- :func:`compare` -> :class:`Check`: an array against its reference (max absolute and relative
  error, the worst entry, pass/fail); :class:`Report` collects checks;
- :class:`NumDiffDynamics`: any dynamics model linearized by finite differences of its
  ``step`` (as crocoddyl's ``ActionModelNumDiff``);
- :func:`check_dynamics`, :func:`check_taskmap`, :func:`check_cost_term`: the checks of a
  dynamics model, a task map and a cost term (given as callables: this module imports nothing
  from ``stages``).

Tolerance convention: a check passes when ``max |got - ref| <= atol + rtol * max |ref|``
(errors scaled by the reference's largest entry, robust to zero entries).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

Array = np.ndarray


# --------------------------------------------------------------------------------------------
# Finite differences
# --------------------------------------------------------------------------------------------
def numdiff_jacobian(f: Callable[[Array], Array], x: Array, eps: float = 1e-6) -> Array:
    """Central differences of ``f: (n,) -> (k...)`` at ``x (n,)``: ``(k..., n)`` (scalars: ``(1, n)``)."""
    x = np.asarray(x, dtype=float)
    cols = []
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = eps
        cols.append((np.atleast_1d(f(x + e)) - np.atleast_1d(f(x - e))) / (2 * eps))
    return np.stack(cols, axis=-1)


def numdiff_rows(f: Callable[[Array], Array], X: Array, eps: float = 1e-6) -> Array:
    """Row-wise central differences of a batched ``f: (K, n) -> (K, k...)`` whose rows do not
    interact (task maps, per-time costs): ``(K, k..., n)``, one pair of calls per column."""
    X = np.asarray(X, dtype=float)
    cols = []
    for i in range(X.shape[1]):
        E = np.zeros_like(X)
        E[:, i] = eps
        cols.append((np.asarray(f(X + E)) - np.asarray(f(X - E))) / (2 * eps))
    return np.stack(cols, axis=-1)


# --------------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Check:
    """One comparison: passes when ``max_abs_error <= atol + rtol * scale``.

    ``max_rel_error = max_abs_error / scale`` with ``scale = max |ref|`` (at least 1e-300);
    ``worst`` is the index of the entry with the largest error (``()`` if the shapes differ).
    """

    name: str
    max_abs_error: float
    max_rel_error: float
    worst: tuple[int, ...]
    atol: float
    rtol: float
    passed: bool
    note: str = ""

    def __bool__(self) -> bool:
        return self.passed

    def __str__(self) -> str:
        status = "ok" if self.passed else "FAILED"
        return (f"{self.name}: {status} (max abs {self.max_abs_error:.2e}, max rel "
                f"{self.max_rel_error:.2e}, worst entry {self.worst}, atol {self.atol:.1e}, "
                f"rtol {self.rtol:.1e}){' ' + self.note if self.note else ''}")


def compare(name: str, got: ArrayLike, ref: ArrayLike, atol: float, rtol: float = 0.0) -> Check:
    """``got`` against the reference ``ref`` (same shape; other shapes or NaN fail)."""
    got, ref = np.asarray(got, dtype=float), np.asarray(ref, dtype=float)
    if got.shape != ref.shape:
        return Check(name, np.inf, np.inf, (), atol, rtol, False,
                     f"shape {got.shape}, expected {ref.shape}")
    if got.size == 0:
        return Check(name, 0.0, 0.0, (), atol, rtol, True)
    err = np.abs(got - ref)
    k = int(np.argmax(np.where(np.isnan(err), np.inf, err)))
    worst = tuple(int(i) for i in np.unravel_index(k, err.shape))
    max_abs = float(err.flat[k])
    scale = max(float(np.max(np.abs(ref))), 1e-300)
    passed = bool(max_abs <= atol + rtol * scale)  # False for NaN
    return Check(name, max_abs, max_abs / scale, worst, atol, rtol, passed)


def check_jacobian(name: str, J: Array, f: Callable[[Array], Array], x: Array,
                   eps: float = 1e-6, atol: float = 1e-6, rtol: float = 0.0) -> Check:
    """An analytic Jacobian ``J (k..., n)`` of ``f`` at ``x (n,)`` against central differences."""
    return compare(name, J, numdiff_jacobian(f, x, eps), atol, rtol)


@dataclass
class Report:
    """The checks of one object; true when all passed."""

    subject: str
    checks: list[Check] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.checks)

    @property
    def failures(self) -> list[Check]:
        return [c for c in self.checks if not c.passed]

    def __bool__(self) -> bool:
        return self.passed

    def __str__(self) -> str:
        return "\n".join([f"{self.subject}: {len(self.checks)} checks, "
                          f"{len(self.failures)} failed", *(f"  {c}" for c in self.checks)])

    def assert_passed(self) -> Report:
        """Raise ``AssertionError`` listing every check if any failed; else return ``self``."""
        if not self.passed:
            raise AssertionError(str(self))
        return self


# --------------------------------------------------------------------------------------------
# Dynamics
# --------------------------------------------------------------------------------------------
class NumDiffDynamics:
    """A dynamics model linearized by central differences of its ``step`` (an oracle: slow).

    Same interface as the model: ``A = d step/dx (n_x, n_x)``, ``B = d step/du (n_x, n_u)``,
    ``a = step(x, u) - A x - B u``.
    """

    def __init__(self, model, eps: float = 1e-6):
        self.model = model
        self.eps = float(eps)
        self.n_x, self.n_u, self.dt = model.n_x, model.n_u, model.dt

    def step(self, x: Array, u: Array) -> Array:
        return self.model.step(x, u)

    def linearize(self, x: Array, u: Array) -> tuple[Array, Array, Array]:
        x, u = np.asarray(x, dtype=float), np.asarray(u, dtype=float)
        A = numdiff_jacobian(lambda z: self.model.step(z, u), x, self.eps)
        B = numdiff_jacobian(lambda w: self.model.step(x, w), u, self.eps)
        return A, self.model.step(x, u) - A @ x - B @ u, B

    def linearize_trajectory(self, X: Array, U: Array) -> tuple[Array, Array, Array]:
        parts = [self.linearize(x, u) for x, u in zip(X, U)]
        return tuple(np.stack([p[i] for p in parts]) for i in range(3))  # type: ignore[return-value]


def check_dynamics(model, x: Array, u: Array, *, eps: float = 1e-6, atol: float = 1e-6,
                   rtol: float = 0.0, affine_atol: float = 1e-12, traj_atol: float = 1e-14,
                   traj_rtol: float = 1e-13) -> Report:
    """Check ``model.linearize`` and ``linearize_trajectory`` at states ``x (K, n_x)`` and
    controls ``u (K, n_u)`` (or one point ``(n_x,)``, ``(n_u,)``).

    Per point: ``A``, ``B`` against central differences of ``model.step`` (``atol``, ``rtol``);
    the affine model is exact at the point, ``A x + a + B u == step(x, u)`` (``affine_atol``).
    Over all points: ``linearize_trajectory`` equals the stacked per-point ``linearize``
    (``traj_atol``, ``traj_rtol``).
    """
    X, U = np.atleast_2d(np.asarray(x, dtype=float)), np.atleast_2d(np.asarray(u, dtype=float))
    report = Report(f"dynamics {type(model).__name__}")
    oracle = NumDiffDynamics(model, eps)
    points = []
    for k, (xk, uk) in enumerate(zip(X, U)):
        A, a, B = model.linearize(xk, uk)
        A_fd, _, B_fd = oracle.linearize(xk, uk)
        step = model.step(xk, uk)
        report.checks += [compare(f"A[{k}] vs FD", A, A_fd, atol, rtol),
                          compare(f"B[{k}] vs FD", B, B_fd, atol, rtol),
                          compare(f"A x + a + B u = step [{k}]", A @ xk + a + B @ uk, step,
                                  affine_atol)]
        points.append((A, a, B))
    batch = model.linearize_trajectory(X, U)
    for i, part in enumerate("AaB"):
        stacked = np.stack([p[i] for p in points])
        report.checks.append(compare(f"linearize_trajectory {part} = pointwise", batch[i],
                                     stacked, traj_atol, traj_rtol))
    return report


# --------------------------------------------------------------------------------------------
# Task maps
# --------------------------------------------------------------------------------------------
def check_taskmap(taskmap, q: Array, *, eps: float = 1e-6, atol: float = 1e-6,
                  rtol: float = 0.0, point_rtol: float = 1e-12) -> Report:
    """Check ``taskmap.values_and_jacobians`` at positions ``q (K, n_q)`` (or ``(n_q,)``).

    Shapes ``(K, dim)``, ``(K, dim, n_q)``; Jacobians against central differences of the
    values (``atol``, ``rtol``); where the map has ``value_and_jacobian``, each point equals
    its row of the batch (``point_rtol``).
    """
    Q = np.atleast_2d(np.asarray(q, dtype=float))
    K, n_q = Q.shape
    report = Report(f"task map {getattr(taskmap, 'name', type(taskmap).__name__)}")
    V, J = taskmap.values_and_jacobians(Q)
    J_fd = numdiff_rows(lambda Z: taskmap.values_and_jacobians(Z)[0], Q, eps)
    report.checks += [compare("values shape", np.shape(V), (K, taskmap.dim), 0.0),
                      compare("J vs FD", J, J_fd, atol, rtol)]
    if hasattr(taskmap, "value_and_jacobian"):
        for k in range(K):
            v, Jk = taskmap.value_and_jacobian(Q[k])
            report.checks += [compare(f"value [{k}] = batch row", v, V[k], 0.0, point_rtol),
                              compare(f"J [{k}] = batch row", Jk, J[k], 0.0, point_rtol)]
    return report


# --------------------------------------------------------------------------------------------
# Cost terms
# --------------------------------------------------------------------------------------------
def check_cost_gradient(value: Callable[[Array], Array], gradient: Array, Z: Array, *,
                        eps: float = 1e-6, atol: float = 1e-6, rtol: float = 1e-6,
                        name: str = "gradient") -> Check:
    """A per-row cost's gradient ``(K, n)`` against central differences of
    ``value: (K, n) -> (K,)`` at ``Z (K, n)`` (states ``X`` for ``l_x``, controls ``U`` for ``l_u``)."""
    return compare(f"{name} vs FD", gradient, numdiff_rows(value, Z, eps), atol, rtol)


def check_cost_term(value: Callable[[Array], Array],
                    derivatives: Callable[[Array], tuple[Array, Array]], Z: Array, *,
                    exact_hessian: bool = False, eps: float = 1e-6, atol: float = 1e-6,
                    rtol: float = 1e-6, what: str = "x", subject: str = "cost term") -> Report:
    """Check a cost term given as callables on rows ``Z (K, n)``.

    ``value(Z) -> (K,)``; ``derivatives(Z) -> (l_z (K, n), l_zz (K, n, n))``. The gradient
    against central differences of ``value``; the (Gauss-Newton) Hessian symmetric and positive
    semi-definite; with ``exact_hessian`` (quadratic terms) also against central differences
    of the gradient. ``what`` names the variable in the report (``x`` or ``u``).
    """
    Z = np.atleast_2d(np.asarray(Z, dtype=float))
    g, H = derivatives(Z)
    report = Report(subject)
    report.checks.append(check_cost_gradient(value, g, Z, eps=eps, atol=atol, rtol=rtol,
                                             name=f"l_{what}"))
    H = np.asarray(H, dtype=float)
    scale = max(1.0, float(np.max(np.abs(H)))) if H.size else 1.0
    report.checks.append(compare(f"l_{what}{what} symmetric", H, np.swapaxes(H, -1, -2),
                                 1e-12 * scale))
    report.checks.append(_psd_check(f"l_{what}{what} positive semi-definite", H, 1e-9))
    if exact_hessian:
        H_fd = numdiff_rows(lambda W: derivatives(W)[0], Z, eps)
        report.checks.append(compare(f"l_{what}{what} vs FD of l_{what}", H, H_fd, atol, rtol))
    return report


def _psd_check(name: str, H: Array, rtol: float) -> Check:
    """Smallest eigenvalue of each symmetric ``H[k] (n, n)`` at least ``-rtol * scale``,
    ``scale = max(1, max |H|)``; the error reported is the most negative eigenvalue's size."""
    if H.size == 0:
        return Check(name, 0.0, 0.0, (), 0.0, rtol, True)
    scale = max(1.0, float(np.max(np.abs(H))))
    low = np.linalg.eigvalsh(0.5 * (H + np.swapaxes(H, -1, -2))).min(axis=-1)
    k = int(np.argmin(low))
    violation = max(0.0, -float(low[k]))
    return Check(name, violation, violation / scale, (k,), 0.0, rtol,
                 bool(violation <= rtol * scale))
