"""Planner benchmarks of SPEC §13: ``make bench`` -> ``artifacts/bench/results.json`` and a table.

Medians over several repetitions (the machine is shared and noisy); each row shows the target
beside the measurement and their ratio. Not a test: nothing here fails on a slow machine.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from pipeline.cache import package_versions
from stages.plan.solvers import solve
from stages.plan.stage import PlanConfig, build_problem


def _problem(plant: str, task: str, dynamics: str):
    _, _, problem, _, _ = build_problem(PlanConfig(plant=plant, task=task, dynamics=dynamics, seed=0))
    return problem


def bench_solver_total(plant, task, dynamics, solver, options, reps) -> list[float]:
    """Wall time (s) of whole solver runs."""
    times = []
    for _ in range(reps):
        problem = _problem(plant, task, dynamics)
        t0 = time.perf_counter()
        solve(problem, solver, options)
        times.append(time.perf_counter() - t0)
    return times


def bench_per_iteration(plant, task, dynamics, solver, options, reps) -> list[float]:
    """Per-iteration wall times (s, linearization included) from the solver's own history."""
    times = []
    for _ in range(reps):
        res = solve(_problem(plant, task, dynamics), solver, options)
        times += [h.time_s for h in res.history]
    return times


def bench_linearization(reps: int) -> list[float]:
    """Analytic arm5 dynamics linearized along a T = 1000 trajectory (s)."""
    problem = _problem("arm5", "reach", "analytic")
    X = np.tile(problem.x0, (problem.T, 1))
    U = np.zeros((problem.T, problem.n_u))
    out = []
    for _ in range(reps):
        t0 = time.perf_counter()
        problem.dynamics.linearize_trajectory(X, U)
        out.append(time.perf_counter() - t0)
    return out


CASES = [
    # name, target (s), function, args
    ("nao balance: 25 R-AICO iterations (T=300, 50-D)", 1.0, bench_solver_total,
     ("nao", "balance", "pseudo", "raico", {"iterations": 25, "alpha": 1.0, "tol_rel": 0.0}, 3)),
    ("nao balance: 25 R-AICO iterations, no relinearization in sweeps (theta=inf)", 1.0, bench_solver_total,
     ("nao", "balance", "pseudo", "raico", {"iterations": 25, "alpha": 1.0, "tol_rel": 0.0, "theta": float("inf")}, 3)),
    ("nao balance: one iLQG iteration", None, bench_per_iteration,
     ("nao", "balance", "pseudo", "ilqg", {"iterations": 3}, 1)),
    ("arm5 analytic: one R-AICO iteration incl. linearization (T=1000)", 0.030, bench_per_iteration,
     ("arm5", "reach-roll", "analytic", "raico", {"iterations": 3, "alpha": 1.0}, 1)),
    ("arm5 analytic: one iLQG iteration (T=1000)", None, bench_per_iteration,
     ("arm5", "reach-roll", "analytic", "ilqg", {"iterations": 3}, 1)),
    ("arm5 analytic: linearize the dynamics along T=1000", None, bench_linearization, (5,)),
]


def model_learning_rows() -> list[dict]:
    """GP posterior along 500 steps with 1000 points (per output), incremental update vs refit,
    and one learn episode of fig4.3 split into fit, plan and execute (SPEC §13, issue 7)."""
    from bench.gp_bench import bench_gp
    from bench.learn_bench import bench_learn_episode

    gp = bench_gp(repeats=5, cap_cost=True)
    ep = bench_learn_episode()
    rows = [
        ("GP: mean, variance and all gradients, 500 steps, N=1000, per output (d=15)",
         gp["mean_var_all_gradients_ms_per_output"] / 1e3, gp["target_ms_per_output"] / 1e3),
        ("GP: mean and its gradient only (what linearization needs), per output",
         gp["mean_and_gradient_ms_per_output"] / 1e3, None),
        ("GP: incremental update with 100 new points (fixed hyperparameters)", gp["update_100_ms"] / 1e3, None),
        ("GP: full refactorization at 1100 points (fixed hyperparameters)", gp["refit_1100_ms"] / 1e3, None),
        ("learn episode of fig4.3 (biorob): fit", ep["fit_s"], None),
        ("learn episode of fig4.3 (biorob): plan (10 R-AICO iterations on the GP)", ep["plan_s"], None),
        ("learn episode of fig4.3 (biorob): execute in Drake", ep["execute_s"], None),
    ]
    out = []
    for name, med, target in rows:
        out.append({"benchmark": name, "median_s": med, "samples_s": [med], "target_s": target,
                    "ratio_to_target": med / target if target else None})
        tgt = f"{target:8.3f}" if target else "       -"
        ratio = f"{med / target:6.2f}x" if target else "      -"
        print(f"{name:68s} median {med:8.3f} s   target {tgt} s   {ratio}", flush=True)
    cap = gp.get("cap_cost") or {}
    out.append({"benchmark": "GP training-set cap: held-out RMSE capped vs all points", "detail": cap})
    print(f"GP cap cost (2000 -> 500 points): {json.dumps(cap, default=float)[:300]}", flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--artifacts", default="artifacts")
    args = ap.parse_args()
    rows = []
    for name, target, fn, fargs in CASES:
        samples = fn(*fargs)
        med = statistics.median(samples)
        rows.append({"benchmark": name, "median_s": med, "samples_s": samples, "target_s": target,
                     "ratio_to_target": med / target if target else None})
        tgt = f"{target:8.3f}" if target else "       -"
        ratio = f"{med / target:6.2f}x" if target else "      -"
        print(f"{name:68s} median {med:8.3f} s   target {tgt} s   {ratio}   (n={len(samples)})", flush=True)
    rows += model_learning_rows()
    out = Path(args.artifacts) / "bench"
    out.mkdir(parents=True, exist_ok=True)
    doc = {"machine": {"python": platform.python_version(), "processor": platform.processor(),
                       "cpus": __import__("os").cpu_count()},
           "packages": package_versions(), "results": rows}
    (out / "results.json").write_text(json.dumps(doc, indent=2))
    print(f"wrote {out / 'results.json'}")


if __name__ == "__main__":
    main()
