"""Planner benchmarks and their time targets: ``make bench`` -> ``artifacts/bench/results.json`` and a table.

Medians over several repetitions (the machine is shared and noisy); each row shows the target
beside the measurement and their ratio. Not a test: nothing here fails on a slow machine.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from raico.pipeline.engine.atomic import write_file_atomic
from raico.pipeline.engine.keys import package_versions
from raico.planning.solvers import solve
from raico.stages.plan.stage import PlanConfig, build_problem


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


def bench_sweep_share(plant, task, dynamics, solver, options, reps) -> list[float]:
    """Wall time (s) of whole solver runs spent inside the sweeps (``Sweeps.sweep``: the compiled
    kernel and its Python driver), the rest being linearization, rollouts and costs in Python."""
    from raico.planning.aico.sweeps import Sweeps

    times, inner = [], [0.0]
    original = Sweeps.sweep

    def timed(self):
        t0 = time.perf_counter()
        try:
            return original(self)
        finally:
            inner[0] += time.perf_counter() - t0

    Sweeps.sweep = timed
    try:
        for _ in range(reps):
            problem = _problem(plant, task, dynamics)
            inner[0] = 0.0
            solve(problem, solver, options)
            times.append(inner[0])
    finally:
        Sweeps.sweep = original
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


def bench_nao_linearization(route: str, reps: int) -> list[float]:
    """The Nao's analytic dynamics linearized along a T = 300 trajectory (s): ``route`` "autodiff"
    is ``AnalyticDynamics`` (Drake's AutoDiffXd, per point; what "analytic" builds for the Nao),
    "tree" is ``TreeAnalyticDynamics`` (the tree kernels in C, checked against it)."""
    from raico.plants.dynamics import AnalyticDynamics
    from raico.plants.fast_analytic import TreeAnalyticDynamics
    from raico.plants.robots import shared_robot

    robot = shared_robot("nao")
    model = (AnalyticDynamics if route == "autodiff" else TreeAnalyticDynamics)(robot, 0.01)
    rng = np.random.default_rng(0)
    n, T = robot.n_q, 300
    X = np.concatenate([robot.default_q + 0.1 * rng.standard_normal((T, n)),
                        0.5 * rng.standard_normal((T, n))], axis=1)
    U = rng.standard_normal((T, n))
    model.linearize_trajectory(X[:2], U[:2])   # warm up (builds and loads the C once)
    out = []
    for _ in range(reps):
        t0 = time.perf_counter()
        model.linearize_trajectory(X, U)
        out.append(time.perf_counter() - t0)
    return out


def bench_stabilizer_execution(reps: int) -> list[float]:
    """One 3 s execution of a fig3.4-inside R-AICO plan (T = 300 steps of 10 ms) on the free-standing
    Nao with the whole-body stabilizer from the standing start: the execute stage's whole computation (start
    projection, simulation with a program every control period, metrics), in a warm process (the first
    execution, which also imports and builds Drake's systems, is left out)."""
    from raico.stages.execute.config import ExecuteConfig
    from raico.stages.execute.stage import execute
    from raico.stages.plan.stage import PlanConfig, plan

    cfg = PlanConfig(plant="nao", task="balance-inside", dynamics="pseudo", solver="raico", alpha=1.0, iterations=25,
                     seed=1, q0_std=0.05).normalized()
    cfg.validate()
    out = plan(cfg)
    desc, arrays = out.description, out.arrays()
    ex = ExecuteConfig(plan="bench", controller="wbc", start="standing")
    execute(ex, desc, arrays)  # warm-up
    samples = []
    for _ in range(reps):
        t0 = time.perf_counter()
        m = execute(ex, desc, arrays).metrics
        samples.append(time.perf_counter() - t0)
    if m["status"] != "ok":
        raise RuntimeError(f"the benchmark's execution ended {m['status']}: {m['reason']}")
    return samples


def bench_cli(args: tuple[str, ...], reps: int) -> list[float]:
    """Wall time (s) of one ``raico ARGS`` process from start to exit (Python's start included; output
    discarded; a non-zero exit is expected for a refused option)."""
    import subprocess
    import sys

    raico = str(Path(sys.executable).with_name("raico"))
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        subprocess.run([raico, *args], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
        times.append(time.perf_counter() - t0)
    return times


def bench_exp_show(reps: int) -> list[float]:
    from bench.exp_bench import bench_exp_show as run

    return run(reps)


def bench_exp_table(reps: int) -> list[float]:
    from bench.exp_bench import bench_exp_table as run

    return run(reps)


def bench_thesis_dry_run(reps: int) -> list[float]:
    from bench.exp_bench import bench_thesis_dry_run as run

    return run(reps, ARTIFACTS)


ARTIFACTS = "artifacts"   # the bench's cache (--artifacts): the thesis files' dry runs look their runs up there

CASES = [
    # name, target (s), function, args
    ("raico --help (start-up: no stage is imported)", 0.5, bench_cli, (("--help",), 7)),
    ("raico plan with a refused option (--solver foo): the plan stage imported, the option checked", 0.5,
     bench_cli, (("plan", "--plant", "arm5", "--task", "reach", "--solver", "foo"), 7)),
    ("nao balance: 25 R-AICO iterations (T=300, 50-D)", 1.0, bench_solver_total,
     ("nao", "balance", "pseudo", "raico", {"iterations": 25, "alpha": 1.0, "tol_rel": 0.0}, 5)),
    ("nao balance: of which in the sweeps (forward, backward, beliefs, relinearizations)", None,
     bench_sweep_share, ("nao", "balance", "pseudo", "raico", {"iterations": 25, "alpha": 1.0, "tol_rel": 0.0}, 3)),
    ("nao balance: 25 R-AICO iterations, no relinearization in sweeps (theta=inf)", 1.0, bench_solver_total,
     ("nao", "balance", "pseudo", "raico", {"iterations": 25, "alpha": 1.0, "tol_rel": 0.0, "theta": float("inf")}, 3)),
    # thesis §3.6: "The computational time of the proposed planning algorithm is the same as for the
    # standard implementation of AICO ... the computation of the balancing movements in Figure 3.4 took less than
    # 50 seconds (which includes all 25 iterations" (Matlab, 2.4 GHz): the target is the thesis's 50 s
    ("nao balance: 25 plain AICO iterations (thesis: R-AICO costs the same; < 50 s in Matlab)", 50.0,
     bench_solver_total, ("nao", "balance", "pseudo", "aico", {"iterations": 25, "tol_rel": 0.0}, 3)),
    ("nao balance: one iLQG iteration", None, bench_per_iteration,
     ("nao", "balance", "pseudo", "ilqg", {"iterations": 3}, 1)),
    ("arm5 analytic: one R-AICO iteration incl. linearization (T=1000)", 0.030, bench_per_iteration,
     ("arm5", "reach-roll", "analytic", "raico", {"iterations": 3, "alpha": 1.0}, 3)),
    ("arm5 analytic: one iLQG iteration (T=1000)", None, bench_per_iteration,
     ("arm5", "reach-roll", "analytic", "ilqg", {"iterations": 3}, 1)),
    ("arm5 analytic: linearize the dynamics along T=1000", None, bench_linearization, (5,)),
    ("nao analytic: linearize along T=300, AutoDiffXd (before; registry 'analytic')", None,
     bench_nao_linearization, ("autodiff", 3)),
    ("nao analytic: linearize along T=300, tree kernels in C (after)", None,
     bench_nao_linearization, ("tree", 5)),
    # real-time factor >= 1 for the stabilizer on the 2-core machine; 7 repetitions: on the shared
    # machine the same execution took 2.0-3.6 s within one minute (idle, load 0.5)
    ("nao: one 3 s execution with the whole-body stabilizer (fig3.4-inside plan, standing start)", 3.0,
     bench_stabilizer_execution, (7,)),
    # experiment files (bench/exp_bench.py): a synthetic experiment of 1000 runs, the thesis's files
    ("raico exp show of a 1000-run experiment (warm: reads its runs table; Python's start included)", 1.0,
     bench_exp_show, (7,)),
    ("building the runs table of a 1000-run experiment (rows from the entries, runs.csv, runs.json)", 5.0,
     bench_exp_table, (3,)),
    ("raico exp run --dry-run of a thesis file (the slowest of raico/thesis/experiments/)", 2.0, bench_thesis_dry_run, (3,)),
]


SPARSE_M = 200  # inducing points of the sparse-GP rows (raico fit/learn --gp sparse's default --inducing)


def model_learning_rows() -> list[dict]:
    """GP posterior along 500 steps with 1000 points (per output), incremental update vs refit,
    and one learn episode of fig4.3 split into fit, plan and execute."""
    from bench.gp_bench import bench_gp
    from bench.learn_bench import bench_learn_default, bench_learn_episode, bench_learn_evaluation

    gp = bench_gp(repeats=5, cap_cost=True)
    ep = bench_learn_episode()
    ev = {kind: bench_learn_evaluation(kind, SPARSE_M) for kind in ("exact", "sparse")}
    whole = bench_learn_default()
    print(f"raico learn biorob reach, 20 episodes, defaults: last executed distance {whole['task_error_last']:.4f} m "
          f"[{whole['status_last']}], {whole['n_points_last']} GP points", flush=True)
    rows = [
        ("GP: mean, variance and all gradients, 500 steps, N=1000, per output (d=15)",
         gp["mean_var_all_gradients_ms_per_output"] / 1e3, gp["target_ms_per_output"] / 1e3),
        ("GP: mean and its gradient only (what linearization needs), per output",
         gp["mean_and_gradient_ms_per_output"] / 1e3, None),
        ("GP: incremental update with 100 new points (fixed hyperparameters)", gp["update_100_ms"] / 1e3, None),
        ("GP: full refactorization at 1100 points (fixed hyperparameters)", gp["refit_1100_ms"] / 1e3, None),
        (f"GP sparse (FITC, M={SPARSE_M} inducing): the same call at N=1000, per output",
         gp["sparse"][str(SPARSE_M)]["mean_var_all_gradients_ms_per_output"] / 1e3, gp["target_ms_per_output"] / 1e3),
        *[(f"fig4.3 evaluation (fit + plan + execute) at {ev[k]['n_points']} points, {k} GP"
           + (f" (M={SPARSE_M})" if k == "sparse" else ""), ev[k]["total_s"], 1.0) for k in ("exact", "sparse")],
        ("learn episode of fig4.3 (biorob): fit", ep["fit_s"], None),
        ("learn episode of fig4.3 (biorob): plan (10 R-AICO iterations on the GP)", ep["plan_s"], None),
        ("learn episode of fig4.3 (biorob): execute in Drake", ep["execute_s"], None),
        ("raico learn --plant biorob --task reach --episodes 20 --alpha 2 (defaults, one run)", whole["wall_s"], 60.0),
    ]
    out = []
    for name, med, target in rows:
        out.append({"benchmark": name, "median_s": med, "samples_s": [med], "target_s": target,
                    "ratio_to_target": med / target if target else None})
        tgt = f"{target:8.3f}" if target else "       -"
        ratio = f"{med / target:6.2f}x" if target else "      -"
        print(f"{name:68s} median {med:8.3f} s   target {tgt} s   {ratio}", flush=True)
    sp = gp["sparse"]
    out.append({"benchmark": "GP sparse vs exact at N=1000 (time per output, held-out RMSE ratio, trajectory "
                             "mean/std differences over y_std)", "detail": sp})
    out.append({"benchmark": "fig4.3 evaluation at 1000 points: fit/plan/execute split", "detail": ev})
    for m, r in sp.items():
        print(f"GP sparse M={m}: {r['mean_var_all_gradients_ms_per_output']:.1f} ms/output, held-out RMSE "
              f"x{min(r['heldout_rmse_ratio']):.2f}-{max(r['heldout_rmse_ratio']):.2f} of the exact GP's, "
              f"mean diff <= {r['trajectory_max_mean_diff_over_ystd']:.2g} y_std", flush=True)
    for k, r in ev.items():
        print(f"fig4.3 evaluation, {k}: fit {r['fit_s']:.2f} s ({r['fit_mode']}), plan {r['plan_s']:.2f} s, "
              f"execute {r['execute_s']:.2f} s at {r['n_points']} points", flush=True)
    cap = gp.get("cap_cost") or {}
    out.append({"benchmark": "GP training-set cap: held-out RMSE capped vs all points", "detail": cap})
    print(f"GP cap cost (2000 -> 500 points): {json.dumps(cap, default=float)[:300]}", flush=True)
    return out


# ----------------------------------------------------------------------------- crocoddyl baseline
BASELINE_SOLVERS = (  # name, solver, options: one run each, side by side in one process
    ("R-AICO a=1", "raico", {"iterations": 25, "alpha": 1.0, "tol_rel": 0.0}),
    ("iLQG", "ilqg", {"iterations": 25}),
    ("crocoddyl FDDP (x0 held)", "fddp", {"iterations": 100}),
    ("crocoddyl FDDP (rollout start)", "fddp-rollout", {"iterations": 100}),
)


def _cost_at(res, t: float) -> float:
    """Cost of the last iteration finished by wall time ``t`` (s; ``initial_cost`` before any)."""
    done = [h.cost for h in res.history if h.elapsed_s <= t]
    return done[-1] if done else res.initial_cost


def _time_to(res, cost: float) -> float | None:
    """Wall time (s) at which the run first reached ``cost`` or less (``None``: never)."""
    return next((h.elapsed_s for h in res.history if h.cost <= cost), None)


def bench_baseline(task: str = "reach") -> dict:
    """raico (R-AICO, iLQG) against crocoddyl FDDP on thesis fig3.2c (``task="reach"``): per-iteration
    time, time to reach R-AICO's 25-iteration cost (+10 %), and cost at R-AICO's 25-iteration wall time,
    with ratios. One run per solver (seed 0) in this process; iteration times are the solvers' own."""
    from raico.planning.solvers import SOLVERS

    if "fddp" not in SOLVERS:
        return {"skipped": "crocoddyl not installed (the extra raico[baseline]: make install)"}
    from bench.model_files import records_after

    results = {}
    for label, solver, opts in BASELINE_SOLVERS:   # crocoddyl's records made after its solve, as in bench.model_files
        results[label] = solve(_problem("arm5", task, "analytic"), solver, opts, **records_after(solver))
    ref = results["R-AICO a=1"]
    target = 1.1 * ref.cost
    budget = ref.history[-1].elapsed_s
    fddp = results["crocoddyl FDDP (x0 held)"]
    fddp_it = statistics.median(h.time_s for h in fddp.history)
    fddp_tt = _time_to(fddp, target)
    rows = []
    for label, res in results.items():
        it = statistics.median(h.time_s for h in res.history)
        tt = _time_to(res, target)
        at = _cost_at(res, budget)
        rows.append({"solver": label, "iterations": res.iterations, "final_cost": res.cost,
                     "iteration_median_s": it, "iteration_ratio_to_fddp": it / fddp_it,
                     "time_to_target_s": tt,
                     "time_to_target_ratio_to_fddp": tt / fddp_tt if tt is not None and fddp_tt else None,
                     "cost_at_budget": at, "cost_at_budget_ratio_to_raico": at / _cost_at(ref, budget),
                     "wall_time_s": res.history[-1].elapsed_s})
    return {"problem": f"fig3.2c: arm5 {task}, analytic, T=1000, seed 0", "target_cost": target,
            "budget_s": budget, "rows": rows,
            "note": "one run per solver in one process; iteration time = median over its iterations; the "
                    "machine is shared (2 cores, other jobs): ratios are more telling than absolute times"}


def print_baseline(b: dict) -> None:
    if "rows" not in b:
        print(f"crocoddyl baseline: {b.get('skipped')}")
        return
    print(f"\nraico vs crocoddyl FDDP on {b['problem']} (medians; shared, noisy machine)")
    print(f"target cost {b['target_cost']:.4g} (R-AICO's 25-iteration cost + 10 %), equal wall time "
          f"{b['budget_s']:.2f} s (R-AICO's 25 iterations); per-iteration target: R-AICO <= FDDP")

    def f(x, spec, suffix=""):
        width = int(spec.split(".")[0])
        return ("-" if x is None else format(x, spec) + suffix).rjust(width + len(suffix))

    print(f"{'solver':32s} {'iters':>5s} {'final cost':>10s} {'s/iter':>8s} {'x FDDP':>7s} {'s to target':>11s} "
          f"{'x FDDP':>7s} {'cost at equal time':>18s} {'x R-AICO':>8s}")
    for r in b["rows"]:
        print(f"{r['solver']:32s} {r['iterations']:5d} {r['final_cost']:10.4g} {r['iteration_median_s']:8.4f} "
              f"{r['iteration_ratio_to_fddp']:6.2f}x {f(r['time_to_target_s'], '11.2f')} "
              f"{f(r['time_to_target_ratio_to_fddp'], '6.2f', 'x')} {r['cost_at_budget']:18.4g} "
              f"{r['cost_at_budget_ratio_to_raico']:7.2f}x")


class _NotCached(Exception):
    pass


def cached_reproduce_row(artifacts: Path, reps: int = 3, ids: list[str] | None = None, quick: bool = False) -> dict:
    """``raico reproduce --all`` on a cache that holds every run (target: <= 15 s): the whole command,
    Python's start and the cache checks of every entry included (a stat per file; an entry published
    before stamps existed is re-hashed once, in the first sample). Skipped unless every run is cached
    (``make reproduce`` first): a probe whose executor refuses any job says so at the first one."""
    import subprocess
    import sys

    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.executors import Executor
    from raico.thesis.reproduce import ALL_IDS, reproduce

    ids = list(ids or ALL_IDS)
    args = ["--all"] if ids == list(ALL_IDS) else [a for fid in ids for a in ("--figure", fid)]
    args += ["--quick"] if quick else []
    name = f"make reproduce, every run cached (raico reproduce {' '.join(args)})"

    class Refuse(Executor):
        name = "refuse"

        def submit(self, fn, arg):
            raise _NotCached

    try:
        for _ in reproduce(Cache(artifacts), ids, quick=quick, executor=Refuse()):
            pass
    except _NotCached:
        print(f"{name:68s} skipped: not every run is cached under {artifacts} (make reproduce first)", flush=True)
        return {"benchmark": name, "detail": f"skipped: not every run is cached under {artifacts}"}
    raico = str(Path(sys.executable).with_name("raico"))
    samples = []
    for _ in range(reps):
        t0 = time.perf_counter()
        subprocess.run([raico, "reproduce", *args, "--quiet", "--artifacts", str(artifacts)], check=True,
                       stdout=subprocess.DEVNULL)
        samples.append(time.perf_counter() - t0)
    med, target = statistics.median(samples), 15.0
    print(f"{name:68s} median {med:8.3f} s   target {target:8.3f} s   {med / target:6.2f}x   (n={reps})", flush=True)
    return {"benchmark": name, "median_s": med, "samples_s": samples, "target_s": target,
            "ratio_to_target": med / target}


def write_only(out: Path, rows: list[dict], load_start: float) -> None:
    """The rows of a partial run (``--only``) into ``results.json``: each replaces the row of its name, or is added;
    the other rows and sections stay as the last whole run wrote them."""
    path = out / "results.json"
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        doc = {"machine": {}, "packages": package_versions(), "results": []}
    new = {r["benchmark"]: r for r in rows}
    doc["results"] = [new.pop(r["benchmark"], r) for r in doc.get("results", [])] + list(new.values())
    doc.setdefault("partial_runs", []).append({"rows": [r["benchmark"] for r in rows],
                                               "load_average_1min_start": load_start,
                                               "load_average_1min_end": os.getloadavg()[0],
                                               "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())})
    out.mkdir(parents=True, exist_ok=True)
    write_file_atomic(path, json.dumps(doc, indent=2))
    print(f"wrote {len(rows)} rows into {path}")


def main() -> None:
    global ARTIFACTS
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--artifacts", default="artifacts")
    ap.add_argument("--only", action="append", default=None, metavar="TEXT",
                    help="Run only the rows whose name contains TEXT (repeatable); their results replace the rows of "
                         "the same name in results.json, the others stay")
    args = ap.parse_args()
    ARTIFACTS = args.artifacts
    load_start = os.getloadavg()[0]
    rows = []
    for name, target, fn, fargs in CASES:
        if args.only and not any(t in name for t in args.only):
            continue
        samples = fn(*fargs)
        med = statistics.median(samples)
        rows.append({"benchmark": name, "median_s": med, "samples_s": samples, "target_s": target,
                     "ratio_to_target": med / target if target else None})
        tgt = f"{target:8.3f}" if target else "       -"
        ratio = f"{med / target:6.2f}x" if target else "      -"
        print(f"{name:68s} median {med:8.3f} s   target {tgt} s   {ratio}   (n={len(samples)})", flush=True)
    if args.only:
        write_only(Path(args.artifacts) / "bench", rows, load_start)
        return
    rows += model_learning_rows()
    from bench.scaling import run as scaling_rows

    rows += scaling_rows(Path(args.artifacts) / "bench")  # and bench/scaling.png
    from bench.model_files import run as model_file_rows

    # robots from model files: load times, per-iteration time against joints (also model_files.json and .md)
    rows += model_file_rows(Path(args.artifacts))
    rows.append(cached_reproduce_row(Path(args.artifacts)))
    baseline = bench_baseline()
    print_baseline(baseline)
    from bench.crocoddyl_problems import BENCH_PROBLEMS
    from bench.crocoddyl_problems import run as crocoddyl_problems

    # crocoddyl's own problems as problem files: every solver, each plan executed in Drake (also written
    # to crocoddyl_problems.json and .md)
    croc_problems = crocoddyl_problems(Path(args.artifacts), BENCH_PROBLEMS)
    from bench.suite import run as solver_suite
    from raico.pipeline.engine.runner import finite_json

    # every solver on every problem of raico/problems/suite, judged by performance profiles (suite.json, .md, .png)
    suite_doc = solver_suite(Path(args.artifacts))
    out = Path(args.artifacts) / "bench"
    out.mkdir(parents=True, exist_ok=True)
    doc = {"machine": {"python": platform.python_version(), "processor": platform.processor(),
                       "cpus": os.cpu_count(), "load_average_1min_start": load_start,
                       "load_average_1min_end": os.getloadavg()[0]},
           "packages": package_versions(), "results": rows, "crocoddyl_baseline": baseline,
           "crocoddyl_problems": croc_problems,
           "suite": {"page": suite_doc["outputs"][1], "profiles": finite_json(suite_doc["profiles"])}}
    write_file_atomic(out / "results.json", json.dumps(doc, indent=2))
    print(f"wrote {out / 'results.json'}")


if __name__ == "__main__":
    main()
