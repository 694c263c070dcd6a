"""The crocoddyl-problems page: targets judged from the measured rows, one table row per solver."""

from __future__ import annotations

from bench.crocoddyl_problems import markdown_page, targets


def _row(solver, cost, wall, per_it, t_ref, status="converged", croc=None, execution="ok"):
    return {"solver": solver, "status": status, "iterations": 10, "final_cost": cost, "solver_cost": cost,
            "crocoddyl_cost": croc, "wall_time_s": wall, "per_iteration_s": per_it, "hand_error_plan_m": 0.003,
            "message": "m", "note": "", "time_to_1.1x_reference_s": t_ref, "execution_status": execution,
            "execution_reason": "", "tracking_rmse_rad": 0.01, "hand_error_executed_m": 0.0081}


def _result():
    rows = [_row("R-AICO a=1 fixed", 8.5, 0.5, 0.050, 0.4),
            _row("R-AICO a=1 adaptive", 3.7, 0.2, 0.001, 0.1),
            _row("AICO", None, 0.3, 0.3, None, status="diverged"),
            _row("FDDP (x0 held)", 3.698, 0.15, 0.002, 0.05, croc=3.698),
            _row("crocoddyl's example (FDDP, cos/sin joints)", 8.179, 0.27, 0.0037, None, croc=8.125)]
    return {"problem": "kinova", "file": "raico/problems/crocoddyl/kinova_reach.toml", "example": "its log",
            "reference_cost": 8.125, "rows": rows}


def test_targets_compare_raico_with_fddp_and_crocoddyls_run():
    t = targets(_result())
    fixed, adaptive = t["R-AICO a=1 fixed"], t["R-AICO a=1 adaptive"]
    assert fixed["per_iteration_ratio_to_fddp"] == 25.0 and not fixed["per_iteration_met"]
    assert adaptive["per_iteration_ratio_to_fddp"] == 0.5 and adaptive["per_iteration_met"]
    assert not fixed["cost_in_time_met"] and adaptive["cost_in_time_met"]  # 0.4 s and 0.1 s against 0.27 s
    res = _result()
    res["rows"] = res["rows"][:-1]  # no run of crocoddyl's example: the timed target cannot be judged
    assert targets(res)["R-AICO a=1 fixed"]["cost_in_time_met"] is None


def test_page_has_one_row_per_solver_with_its_numbers():
    res = _result()
    res["targets"] = targets(res)
    page = markdown_page({"date": "d", "machine": "m", "problems": [res]})
    lines = page.splitlines()
    assert sum(line.startswith("| R-AICO") or line.startswith("| AICO") or line.startswith("| FDDP")
               or line.startswith("| crocoddyl") for line in lines) == 5
    assert "| FDDP (x0 held) | converged | 10 | 3.698 | 3.698 | 0.150 | 2.00 | 3.00 | ok | 0.01 | 8.10 |" in lines
    assert "| AICO | diverged | 10 | - |" in page
    assert "25.0x: missed" in page and "0.5x: met" in page


def test_a_diverged_raico_run_has_no_cost_ratio_and_its_page_says_diverged():
    res = _result()
    res["rows"][0] = _row("R-AICO a=1 fixed", None, 0.5, 0.050, None, status="diverged")
    t = targets(res)
    assert t["R-AICO a=1 fixed"]["cost_ratio_to_reference"] is None
    assert t["R-AICO a=1 adaptive"]["cost_ratio_to_reference"] == 3.7 / 8.125
    res["targets"] = t
    assert "| R-AICO a=1 fixed | diverged | 10 | - |" in markdown_page({"date": "d", "machine": "m", "problems": [res]})
