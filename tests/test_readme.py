"""The crocoddyl baseline's page (docs/crocoddyl.md): its tolerances are the tests' and it types no measured
number (those come from the generated blocks, ``scripts/readme_numbers.py``)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _section(start: str, end: str) -> str:
    text = (ROOT / "docs" / "crocoddyl.md").read_text()
    i = text.index(start)
    return text[i:text.index(end, i)]


def test_crocoddyl_tolerances_quoted_are_the_ones_tested():
    text = " ".join(_section("# Baseline: crocoddyl", "## crocoddyl's own problems").split())
    rollout = re.search(r"rollouts agree with raico's analytic model to (\S+)", text).group(1)
    cost = re.search(r"costs of the same trajectory to (\S+) relative", text).group(1)
    tests = (ROOT / "tests" / "planning" / "test_crocoddyl.py").read_text()
    assert f"np.max(np.abs(Xc - X)) <= {rollout} * max(1.0, np.max(np.abs(X)))" in tests, rollout
    assert f"abs(cp.cost(X, U) - c) <= {cost} * c" in tests, cost


def test_crocoddyl_section_types_no_measured_cost_or_time():
    """A wall time (``0.8 s``, ``70 ms``), a cost ratio (``139x``) or a median cost (``at a median 5850``,
    ``ends at 474``) typed into prose goes stale at the next run; the generated tables hold them."""
    text = " ".join(_section("# Baseline: crocoddyl", "## crocoddyl's own problems").split())
    measured = re.findall(r"\b\d+(?:\.\d+)? ?(?:ms|s)\b|\(\d+(?:\.\d+)?x\b|\bat (?:a median )?\d{2,}\b|"
                          r"\bends at \d", text)
    assert measured == [], measured
