"""The flop count of the bench (bench/flops.py) against a literal count: the compiled sweep's loops run as scalar
Python on counted numbers (tests/bench/sweep_count.py), each operation counted where it happens, on small sizes;
each part's cubic term (the formulas' leading term) from those counts, and the rate columns."""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest

from bench.flops import flop_fields, sweep_flops
from tests.bench import sweep_count as sc
from tests.tolerance import REL, assert_close

SIZES = (1, 2, 3, 4, 5)   # joints n: N = 2 n states, m = n controls, h = n velocity rows


def _differences(values, order: int):
    for _ in range(order):
        values = [b - a for a, b in zip(values, values[1:])]
    return values


def _cubic_term(counts) -> Fraction:
    """The n^3 coefficient of the cubic through ``counts`` at n = 1, 2, ... (its third difference over 6), after
    checking that they lie on one cubic (their fourth difference 0: the count has no higher term)."""
    assert _differences(list(counts), 4) == [0], counts
    return Fraction(_differences(list(counts), 3)[0], 6)


def _formula_cubic_term(part: str, block: bool = True) -> float:
    values = [sweep_flops(2 * n, n, 1, block=block)["parts"][part] for n in SIZES]
    return _differences(values, 3)[0] / 6


def test_the_counted_loops_compute_the_messages():
    """The scalar loops are the sweep's step (else their count would be of something else): each part's result
    equals numpy's dense formulas to rounding (a factorization of a matrix of condition below 1e3: REL)."""
    d = sc.step_data(3)
    n, m, A, B, q = d["n"], d["m"], d["A"], d["B"], d["q"]
    _, out = sc.count("forward", d)
    P, p = d["SA"][:, :n] + d["RA"][:, :n], d["SA"][:, n] + d["RA"][:, n]
    S = A @ np.linalg.solve(P, A.T) + d["Qbar"]
    Si = np.linalg.inv(S)
    assert_close(out, np.column_stack([Si, Si @ (A @ np.linalg.solve(P, p) + d["ae"])]))
    Vs = np.linalg.solve(np.eye(n) + q * d["P1"][:, :n], d["P1"])
    G = Vs @ d["Ct"]
    FB, FA = B.T @ G, A.T @ G[:, m:]
    L = np.linalg.cholesky(FB[:, :m] + d["H"])
    rhs = FB[:, m:].copy()
    rhs[:, n] += d["hv"]
    K = np.linalg.solve(L, rhs)
    V = FA - K[:, :n].T @ K
    for block in (True, False):
        _, (v, z) = sc.count("backward", d, block)
        assert_close(v, np.column_stack([(V[:, :n] + V[:, :n].T) / 2, V[:, n]]))
        assert_close(z, np.linalg.solve(L.T, K))
        _, (Qb, ae) = sc.count("relinearization", d, block)
        assert_close(Qb, B @ d["Hinv"] @ B.T + q * np.eye(n))
        assert_close(ae, d["a"] + B @ d["Hinv"] @ d["hv"])
    Ba = d["SA"] + d["VA"] + d["RA"]
    _, b = sc.count("belief", d)
    assert_close(b, np.linalg.solve(Ba[:, :n], Ba[:, n]))


def test_the_counted_kernels_take_the_textbook_counts():
    """The loops' own counts on a 3 x 3 case, by hand: Cholesky 3 square roots, 3 reciprocals, 5 multiply-adds
    (rows 1, 2 from row 0: 2 + 1, row 2 from row 1: 1, as (p, j) pairs (0,1), (0,2), (0,1)...) and 3 scalings; a
    2 x 3 by 3 x 2 product 2 * 2 * 3 multiply-adds."""
    A = sc.mat(np.array([[4.0, 2.0, 0.4], [2.0, 5.0, 1.0], [0.4, 1.0, 3.0]]))
    sc.Tally.ops = 0
    sc.chol_u(A, 3)
    # i = 1: p = 0, j = 1..2 (2 multiply-adds); i = 2: p = 0, 1, j = 2 (2); 3 sqrt, 3 reciprocals; scalings: 2 + 1
    assert sc.Tally.ops == 2 * 2 + 2 * 2 + 3 + 3 + 3
    assert_close(np.triu(sc.arr(A)), np.linalg.cholesky(np.array([[4.0, 2.0, 0.4], [2.0, 5.0, 1.0],
                                                                   [0.4, 1.0, 3.0]])).T)
    sc.Tally.ops = 0
    C = sc.gemm(sc.mat(np.ones((2, 3))), sc.mat(np.ones((3, 2))), 2, 3, 2)
    assert sc.Tally.ops == 2 * 2 * 3 * 2 and sc.arr(C).tolist() == [[3.0, 3.0], [3.0, 3.0]]


@pytest.mark.parametrize("part, counted, block", [
    ("forward", "forward", True), ("backward", "backward", True), ("backward", "backward", False),
    ("beliefs", "belief", True), ("dynamics relinearization", "relinearization", True),
    ("dynamics relinearization", "relinearization", False)])
def test_each_part_of_the_formula_has_the_cubic_term_of_the_counted_loops(part, counted, block):
    """The formulas of bench/flops.py against the literal count of the loops they describe, part by part: the same
    n^3 coefficient (N = 2 n, m = n; the beliefs are two per step). The counts are integers on an exact cubic; the
    formula's third difference is of a few floats below 1e5 (rounding below 1e-10 of it: REL)."""
    counts = [sc.count(counted, sc.step_data(n), block)[0] * (2 if part == "beliefs" else 1) for n in SIZES]
    literal = _cubic_term(counts)
    assert math.isclose(_formula_cubic_term(part, block), float(literal), rel_tol=REL), (part, block, literal)


def test_the_whole_step_against_the_counted_loops():
    """A step with the relinearizations in the sweeps: forward, backward and two beliefs, 79 n^3 (the semi-implicit
    Euler block form; 111 n^3 with the dense products); without them (the robust schedule) the backward message
    alone, 47 n^3; each the sum of the counted loops' cubic terms."""
    block = {p: _cubic_term([sc.count(p, sc.step_data(n))[0] for n in SIZES]) for p in ("forward", "backward", "belief")}
    dense = _cubic_term([sc.count("backward", sc.step_data(n), False)[0] for n in SIZES])
    assert block["forward"] + block["backward"] + 2 * block["belief"] == 79
    assert block["forward"] + dense + 2 * block["belief"] == 111 and block["backward"] == 47
    n = 4096
    assert math.isclose(sweep_flops(2 * n, n, 1)["per_step"] / n ** 3, 79, rel_tol=1e-3)
    assert math.isclose(sweep_flops(2 * n, n, 1, block=False)["per_step"] / n ** 3, 111, rel_tol=1e-3)
    assert math.isclose(sweep_flops(2 * n, n, 1, forward=False)["per_step"] / n ** 3, 47, rel_tol=1e-3)


def test_iteration_counts_steps_and_repeats():
    f0, f = sweep_flops(12, 6, 100), sweep_flops(12, 6, 100, repeats=50)
    per_repeat = f0["parts"]["dynamics relinearization"] + f0["parts"]["beliefs"] / 2
    assert f0["per_iteration"] == 100 * f0["per_step"]
    assert math.isclose(f["per_iteration"] - f0["per_iteration"], 50 * per_repeat, rel_tol=1e-9)
    b = sweep_flops(12, 6, 100, repeats=50, forward=False)   # the robust schedule: T backward messages
    assert b["per_iteration"] == 100 * f0["parts"]["backward"]


def test_rate_columns():
    row = flop_fields(64, 32, 100, 0.25, 50.0, repeats=10)
    assert math.isclose(row["gflops"], row["flops_per_iteration"] / 0.25 / 1e9, rel_tol=1e-9)
    assert math.isclose(row["ratio_to_dgemm"], row["gflops"] / 50.0, rel_tol=1e-9)


def test_the_backward_sweep_alone_is_timed_on_its_own_flops(tmp_path):
    """The sweeps' own rate: T backward messages of the chain (block form), counted by the formulas."""
    from bench import model_files as mf
    from bench.flops import backward_sweep_rate
    from raico.stages.plan.stage import PlanConfig, build_problem

    _, _, problem, _, _ = build_problem(PlanConfig(problem=str(mf.chain_problem(3, tmp_path)), bounds="none").normalized())
    r = backward_sweep_rate(problem, reps=2)
    assert r["block"] and r["seconds"] > 0
    assert r["flops"] == sweep_flops(6, 3, problem.T)["parts"]["backward"] * problem.T
    assert r["gflops"] == r["flops"] / r["seconds"] / 1e9
