"""The flop count of the bench (bench/flops.py): the formulas' leading term, the repeats' share, and
the rate columns."""

from __future__ import annotations

import math

from bench.flops import flop_fields, sweep_flops


def test_leading_term_of_a_sweep_step():
    """For a state of 2 n and n controls one step costs, to leading order, (11/3 + 7/3 + 5/2 + 25/24 + 2/3
    + 3/8) N^3 = 254/3 n^3 flops in the semi-implicit Euler block form (forward, V*, the backward's block
    products, its control part, two beliefs, the dynamics' relinearization) and 365/3 n^3 with the dense
    products."""
    n = 4096
    f = sweep_flops(2 * n, n, 1)
    assert math.isclose(f["per_step"] / n ** 3, 254 / 3, rel_tol=1e-3)
    assert math.isclose(sum(f["parts"].values()), f["per_step"], rel_tol=1e-9)
    assert math.isclose(f["parts"]["forward"], 11 / 3 * (2 * n) ** 3, rel_tol=1e-9)
    d = sweep_flops(2 * n, n, 1, block=False)
    assert math.isclose(d["per_step"] / n ** 3, 365 / 3, rel_tol=1e-3)
    assert d["parts"]["forward"] == f["parts"]["forward"] and d["parts"]["beliefs"] == f["parts"]["beliefs"]


def test_iteration_counts_steps_and_repeats():
    f0, f = sweep_flops(12, 6, 100), sweep_flops(12, 6, 100, repeats=50)
    per_repeat = f0["parts"]["dynamics relinearization"] + f0["parts"]["beliefs"] / 2
    assert f0["per_iteration"] == 100 * f0["per_step"]
    assert math.isclose(f["per_iteration"] - f0["per_iteration"], 50 * per_repeat, rel_tol=1e-9)


def test_rate_columns():
    row = flop_fields(64, 32, 100, 0.25, 50.0, repeats=10)
    assert math.isclose(row["gflops"], row["flops_per_iteration"] / 0.25 / 1e9, rel_tol=1e-9)
    assert math.isclose(row["ratio_to_dgemm"], row["gflops"] / 50.0, rel_tol=1e-9)


def test_the_backward_sweep_alone_is_timed_on_its_own_flops(tmp_path):
    """The sweeps' own rate: T backward messages of the chain (block form), counted by the formulas."""
    from bench import model_files as mf
    from bench.flops import backward_sweep_rate
    from stages.plan.stage import PlanConfig, build_problem

    _, _, problem, _, _ = build_problem(PlanConfig(problem=str(mf.chain_problem(3, tmp_path)), bounds="none").normalized())
    r = backward_sweep_rate(problem, reps=2)
    assert r["block"] and r["seconds"] > 0
    assert r["flops"] == sweep_flops(6, 3, problem.T)["parts"]["backward"] * problem.T
    assert r["gflops"] == r["flops"] / r["seconds"] / 1e9
