"""The joint-scaling bench: a solver that cannot take a chain is said (why, which size), not dropped; a run that
diverged keeps its row, labelled, out of the exponents and the ratios; the chain is a well-posed problem."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bench import model_files
from tests.tolerance import assert_close


def test_a_solver_exception_is_said_with_its_chain_size(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(model_files, "CHAIN_SIZES", (2, 3))
    real = model_files._per_iteration_detail

    def per_iteration(f, solver, options, reps=3):
        if solver == "raico" and f.name == "chain3.toml":
            return real(f, "no-such-solver", options, reps=1)   # the solver registry refuses it: an exception
        return {"seconds": 1e-3, "repeats": 0.0, "n_x": 4, "n_u": 2, "T": 100, "status": "max-iterations",
                "ended": "max-iterations", "start_cost": 2.0, "final_cost": 1.0, "iteration_s": 5e-4}, ""

    monkeypatch.setattr(model_files, "_per_iteration_detail", per_iteration)
    rows = model_files.scaling_rows()
    out = capsys.readouterr().out
    assert "n=  3  not timed: " in out and "no-such-solver" in out
    fit = next(r for r in rows if r["benchmark"] == "R-AICO per iteration against joints")
    assert fit["joint_sizes"] == [2] and fit["joint_exponent"] is None
    assert list(fit["joint_skipped"]) == [3] and "no-such-solver" in fit["joint_skipped"][3]


def test_the_readme_block_names_the_sizes_left_out(tmp_path):
    from scripts.readme_numbers import bench_block

    row = {"benchmark": "R-AICO per iteration against joints", "joint_sizes": [2, 4, 8],
           "joint_seconds": [1e-3, 2e-3, 4e-3], "joint_exponent": 1.0, "joint_skipped": {"16": "ValueError: x"}}
    (tmp_path / "results.json").write_text(json.dumps({"results": [row]}))
    block = bench_block(tmp_path / "results.json")
    assert "| R-AICO | 2, 4, 8 |" in block and "R-AICO left out of the exponents: n = 16: ValueError: x" in block


def test_a_diverged_run_is_labelled_and_left_out_of_the_exponents_and_ratios(monkeypatch):
    sizes = (2, 4, 8, 16, 32)
    monkeypatch.setattr(model_files, "CHAIN_SIZES", sizes)

    def per_iteration(f, solver, options, reps=3):
        n = int(f.stem.removeprefix("chain"))
        seconds = 1e-4 * n ** 3 if n >= 8 else 1e-3 * n   # cubic from 8 joints on, linear below
        if solver == "raico" and n == 16:
            return {"seconds": 5.0, "repeats": 300.0, "n_x": 2 * n, "n_u": n, "T": 100, "status": "diverged",
                    "ended": "diverged", "start_cost": 10.0, "final_cost": math.inf, "iteration_s": 4.0}, ""
        return {"seconds": seconds * (2.0 if solver == "raico" else 1.0), "repeats": 0.0, "n_x": 2 * n, "n_u": n,
                "T": 100, "status": "max-iterations", "ended": "max-iterations", "start_cost": 10.0,
                "final_cost": 1.0, "iteration_s": 0.5 * seconds}, ""

    monkeypatch.setattr(model_files, "_per_iteration_detail", per_iteration)
    rows = model_files.scaling_rows(dgemm=10.0)
    raico = next(r for r in rows if r["benchmark"] == "R-AICO per iteration against joints")
    assert raico["joint_sizes"] == [2, 4, 8, 32] and "diverged" in raico["joint_skipped"][16]
    assert raico["joint_exponent_from"] == 8
    assert_close(raico["joint_iteration_seconds"], [1e-3, 2e-3, 0.0256, 1.6384], rel=1e-9)
    assert math.isclose(raico["joint_exponent_upper"], 3.0, rel_tol=1e-9)   # over 8 and 32 only: cubic
    fddp = next((r for r in rows if r["benchmark"] == "crocoddyl FDDP per iteration against joints"), None)
    if fddp is not None:   # crocoddyl installed: FDDP's fit over 8, 16, 32, its time beside R-AICO's
        assert math.isclose(fddp["joint_exponent_upper"], 3.0, rel_tol=1e-9)
        r32 = next(r for r in rows if r["benchmark"].startswith("chain of 32 joints") and "R-AICO" in r["benchmark"])
        assert math.isclose(r32["ratio_to_fddp"], 2.0, rel_tol=1e-9)
    r16 = next(r for r in rows if r["benchmark"].startswith("chain of 16 joints") and "R-AICO" in r["benchmark"])
    assert r16["ended"] == "diverged" and "ratio_to_fddp" not in r16


def test_the_readme_block_labels_a_run_that_found_nothing(tmp_path):
    from scripts.readme_numbers import bench_block

    rows = [{"benchmark": "chain of 16 joints: one R-AICO iteration", "median_s": 0.033, "status": "diverged",
             "ended": "diverged"},
            {"benchmark": "chain of 8 joints: one crocoddyl FDDP iteration", "median_s": 0.005,
             "status": "max-iterations", "ended": "no descent"},
            {"benchmark": "chain of 4 joints: one R-AICO iteration", "median_s": 0.002, "status": "max-iterations",
             "ended": "max-iterations"},
            {"benchmark": "R-AICO per iteration against joints", "joint_sizes": [2, 4, 8, 32],
             "joint_seconds": [1e-3, 2e-3, 4e-3, 8e-3], "joint_exponent": 0.5, "joint_exponent_from": 8,
             "joint_exponent_upper": 0.5, "joint_iteration_seconds": [5e-4, 1e-3, 2e-3, 4e-3],
             "joint_skipped": {"16": "diverged (33.0 ms per iteration)"}}]
    (tmp_path / "results.json").write_text(json.dumps({"results": rows}))
    block = bench_block(tmp_path / "results.json")
    assert "| chain of 16 joints: one R-AICO iteration (diverged) | 33.0 ms |" in block
    assert "| chain of 8 joints: one crocoddyl FDDP iteration (no descent) | 5.0 ms |" in block
    assert "| chain of 4 joints: one R-AICO iteration | 2.0 ms |" in block
    assert ("| R-AICO | 2, 4, 8, 32 | 1.0 ms, 2.0 ms, 4.0 ms, 8.0 ms | 0.5 ms, 1.0 ms, 2.0 ms, 4.0 ms | 0.50 | "
            "0.50 (n >= 8) |") in block
    assert "R-AICO left out of the exponents: n = 16: diverged (33.0 ms per iteration)" in block


def test_ended_says_diverged_no_descent_or_the_status():
    assert model_files._ended("diverged", 10.0, 1.0) == "diverged"
    assert model_files._ended("max-iterations", 10.0, math.inf) == "diverged"
    assert model_files._ended("max-iterations", 10.0, 1.7e201) == "no descent"
    assert model_files._ended("max-iterations", math.inf, 5.0) == "max-iterations"   # a start that is no rollout
    assert model_files._ended("converged", 10.0, 1.0) == "converged"


@pytest.mark.numerics
def test_the_chain_hangs_in_a_stable_posture_and_r_aico_runs_as_raico_plan_does(tmp_path):
    """The start, held by the torques that hold it, is a stable equilibrium of the planning model at dt (the
    step's spectral radius 1 to rounding: no mode grows), which the upright chain with twist joints was not; R-AICO
    gets the options ``raico plan`` gives a problem file."""
    from stages.plan.stage import PlanConfig, build_problem, quasi_static_controls

    f = model_files.chain_problem(8, tmp_path)
    _, _, problem, q0, _ = build_problem(PlanConfig(problem=str(f), bounds="none").normalized())
    assert_close(q0, list(model_files.chain_start(8).values()), rel=1e-9)
    U = quasi_static_controls(problem, q0)
    A, _, _ = problem.dynamics.linearize(problem.x0, U[0])
    assert np.abs(np.linalg.eigvals(A)).max() < 1 + 1e-6
    X = problem.dynamics.step(problem.x0, U[0])
    assert_close(X, problem.x0, rel=1e-9)   # held: at rest where it starts
    opts = model_files.chain_raico_options(f)
    assert opts["schedule"] == "robust" and opts["iterations"] == model_files.ITERATIONS and opts["tol_rel"] == 0.0


@pytest.mark.numerics
def test_both_solvers_lower_the_cost_of_the_8_joint_chain(tmp_path):
    """The timed runs are of a problem both solvers solve: their 4 iterations end below the start's cost (the
    upright chain this bench wrote before ended FDDP's at 1e201 here)."""
    from planning.solvers import SOLVERS

    f = model_files.chain_problem(8, tmp_path)
    solvers = [("raico", model_files.chain_raico_options(f))]
    if "fddp" in SOLVERS:
        solvers.append(("fddp", {"iterations": model_files.ITERATIONS}))
    for solver, options in solvers:
        d, why = model_files._per_iteration_detail(f, solver, options, reps=1)
        assert d is not None, why
        assert d["ended"] in ("converged", "max-iterations"), (solver, d)
        assert d["final_cost"] < 0.01 * d["start_cost"], (solver, d)
