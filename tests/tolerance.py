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
"""

from __future__ import annotations

import numpy as np

EPS = float(np.finfo(float).eps)
REL = 1e-9  # relative to the compared quantities' scale; see the module docstring


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
