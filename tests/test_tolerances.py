"""No test compares floating-point results with a literal tolerance below 1e-9, absolute or relative:
rounding differs between processors (FMA, AVX-512, OpenBLAS's kernels, a library's last bit), so such a
test passes here and fails elsewhere. Tolerances are relative to the compared quantities' scale
(``tests/tolerance.py``), at 1e-9; a tighter (or a looser) one is the error bound of its computation,
``bound(n_ops, cond)``, which says where it comes from. ``make test-portable`` runs the comparisons
under other OpenBLAS kernels and instruction sets."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from tests.tolerance import EPS, MAX_BOUND, REL, assert_close, bound, close, cond_of

TESTS = Path(__file__).resolve().parent
LIT = r"(\d+(?:\.\d+)?e-\d+)"
EPS_NAME = r"(?:EPS|np\.finfo\(\s*(?:float|np\.float64)?\s*\)\.eps)"
# a literal below 1e-9 as a tolerance, absolute or a multiple of a scale (``1e-12 * scale`` is as tight):
# atol= / abs= / rtol= / rel= / rel_tol= / tol=, or the bound of an assert's comparison or of its offset
PATTERNS = [re.compile(rf"\b(?:atol|abs|rtol|rel|rel_tol|tol)\s*=\s*{LIT}"),
            re.compile(rf"^\s*assert\b.*[<>]=?\s*-?\s*{LIT}"),
            re.compile(rf"^\s*assert\b.*[<>]=?.*[-+]\s*{LIT}")]
# a tolerance spelled as a multiple of eps (``16 * EPS``, ``np.finfo(float).eps * 4``): below 1e-9 unless
# the multiple is above 4.5e6; written so, it states no bound (bound(n_ops, cond) does)
EPS_MULTIPLES = [re.compile(rf"(\d+(?:\.\d+)?(?:e-?\d+)?)\s*\*\s*{EPS_NAME}\b"),
                 re.compile(rf"{EPS_NAME}\s*\*\s*(\d+(?:\.\d+)?(?:e-?\d+)?)")]


def tight_tolerances(text: str) -> list[str]:
    """``line: text`` of each literal tolerance below 1e-9 in the source ``text`` (a number, or a number
    times eps); a tolerance from ``bound(...)`` has no literal and passes."""
    found = []
    for i, line in enumerate(text.splitlines(), 1):
        code = line.split("#", 1)[0]
        for pat in PATTERNS:
            for m in pat.finditer(code):
                if float(m.group(1)) < REL:
                    found.append(f"{i}: {line.strip()}")
        for pat in EPS_MULTIPLES:
            for m in pat.finditer(code):
                if float(m.group(1)) * EPS < REL:
                    found.append(f"{i}: {line.strip()}")
    return sorted(set(found), key=lambda f: int(f.split(":")[0]))


def test_no_test_uses_a_tolerance_below_1e_9():
    found = {str(p.relative_to(TESTS)): tight_tolerances(p.read_text()) for p in sorted(TESTS.rglob("test_*.py"))
             if p.name != Path(__file__).name}
    assert len(found) > 40, "the scan sees the tests in their folders"
    found = {k: v for k, v in found.items() if v}
    assert found == {}, found


def test_the_scan_sees_each_form():
    tight = "1e-" + "12"   # the forms the scan must catch, spelled so that no source line is one of them
    eps = "np.finfo(float)." + "eps"
    src = (f"np.testing.assert_allclose(a, b, atol={tight})\nassert x == pytest.approx(0, abs=1e-20)\n"
           f"assert err < 1e-10\nassert c >= d - {tight}\nassert np.allclose(a, b, rtol={tight})\n"
           f"assert x == pytest.approx(y, rel={tight})\nassert np.allclose(a, b, rtol=0, atol={tight} * scale)\n"
           f"assert np.max(np.abs(a - b)) <= 1e-10 * max(1.0, np.max(np.abs(b)))\n"
           f"np.testing.assert_allclose(a, b, rtol=16 * {'EP' + 'S'})\n"
           f"np.testing.assert_allclose(a, b, rtol=0, atol=16 * {eps} * scale)\n"
           f"assert err < {eps} * 1000\ntol = 1e-10\n"
           "ok = np.allclose(a, b, atol=1e-9)\nok = np.allclose(a, b, rtol=1e-9, atol=1e-9 * scale)\n"
           f"if tol > 1e-10:\nILQGOptions(tol_rel={'1e-' + '13'})\nassert err < 1e7 * EPS\n"   # a stopping rule
           "assert_close(a, b, rel=bound(4))\nassert err <= bound(n, cond_of(K)) * scale\n")
    assert [s.split(":")[0] for s in tight_tolerances(src)] == [str(i) for i in range(1, 13)]


def test_the_bound_grows_with_length_and_condition_and_refuses_an_ill_conditioned_set_up():
    assert bound(1) == 8 * EPS and bound(10, 100.0) == 8 * 10 * 100 * EPS and bound(10, c=2.0) == 20 * EPS
    K = np.diag([1.0, 1e-6])
    assert cond_of(K) == pytest.approx(1e6) and cond_of(np.stack([np.eye(2), K])) == pytest.approx(1e6)
    assert cond_of(np.array([[np.nan, 0.0], [0.0, 1.0]])) == 1.0     # non-finite matrices left out
    with pytest.raises(ValueError, match="too ill-conditioned"):
        bound(100, cond_of(np.diag([1.0, 1e-12])))
    with pytest.raises(ValueError, match="too ill-conditioned"):
        bound(1, cond_of(np.zeros((2, 2))))                            # singular: inf
    assert bound(1, MAX_BOUND / (8 * EPS)) == pytest.approx(MAX_BOUND)


def test_close_is_relative_to_the_scale_and_still_fails_on_a_real_difference():
    rng = np.random.default_rng(0)
    big = 1e6 * rng.standard_normal(50)
    assert close(big * (1 + 1e3 * np.finfo(float).eps), big)   # rounding of a large quantity
    assert not close(big + 1e-6 * np.abs(big).max(), big)       # a relative difference of 1e-6
    tiny = np.array([1e-12, 0.0, -3e-13])
    assert close(tiny + 1e-17, tiny, scale=1.0)     # a vanishing result: the inputs' scale counts
    assert not close(tiny + 1e-17, tiny)            # ... without it, its own scale
    assert not close(np.array([1.0, np.nan]), np.array([1.0, 0.0]))
    assert close(np.array([np.inf, 1.0]), np.array([np.inf, 1.0]))
    assert not close(np.zeros(2), np.zeros(3))
    with pytest.raises(AssertionError, match="largest difference"):
        assert_close([1.0 + 10 * REL], [1.0])
