"""Comparisons of floating-point results that agree up to rounding, on any processor.

Two routes to the same numbers (compiled and Python, batched and row by row, raico and Drake or
crocoddyl) round differently where the compiler fuses a multiply-add (FMA), vectorizes a sum in another
order (AVX2, AVX-512) or a library's ``sin`` differs in its last bit. Such differences are a few units
in the last place (eps = 2.2e-16) of the *largest* quantity that went into a result, times the
condition of the computation, times its length; the result itself may be far smaller (a cancellation:
a Jacobian entry near zero, a residual at its target). So a tolerance is relative to the scale of the
compared arrays (or of the inputs, where the result should vanish), never absolute:

    |actual - desired| <= rel * scale,  scale = max(|desired|, given scale)   (the largest entries)

``rel = 1e-9`` (about 4.5e6 eps) covers fused and reordered arithmetic over thousands of steps or a
condition number of 1e4-1e6 with a margin; a real bug (a wrong sign, a missing term, a wrong branch, a
truncated series) differs by far more than that in relative terms, so each comparison can still fail.

Where a computation is longer or worse conditioned than that, or where a test means to be tighter,
the tolerance is the error bound of the computation, :func:`bound` (``c * n_ops * cond * eps``), with
the condition estimated from the inputs (:func:`cond_of`, the factored matrices) and the length counted
from the set-up (steps, sweeps, the order of the factorizations): never a literal below ``REL``
(``tests/test_tolerances.py`` scans for one), and never a literal loosened without its reason.
``make test-portable`` runs the comparisons (marked ``numerics``) under other OpenBLAS kernels and
other instruction sets of the compiled kernels, where such a bound is what still holds.
"""

from __future__ import annotations

import numpy as np

EPS = float(np.finfo(float).eps)
REL = 1e-9  # relative to the compared quantities' scale; see the module docstring
MAX_BOUND = 1e-4  # a bound above this compares nothing a real bug would not pass: choose a better set-up


def bound(n_ops: float, cond: float = 1.0, c: float = 8.0) -> float:
    """The relative tolerance between two routes to one result, from the rounding error bound of the
    computation (Higham, *Accuracy and Stability of Numerical Algorithms*, ch. 3, 7, 10):

        rel = c * n_ops * cond * eps,   eps = 2.2e-16

    - ``n_ops``: the length of the longest chain of dependent roundings to one entry of the result: a
      sum or dot product of ``n`` terms, or a factorization / solve of order ``n``, is ``n`` (gamma_n =
      n eps / (1 - n eps) bounds its backward error); ``k`` such steps, each feeding the next, are
      ``k * n``. Both routes round (in another order, fused or not), so their difference is up to
      twice one route's error.
    - ``cond``: how much the computation amplifies a relative perturbation of its inputs into its
      result: for a solve with, or a factorization of, a matrix its 2-norm condition number
      (:func:`cond_of` of the factored matrices, estimated from the test's inputs), 1 for a
      well-conditioned map (a product of rotations, a polynomial of bounded inputs).
    - ``c``: the constants the count leaves out (the factor 2 of two routes, a library function's few
      units in the last place, the constant of Cholesky's bound) with a margin: 8 by default.

    The bound is a worst case (rounding errors that all add up); a real bug (a missing term, a wrong
    sign, a wrong branch) changes a result by far more, so a comparison to it can still fail. A bound
    above ``MAX_BOUND`` raises ``ValueError``: the set-up is too ill-conditioned to compare two routes
    on it (choose a better-conditioned one)."""
    if not (n_ops >= 1 and cond >= 1 and c > 0):
        raise ValueError(f"bound needs n_ops >= 1, cond >= 1, c > 0 (got {n_ops}, {cond}, {c})")
    rel = c * n_ops * cond * EPS
    if not rel <= MAX_BOUND:
        raise ValueError(f"rounding bound {rel:.3g} (n_ops {n_ops:g}, condition {cond:.3g}) is above "
                         f"{MAX_BOUND:g}: the set-up is too ill-conditioned to compare two routes on it")
    return rel


def cond_of(*matrices) -> float:
    """The largest 2-norm condition number (``numpy.linalg.cond``) of ``matrices``: square arrays or
    stacks of them ``(..., n, n)``; matrices with a non-finite entry are left out (1.0 if none is left).
    A singular one gives ``inf`` (and :func:`bound` refuses it)."""
    worst = 1.0
    for m in matrices:
        m = np.asarray(m, dtype=float)
        m = m.reshape(-1, *m.shape[-2:])
        m = m[np.all(np.isfinite(m), axis=(1, 2))]
        if len(m):
            worst = max(worst, float(np.max(np.linalg.cond(m))))
    return worst


def scale_of(*arrays) -> float:
    """The largest magnitude of the finite entries of ``arrays`` (0.0 if there are none)."""
    m = 0.0
    for a in arrays:
        a = np.abs(np.asarray(a, dtype=float))
        a = a[np.isfinite(a)]
        if a.size:
            m = max(m, float(a.max()))
    return m


def close(actual, desired, rel: float = REL, scale: float = 0.0) -> bool:
    """True if ``actual`` equals ``desired`` (same shape, non-finite entries equal) up to
    ``rel * max(scale_of(desired), scale)`` in every entry."""
    actual, desired = np.asarray(actual, dtype=float), np.asarray(desired, dtype=float)
    if actual.shape != desired.shape:
        return False
    same_nonfinite = np.array_equal(~np.isfinite(actual), ~np.isfinite(desired)) and np.array_equal(
        actual[~np.isfinite(actual)], desired[~np.isfinite(desired)])
    if not same_nonfinite:
        return False
    tol = rel * max(scale_of(desired), scale)
    ok = np.isfinite(desired)
    return bool(np.all(np.abs(actual[ok] - desired[ok]) <= tol))


def assert_close(actual, desired, rel: float = REL, scale: float = 0.0, err_msg: str = "") -> None:
    """Assert :func:`close`, naming the largest difference and the tolerance it missed."""
    if close(actual, desired, rel, scale):
        return
    a, d = np.asarray(actual, dtype=float), np.asarray(desired, dtype=float)
    if a.shape != d.shape:
        raise AssertionError(f"shapes differ: {a.shape} against {d.shape} {err_msg}".rstrip())
    with np.errstate(invalid="ignore"):
        diff = float(np.nanmax(np.abs(a - d))) if a.size else 0.0
    tol = rel * max(scale_of(d), scale)
    raise AssertionError(f"largest difference {diff:.3g} > {tol:.3g} (rel {rel:g} of scale "
                         f"{max(scale_of(d), scale):.3g}) {err_msg}".rstrip())
