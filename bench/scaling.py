"""How cost grows with the work: ``make bench`` -> rows in ``results.json`` and
``artifacts/bench/scaling.png``.

    .venv/bin/python -m bench.scaling [--artifacts artifacts]

Three sweeps, each a median over repetitions of a time per unit of work, with the exponent of a
least-squares line through ``log(time)`` against ``log(size)`` beside the exponent the algorithm
predicts:

- **Horizon** ``T`` (250 to 4000 steps, arm5 analytic reach, its via-points at ``T/2`` and ``T``):
  R-AICO (alpha = 1) and crocoddyl FDDP, seconds per iteration; expected ``O(T n^3)``: exponent 1.
- **State dimension** ``n_x`` (pendulum 2, arm5 10, Nao 50; every task at the same ``T``): R-AICO
  seconds per iteration; expected ``O(T n^3)``: exponent 3 once the dense ``n x n`` algebra dominates.
  Measured (one run, 2-core VM): about 1.1-1.2 up to the Nao's ``n_x = 50``: at these sizes the
  per-step work that grows more slowly (dynamics and task-map evaluations, the compiled sweep's
  per-step overhead) outweighs the cubic factorizations; the exponent is reported as measured.
- **GP training points** ``N`` (250 to 4000; d = 15 inputs, BioRob-like, one output): one log
  marginal likelihood with its gradient (what every optimizer step of the fit costs), expected
  ``O(N^3)``: exponent 3; the posterior (mean, variance and all input gradients at ``M = 500``
  points, one output), expected ``O(M N^2)``: exponent 2.

One BLAS thread (the project's policy per process). Not a test: nothing here fails on a slow machine.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

HORIZONS = (250, 500, 1000, 2000, 4000)
DIM_T = 300
GP_POINTS = (250, 500, 1000, 2000, 4000)
GP_M, GP_D = 500, 15
ITERATIONS = 4


def _problem(plant: str, task: str, dynamics: str, T: int):
    """The task's problem at horizon ``T`` (its via-point steps scaled with the horizon; seed 0)."""
    from raico.planning.objective import build_terms
    from raico.planning.problem import Problem
    from raico.planning.problem_file import read_problem, shipped, with_horizon
    from raico.planning.tasks import task_from_problem
    from raico.plants.dynamics_registry import make_dynamics
    from raico.stages.plan.stage import control_kind, initial_posture, shared_robot

    robot = shared_robot(plant)
    spec = task_from_problem(with_horizon(read_problem(shipped(plant, task)), T))
    q0 = initial_posture(robot, 0.05, 0)
    dyn = make_dynamics(dynamics, robot, spec.dt, None)
    objective = build_terms(robot, spec.build(robot, q0, T), T, control_kind(dyn))
    x0 = np.concatenate([q0, np.zeros(robot.n_q)])
    return Problem(dyn, x0, T, objective.state_terms, objective.control_terms, objective.joint_terms)


def seconds_per_iteration(plant: str, task: str, dynamics: str, T: int, solver: str, reps: int = 2) -> float:
    """Median wall time (s) of one iteration of ``solver`` (``ITERATIONS`` iterations per run)."""
    from bench.model_files import records_after
    from raico.planning.solvers import solve
    from raico.stages.plan.stage import PlanConfig

    opts = PlanConfig(plant=plant, task=task, dynamics=dynamics, solver=solver, iterations=ITERATIONS).solver_options()
    per = []
    for _ in range(reps):   # crocoddyl's records made after its solve: no raico work between its iterations
        res = solve(_problem(plant, task, dynamics, T), solver, opts, **records_after(solver))
        per += [h.time_s for h in res.history]
    return float(statistics.median(per))


def exponent(sizes, times) -> float:
    """Slope of ``log(time)`` against ``log(size)`` (least squares)."""
    x, y = np.log(np.asarray(sizes, float)), np.log(np.asarray(times, float))
    return float(np.polyfit(x, y, 1)[0])


def _gp_times(N: int, rng: np.random.Generator, reps: int = 3) -> tuple[float, float]:
    """(lml + gradient, posterior with gradients at ``GP_M`` points) in s, one output, ``N`` points."""
    from raico.plants.gp import GPModel
    from raico.stages.fit.gp_fit import lml_and_gradient

    X = rng.normal(size=(N, GP_D))
    Y = np.sin(X[:, :5]).sum(1, keepdims=True) + 0.01 * rng.normal(size=(N, 1))
    Xq = rng.normal(size=(GP_M, GP_D))
    theta = np.log(np.r_[1.0, np.full(GP_D, 2.0), 1e-3])
    Z = (X - X.mean(0)) / X.std(0)
    y = (Y[:, 0] - Y.mean()) / Y.std()
    t_lml, t_post = [], []
    model = GPModel(X, Y, np.full((1, GP_D), 2.0), np.ones(1), np.full(1, 1e-3))
    for _ in range(reps):
        t0 = time.perf_counter()
        lml_and_gradient(theta, Z, y)
        t_lml.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        model.predict_with_gradients(Xq)
        t_post.append(time.perf_counter() - t0)
    return float(statistics.median(t_lml)), float(statistics.median(t_post))


def run(out_dir: Path | None = None) -> list[dict]:
    """The three sweeps as result rows (and ``scaling.png`` in ``out_dir``)."""
    from threadpoolctl import threadpool_limits

    from raico.planning.crocoddyl import AVAILABLE

    rows, curves = [], {}
    with threadpool_limits(1):
        solvers = ("raico", "fddp") if AVAILABLE else ("raico",)
        for solver in solvers:
            ts = [seconds_per_iteration("arm5", "reach", "analytic", T, solver) for T in HORIZONS]
            curves[f"horizon/{solver}"] = (HORIZONS, ts)
        dims = (("pendulum", "swing-up", "analytic", 2), ("arm5", "reach", "analytic", 10), ("nao", "balance", "pseudo", 50))
        ts = [seconds_per_iteration(p, t, d, DIM_T, "raico") for p, t, d, _ in dims]
        curves["state/raico"] = ([n for *_, n in dims], ts)
        rng = np.random.default_rng(0)
        gp = [_gp_times(N, rng) for N in GP_POINTS]
        curves["gp/fit"] = (GP_POINTS, [g[0] for g in gp])
        curves["gp/posterior"] = (GP_POINTS, [g[1] for g in gp])
    expected = {"horizon/raico": 1.0, "horizon/fddp": 1.0, "state/raico": 3.0, "gp/fit": 3.0, "gp/posterior": 2.0}
    what = {"horizon/raico": "R-AICO s/iteration vs horizon T (arm5 analytic)",
            "horizon/fddp": "crocoddyl FDDP s/iteration vs horizon T (arm5 analytic)",
            "state/raico": f"R-AICO s/iteration vs state dimension (pendulum, arm5, Nao; T = {DIM_T})",
            "gp/fit": f"GP log marginal likelihood + gradient vs training points N (d = {GP_D})",
            "gp/posterior": f"GP posterior with all input gradients at M = {GP_M} vs training points N"}
    for name, (sizes, ts) in curves.items():
        # the exponent over the upper half of the sizes, where the leading term dominates
        k = max(2, len(sizes) // 2 + 1)
        rows.append({"benchmark": f"scaling: {what[name]}", "sizes": list(sizes), "seconds": ts,
                     "exponent": exponent(sizes, ts), "exponent_upper": exponent(sizes[-k:], ts[-k:]),
                     "expected_exponent": expected[name]})
        print(f"{what[name]:75s} exponent {rows[-1]['exponent']:.2f} (upper sizes {rows[-1]['exponent_upper']:.2f}; "
              f"expected {expected[name]:g}); " + ", ".join(f"{s}: {t * 1e3:.3g} ms" for s, t in zip(sizes, ts)),
              flush=True)
    if out_dir is not None:
        plot(curves, rows, out_dir / "scaling.png")
    return rows


def plot(curves: dict, rows: list[dict], path: Path) -> None:
    """Three log-log panels, each curve with its measured and expected exponent in the legend."""
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = {"horizon": ("horizon T (steps)", "s / iteration"), "state": ("state dimension n_x", "s / iteration"),
              "gp": ("training points N", "s per call (one output)")}
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    for ax, (panel, (xl, yl)) in zip(axes, panels.items()):
        for (name, (sizes, ts)), row in zip(curves.items(), rows):
            if name.split("/")[0] != panel:
                continue
            ax.loglog(sizes, ts, "o-", label=f"{name.split('/')[1]}: slope {row['exponent']:.2f} "
                                              f"(expected {row['expected_exponent']:g})")
        sizes = sorted({s for name, (ss, _) in curves.items() if name.split("/")[0] == panel for s in ss})
        ax.set_xticks(sizes, [str(s) for s in sizes])
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_title("planner vs horizon")
    axes[1].set_title("planner vs state dimension")
    axes[2].set_title("GP vs training points")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--artifacts", default="artifacts")
    args = ap.parse_args()
    rows = run(Path(args.artifacts) / "bench")
    print(json.dumps(rows, indent=1)[:2000])


if __name__ == "__main__":
    main()
