"""No test compares floating-point results with an absolute tolerance below 1e-9: rounding differs
between processors (FMA, AVX-512, a library's last bit), so such a test passes here and fails elsewhere.
Tolerances are relative to the compared quantities' scale (``tests/tolerance.py``)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from tests.tolerance import REL, assert_close, close

TESTS = Path(__file__).resolve().parent
LIT = r"(\d+(?:\.\d+)?e-\d+)"
# a literal below 1e-9 as an absolute tolerance: atol= / abs= / a bound of a comparison or an
# assert's offset, not multiplied by a scale (``1e-12 * scale`` is relative)
PATTERNS = [re.compile(rf"\b(?:atol|abs)\s*=\s*{LIT}(?!\s*\*)"),
            re.compile(rf"^\s*assert\b.*[<>]=?\s*-?\s*{LIT}(?!\s*\*)"),
            re.compile(rf"^\s*assert\b.*[<>]=?.*[-+]\s*{LIT}(?!\s*\*)")]


def absolute_tolerances(text: str) -> list[str]:
    """``line: text`` of each absolute tolerance below 1e-9 in the source ``text``."""
    found = []
    for i, line in enumerate(text.splitlines(), 1):
        code = line.split("#", 1)[0]
        for pat in PATTERNS:
            for m in pat.finditer(code):
                if float(m.group(1)) < 1e-9:
                    found.append(f"{i}: {line.strip()}")
    return sorted(set(found))


def test_no_test_uses_an_absolute_tolerance_below_1e_9():
    found = {str(p.relative_to(TESTS)): absolute_tolerances(p.read_text()) for p in sorted(TESTS.rglob("test_*.py"))
             if p.name != Path(__file__).name}
    assert len(found) > 40, "the scan sees the tests in their folders"
    found = {k: v for k, v in found.items() if v}
    assert found == {}, found


def test_the_scan_sees_each_form():
    src = ("np.testing.assert_allclose(a, b, atol=1e-12)\nassert x == pytest.approx(0, abs=1e-20)\n"
           "assert err < 1e-10\nassert c >= d - 1e-12\nassert e <= 1e-12 * scale\nok = np.allclose(a, b, atol=1e-9)\n"
           "if tol > 1e-10:\n")
    assert [s.split(":")[0] for s in absolute_tolerances(src)] == ["1", "2", "3", "4"]


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
