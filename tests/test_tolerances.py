"""No test compares floating-point results with a tolerance below 1e-9, absolute or relative: rounding
differs between processors (FMA, AVX-512, a library's last bit), so such a test passes here and fails
elsewhere. Tolerances are relative to the compared quantities' scale (``tests/tolerance.py``), at 1e-9."""

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
            re.compile(rf"^\s*assert\b.*[<>]=?.*[-+]\s*{LIT}(?!\s*\*)"),
            # a relative one: rtol= / rel= / rel_tol=, or an absolute one as a multiple of the scale
            re.compile(rf"\b(?:rtol|rel|rel_tol)\s*=\s*{LIT}"),
            re.compile(rf"\b(?:atol|abs)\s*=\s*{LIT}(?=\s*\*)")]


def tight_tolerances(text: str) -> list[str]:
    """``line: text`` of each tolerance below 1e-9 in the source ``text``."""
    found = []
    for i, line in enumerate(text.splitlines(), 1):
        code = line.split("#", 1)[0]
        for pat in PATTERNS:
            for m in pat.finditer(code):
                if float(m.group(1)) < 1e-9:
                    found.append(f"{i}: {line.strip()}")
    return sorted(set(found))


def test_no_test_uses_a_tolerance_below_1e_9():
    found = {str(p.relative_to(TESTS)): tight_tolerances(p.read_text()) for p in sorted(TESTS.rglob("test_*.py"))
             if p.name != Path(__file__).name}
    assert len(found) > 40, "the scan sees the tests in their folders"
    found = {k: v for k, v in found.items() if v}
    assert found == {}, found


def test_the_scan_sees_each_form():
    tight = "1e-" + "12"   # the forms the scan must catch, spelled so that no source line is one of them
    src = (f"np.testing.assert_allclose(a, b, atol={tight})\nassert x == pytest.approx(0, abs=1e-20)\n"
           f"assert err < 1e-10\nassert c >= d - {tight}\nassert np.allclose(a, b, rtol={tight})\n"
           f"assert x == pytest.approx(y, rel={tight})\nassert np.allclose(a, b, rtol=0, atol={tight} * scale)\n"
           "ok = np.allclose(a, b, atol=1e-9)\nok = np.allclose(a, b, rtol=1e-9, atol=1e-9 * scale)\n"
           "if tol > 1e-10:\nILQGOptions(tol_rel=1e-13)\n")
    assert [s.split(":")[0] for s in tight_tolerances(src)] == ["1", "2", "3", "4", "5", "6", "7"]


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
