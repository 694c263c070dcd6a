"""Evaluation as pure functions: summaries and every claim criterion on synthetic inputs whose
verdict is known (one that should hold, one that should not)."""

import math

import numpy as np
import pytest

from stages.evaluate.claims import CLAIMS, evaluate_claims
from stages.evaluate.stage import iterations_to
from stages.evaluate.summary import largest_via_error, summarize


def S_(label, final, diverged=0, runs=10, first=None, via=0.001, ratio=0.01, worst=None):
    """A synthetic summary row."""
    return {"label": label, "runs": runs, "diverged": diverged, "converged": 0, "final_cost_median": final,
            "first_cost_median": first if first is not None else 10 * final, "cost_ratio_median": ratio,
            "cost_ratio_max": ratio, "final_cost_max": worst if worst is not None else final,
            "max_via_error_median": via, "wall_time_median_s": 1.0}


def table(**rows):
    names = {"ilqg": "iLQG", "aico": "AICO", "r1": "R-AICO a=1", "r10": "R-AICO a=10",
             "abl": "AICO (no sweep relinearization)"}
    return {names[k]: S_(names[k], **v) if isinstance(v, dict) else S_(names[k], v) for k, v in rows.items()}


CASES = [
    ("raico_converges", table(ilqg=100, aico=100, r1=120, r10=150), True),
    ("raico_converges", table(ilqg=100, aico=100, r1=120, r10=300), False),
    ("raico_converges", table(ilqg=100, aico=100, r1={"final": 100, "diverged": 1}, r10=100), False),
    ("aico_unstable", table(ilqg=100, aico={"final": 100, "diverged": 2}, r1=100), True),
    ("aico_unstable", table(ilqg=100, aico=300, r1=100), True),
    ("aico_unstable", table(ilqg=100, aico=110, r1=100), False),
    ("aico_unstable_without_relinearization", table(abl={"final": 100, "worst": 500}, r1=100), True),
    ("aico_unstable_without_relinearization", table(abl={"final": 100, "worst": 150}, r1=100), False),
    ("aico_fails", table(aico={"final": 100, "diverged": 5}, r1=100), True),
    ("aico_fails", table(aico={"final": 100, "diverged": 4}, r1=100), False),
    ("aico_fails", table(aico=1001, r1=100), True),
    ("ilqg_stalls", table(ilqg=201, r1=100), True),
    ("ilqg_stalls", table(ilqg=199, r1=100), False),
    ("all_converge_aico_fastest", table(ilqg={"final": 100, "first": 50}, aico={"final": 100, "first": 20}), True),
    ("all_converge_aico_fastest", table(ilqg={"final": 100, "first": 10}, aico={"final": 100, "first": 20}), False),
    ("all_converge_aico_fastest", table(ilqg={"final": 300, "first": 50}, aico={"final": 100, "first": 20}), False),
    ("raico_reaches_aico_not", table(r1={"final": 1, "via": 0.005}, aico={"final": 1, "via": 0.05}), True),
    ("raico_reaches_aico_not", table(r1={"final": 1, "via": 0.005}, aico={"final": 1, "via": 0.005}), False),
    ("raico_reaches_aico_not", table(r1={"final": 1, "via": 0.02}, aico={"final": 1, "via": 0.05}), False),
]


@pytest.mark.parametrize("name, S, holds", CASES)
def test_claim_verdicts_on_synthetic_summaries(name, S, holds):
    claim, criterion, measured, ok = CLAIMS[name](S, [])
    assert ok is holds, (name, measured)
    assert claim and criterion and measured


def test_every_claim_has_a_case_each_way():
    for name in CLAIMS:
        if name == "cog_support":
            continue
        verdicts = {h for n, _, h in CASES if n == name}
        assert verdicts == {True, False}, name


def test_cog_support_needs_every_step_of_every_run_inside():
    inside = [{"cog_inside_fraction": 1.0, "cog_min_margin": 0.01, "torque_saturation": 0.0,
               "rmse_planned_executed": 0.01}] * 3
    assert CLAIMS["cog_support"]({}, inside)[3] is True
    one_out = inside[:2] + [{**inside[0], "cog_inside_fraction": 0.98, "cog_min_margin": -0.002}]
    assert CLAIMS["cog_support"]({}, one_out)[3] is False
    assert CLAIMS["cog_support"]({}, [])[3] is False


def test_evaluate_claims_rows():
    rows = evaluate_claims(("ilqg_stalls",), table(ilqg=500, r1=100), [], "figX")
    assert rows == [{"figure": "figX", "claim": "iLQG stalls on the analytic model",
                     "criterion": "iLQG's median final cost exceeds 2x the best R-AICO's",
                     "measured": "iLQG final median 500; best R-AICO 100", "verdict": "holds"}]


def test_summary_medians_and_counts():
    runs = [{"status": "converged", "metrics": {"final_cost": 1.0, "cost_ratio": 0.1, "first_iteration_cost": 5.0,
                                                "wall_time_s": 2.0, "via_point_errors": {"a@1": 0.1, "r_sole@max": 9}}},
            {"status": "diverged", "metrics": {"final_cost": math.inf, "cost_ratio": None,
                                               "via_point_errors": {"a@1": None}}},
            {"status": "max-iterations", "metrics": {"final_cost": 3.0, "cost_ratio": 0.3, "first_iteration_cost": 7.0,
                                                     "wall_time_s": 4.0, "via_point_errors": {"a@1": 0.3}}}]
    s = summarize("X", runs)
    assert (s["runs"], s["diverged"], s["converged"]) == (3, 1, 1)
    assert s["final_cost_median"] == 2.0 and s["final_cost_max"] == math.inf  # the diverged run counts
    assert s["cost_ratio_median"] == pytest.approx(0.2) and s["first_cost_median"] == 6.0
    assert s["max_via_error_median"] == pytest.approx(0.2)  # of the finite 0.1, 0.3: the sole is left out
    assert math.isnan(largest_via_error({"via_point_errors": {"r_sole@max": 1.0}}))


def test_iterations_to_relative_change():
    assert iterations_to(np.array([100.0, 50.0, 49.99, 49.98])) == 3
    assert iterations_to(np.array([100.0, 50.0, 25.0])) is None
    assert iterations_to(np.array([1.0])) is None
