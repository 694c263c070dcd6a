"""bench/al_diagnosis.py: one line per trial of the default plan, the model's linear term along it, the methods it
wraps put back."""

from __future__ import annotations

import pytest


@pytest.mark.slow
@pytest.mark.compiled
def test_the_trials_are_reported_and_the_solver_is_left_as_it_was():
    from bench.al_diagnosis import diagnose
    from raico.planning.aico import solve as aico_solve
    from raico.planning.aico import steps

    before = (steps.RobustStep._trial, steps.RobustStep.__call__, aico_solve._aico)
    lines: list[str] = []
    out = diagnose("arm3-mjcf-reach", 3, say=lines.append)
    assert out["iterations"] <= 3 and out["status"] and len(lines) >= 2
    assert all("g.d" in line and "penalty" in line for line in lines[:-1])
    assert (steps.RobustStep._trial, steps.RobustStep.__call__, aico_solve._aico) == before
