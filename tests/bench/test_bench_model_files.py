"""The joint-scaling bench: a solver that cannot take a chain is said (why, which size), not dropped; a run that
diverged keeps its row, labelled, out of the exponents and the ratios; the chain is a well-posed problem."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bench import model_files
from tests.tolerance import assert_close


def _each(monkeypatch, per_iteration) -> None:
    """``model_files.per_iteration_details`` made of ``per_iteration(f, solver, options, reps)`` per solver."""
    monkeypatch.setattr(model_files, "per_iteration_details",
                        lambda f, specs, reps=3: [per_iteration(f, solver, options, reps) for solver, options in specs])


def _detail(seconds, status, start, costs, n=2, setup=0.01):
    """A measurement as ``model_files.per_iteration_details`` returns one: its iterations' costs, ``seconds``
    each."""
    return {"seconds": seconds, "setup_s": setup, "repeats": 0.0, "n_x": 2 * n, "n_u": n, "T": 100,
            "status": status, "start_cost": start, "final_cost": costs[-1], "costs": list(costs),
            "elapsed_s": [seconds * (k + 1) for k in range(len(costs))],
            "ended": model_files.ending(status, start, costs[-1])}


def test_a_solver_exception_is_said_with_its_chain_size(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(model_files, "CHAIN_SIZES", (2, 3))
    real = model_files.per_iteration_details

    def per_iteration(f, solver, options, reps=3):
        if solver == "raico" and f.name == "chain3.toml":   # the solver registry refuses it: an exception
            return real(f, [("no-such-solver", options)], reps=1)[0]
        return _detail(1e-3, "max-iterations", 2.0, [1.5, 1.0], n=2), ""

    _each(monkeypatch, per_iteration)
    rows = model_files.scaling_rows()
    out = capsys.readouterr().out
    assert "n=  3  not timed: " in out and "no-such-solver" in out
    fit = next(r for r in rows if r["benchmark"] == "R-AICO per iteration against joints")
    assert fit["joint_sizes"] == [2] and fit["joint_exponent"] is None
    assert list(fit["joint_skipped"]) == [3] and "no-such-solver" in fit["joint_skipped"][3]


def test_the_page_names_the_sizes_left_out():
    row = {"benchmark": "R-AICO per iteration against joints", "joint_sizes": [2, 4, 8],
           "joint_seconds": [1e-3, 2e-3, 4e-3], "joint_setup_seconds": [1e-2, 1e-2, 2e-2], "joint_exponent": 1.0,
           "joint_skipped": {"16": "ValueError: x"}}
    page = model_files.markdown_page({"date": "d", "machine": "m", "rows": [row]})
    assert "| R-AICO | 2, 4, 8 | 1.0 ms, 2.0 ms, 4.0 ms | 10.0 ms, 10.0 ms, 20.0 ms |" in page
    assert "R-AICO left out of the exponents: n = 16: ValueError: x" in page


def test_a_diverged_run_is_labelled_and_left_out_of_the_exponents_and_ratios(monkeypatch):
    sizes = (2, 4, 8, 16, 32)
    monkeypatch.setattr(model_files, "CHAIN_SIZES", sizes)

    def per_iteration(f, solver, options, reps=3):
        n = int(f.stem.removeprefix("chain"))
        seconds = 1e-4 * n ** 3 if n >= 8 else 1e-3 * n   # cubic from 8 joints on, linear below
        if solver == "raico" and n == 16:
            return {**_detail(5.0, "diverged", 10.0, [math.inf], n=n), "repeats": 300.0}, ""
        return _detail(seconds * (2.0 if solver == "raico" else 1.0), "max-iterations", 10.0, [2.0, 1.0], n=n), ""

    _each(monkeypatch, per_iteration)
    monkeypatch.setattr(model_files, "flop_columns", lambda *args, **kwargs: {})   # the flop columns: test_bench_flops.py
    rows = model_files.scaling_rows(dgemm=10.0)
    raico = next(r for r in rows if r["benchmark"] == "R-AICO per iteration against joints")
    assert raico["joint_sizes"] == [2, 4, 8, 32] and "diverged" in raico["joint_skipped"][16]
    assert raico["joint_exponent_from"] == 8
    assert_close(raico["joint_seconds"], [4e-3, 8e-3, 0.1024, 6.5536], rel=1e-9)
    assert raico["joint_setup_seconds"] == [0.01] * 4
    assert math.isclose(raico["joint_exponent_upper"], 3.0, rel_tol=1e-9)   # over 8 and 32 only: cubic
    fddp = next((r for r in rows if r["benchmark"] == "crocoddyl FDDP per iteration against joints"), None)
    if fddp is not None:   # crocoddyl installed: FDDP's fit over 8, 16, 32, its time beside R-AICO's
        assert math.isclose(fddp["joint_exponent_upper"], 3.0, rel_tol=1e-9)
        r32 = next(r for r in rows if r["benchmark"].startswith("chain of 32 joints") and "R-AICO" in r["benchmark"])
        assert math.isclose(r32["ratio_to_fddp"], 2.0, rel_tol=1e-9)
    r16 = next(r for r in rows if r["benchmark"].startswith("chain of 16 joints") and "R-AICO" in r["benchmark"])
    assert r16["ended"] == "diverged" and "ratio_to_fddp" not in r16


def test_the_page_labels_a_run_that_found_nothing_and_a_failed_one():
    rows = [{"benchmark": "chain of 16 joints: one R-AICO iteration", "median_s": 0.033, "setup_s": 0.01,
             "status": "diverged", "ended": "diverged", "final_cost": math.inf, "fddp_s": 0.005, "fddp_setup_s": 0.02,
             "fddp_final_cost": 3.0, "fddp_ended": "max-iterations", "common_cost": 3.03, "time_to_common_s": None,
             "fddp_time_to_common_s": 0.015},
            {"benchmark": "chain of 8 joints: one R-AICO iteration", "median_s": 0.002, "setup_s": 0.01,
             "status": "max-iterations", "ended": "max-iterations", "final_cost": 2.0, "fddp_s": 0.005,
             "fddp_setup_s": 0.02, "fddp_final_cost": 1e5, "fddp_ended": "no descent", "common_cost": 2.02,
             "time_to_common_s": 0.008, "fddp_time_to_common_s": None, "ratio_to_fddp": 0.4},
            {"benchmark": "UR5 reach: one R-AICO iteration", "status": "failed", "ended": "failed",
             "error": "ValueError: no arm"}]
    page = model_files.markdown_page({"date": "d", "machine": "m", "rows": rows})
    assert ("| chain of 16 joints (diverged) | 33.0 ms | 5.0 ms | - | 10.0 ms | 20.0 ms | 3.03 | not reached | "
            "15.0 ms | inf | 3 |") in page
    assert ("| chain of 8 joints | 2.0 ms | 5.0 ms | 0.40 | 10.0 ms | 20.0 ms | 2.02 | 8.0 ms | not reached | 2 | "
            "1e+05 (no descent) |") in page
    assert "| UR5 reach (failed) | ValueError: no arm |" in page


def test_ended_says_diverged_no_descent_or_the_status():
    assert model_files.ending("diverged", 10.0, 1.0) == "diverged"
    assert model_files.ending("max-iterations", 10.0, math.inf) == "diverged"
    assert model_files.ending("max-iterations", 10.0, 1.7e201) == "no descent"
    assert model_files.ending("max-iterations", math.inf, 5.0) == "max-iterations"   # a start that is no rollout
    assert model_files.ending("converged", 10.0, 1.0) == "converged"


def test_the_common_cost_is_the_better_final_cost_plus_one_percent_and_each_solver_is_timed_to_it():
    """The chain at 32 joints as measured: R-AICO's cheap iterations end at 44.2, FDDP's at 0.020: the common cost
    is 1.01 x 0.020, which R-AICO never reaches; a run that diverged or did not descend sets no common cost."""
    a = _detail(0.016, "max-iterations", 90.0, [80.0, 60.0, 50.0, 44.2], n=32)
    f = _detail(0.035, "max-iterations", 90.0, [5.0, 0.5, 0.0201, 0.020], n=32)
    target = model_files.common_cost(a, f)
    assert math.isclose(target, 0.0202, rel_tol=1e-9)
    assert model_files.time_to(a, target) is None
    assert math.isclose(model_files.time_to(f, target), 3 * 0.035, rel_tol=1e-9)   # its third iteration: 0.0201
    row = model_files.fddp_columns(a, f)
    assert row["time_to_common_s"] is None and math.isclose(row["ratio_to_fddp"], 0.016 / 0.035, rel_tol=1e-9)
    assert row["fddp_final_cost"] == 0.020 and row["fddp_setup_s"] == 0.01
    diverged = _detail(0.01, "diverged", 90.0, [math.inf], n=32)
    assert model_files.common_cost(a, diverged) == 44.2 * 1.01
    no_descent = _detail(0.01, "max-iterations", 90.0, [95.0], n=32)
    assert model_files.common_cost(diverged, no_descent) is None
    assert model_files.time_to(a, None) is None


def test_a_robot_a_solver_fails_on_keeps_its_row_with_the_reason(monkeypatch, capsys):
    from raico.plants.model_file import example_robot_data

    if example_robot_data() is None:
        pytest.skip("example-robot-data is not installed: no robot rows")
    monkeypatch.setattr(model_files, "ROBOTS", (("UR5 reach", "raico/problems/examples/ur5_reach.toml"),))
    _each(monkeypatch, lambda f, solver, options, reps=3: (None, f"ValueError: {solver} refused"))
    rows = model_files.robot_rows()
    assert rows == [{"benchmark": "UR5 reach: one R-AICO iteration", "status": "failed", "ended": "failed",
                     "error": "ValueError: raico refused"}]
    assert "UR5 reach: one R-AICO iteration: not timed: ValueError: raico refused" in capsys.readouterr().err


def test_fddp_is_timed_with_its_records_made_after_its_solve_and_its_setup_apart(tmp_path, monkeypatch):
    """The bench's FDDP solve: records made after crocoddyl's solve (the same costs and iterates as the live
    recorder's, the infeasible first iterate's feedback rollout included: the 4-joint chain's first step leaves
    gaps), its setup (the model built) measured apart."""
    from raico.planning.solvers import SOLVERS, solve
    from raico.stages.plan.stage import PlanConfig, build_problem

    if "fddp" not in SOLVERS:
        pytest.skip("crocoddyl is not installed")
    from raico.planning.crocoddyl import fddp
    from raico.planning.crocoddyl import solve as croc_solve

    f = model_files.chain_problem(4, tmp_path)
    _, _, problem, _, _ = build_problem(PlanConfig(problem=str(f), bounds="none").normalized())
    live = solve(problem, "fddp", {"iterations": 4})
    deferred, finish = [], croc_solve._Recorder.finish

    def counted_finish(self):
        deferred.append(sum(K is not None for *_, K in self.pending))
        finish(self)

    monkeypatch.setattr(croc_solve._Recorder, "finish", counted_finish)
    res, setup = model_files.timed_solve(problem, "fddp", {"iterations": 4})
    assert deferred[-1] >= 1   # an infeasible iterate rolled out after the solve
    assert [h.cost for h in res.history] == [h.cost for h in live.history]
    assert setup > 0 and all(h.time_s > 0 for h in res.history)
    assert np.array_equal(res.X_iterations, live.X_iterations, equal_nan=True)   # the callbacks: the same iterates
    assert model_files.records_after("boxfddp") == {"record": "after"} and model_files.records_after("raico") == {}
    with pytest.raises(ValueError, match="record must be"):
        fddp(problem, record="later")
    _, setup_a = model_files.timed_solve(problem, "raico", model_files.chain_raico_options(f))
    assert setup_a is not None and setup_a > 0


@pytest.mark.parametrize("n", [pytest.param(n, marks=pytest.mark.slow) if n >= 16 else n
                               for n in model_files.CHAIN_SIZES])
@pytest.mark.numerics
def test_the_chain_hangs_in_a_stable_posture_and_r_aico_runs_as_raico_plan_does(tmp_path, n):
    """At every size the page times: the start, held by the torques that hold it, is a stable equilibrium of the
    planning model at dt (the step's spectral radius 1 to rounding: no mode grows), which the upright chain with
    twist joints was not; R-AICO gets the options ``raico plan`` gives a problem file."""
    from raico.stages.plan.stage import PlanConfig, build_problem, quasi_static_controls

    f = model_files.chain_problem(n, tmp_path)
    _, _, problem, q0, _ = build_problem(PlanConfig(problem=str(f), bounds="none").normalized())
    assert_close(q0, list(model_files.chain_start(n).values()), rel=1e-9)
    U = quasi_static_controls(problem, q0)
    A, _, _ = problem.dynamics.linearize(problem.x0, U[0])
    assert np.abs(np.linalg.eigvals(A)).max() < 1 + 1e-6
    X = problem.dynamics.step(problem.x0, U[0])
    assert_close(X, problem.x0, rel=1e-9)   # held: at rest where it starts
    opts = model_files.chain_raico_options(f)
    assert opts["schedule"] == "robust" and opts["iterations"] == model_files.ITERATIONS and opts["tol_rel"] == 0.0


@pytest.mark.parametrize("n", [pytest.param(n, marks=pytest.mark.slow) if n >= 16 else n
                               for n in model_files.CHAIN_SIZES])
@pytest.mark.numerics
def test_both_solvers_lower_the_cost_of_the_chain(tmp_path, n):
    """At every size the page times, the timed runs are of a problem both solvers solve: their iterations (the
    bench's 4) end below the start's cost, neither diverged nor stalled (the upright chain this bench wrote before
    ended FDDP's at 1e201 at 8 joints). How far each gets is the page's common cost, not asserted here."""
    from raico.planning.solvers import SOLVERS

    f = model_files.chain_problem(n, tmp_path)
    solvers = [("raico", model_files.chain_raico_options(f))]
    if "fddp" in SOLVERS:
        solvers.append(("fddp", {"iterations": model_files.ITERATIONS}))
    for solver, options in solvers:
        d, why = model_files.per_iteration_details(f, [(solver, options)], reps=1)[0]
        assert d is not None, why
        assert d["ended"] in ("converged", "max-iterations"), (solver, d)
        assert d["final_cost"] < d["start_cost"], (solver, d)
        assert d["setup_s"] is not None and d["setup_s"] > 0 and len(d["costs"]) == len(d["elapsed_s"]) >= 1


def test_the_models_block_lives_on_the_benchmarks_page_and_is_the_page_without_its_title(tmp_path):
    from scripts import readme_numbers

    root = readme_numbers.ROOT
    assert readme_numbers.home("models") == root / "docs" / "benchmarks.md"
    page = tmp_path / "model_files.md"
    page.write_text(model_files.markdown_page({"date": "d", "machine": "m", "rows": []}))
    block = readme_numbers.models_block(page)
    assert block.startswith(f"From `{page}`") and "# Per-iteration time" not in block and "Measured by" in block


def test_the_bench_block_leaves_the_per_iteration_rows_to_the_models_block(tmp_path):
    from scripts.readme_numbers import bench_block

    rows = [{"benchmark": "chain of 4 joints: one R-AICO iteration", "median_s": 0.002, "setup_s": 0.01},
            {"benchmark": "xArm7 (7 joints): first load", "median_s": 1.7, "target_s": 10.0}]
    (tmp_path / "results.json").write_text(json.dumps({"results": rows}))
    block = bench_block(tmp_path / "results.json")
    assert "| xArm7 (7 joints): first load | 1.70 s | 10.00 s | 0.17 |" in block and "chain of 4" not in block
