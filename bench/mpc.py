"""Receding-horizon control's tick time on a 7-DOF arm: R-AICO against crocoddyl's FDDP in one harness.

``python -m bench.mpc [--artifacts DIR] [--ticks N]`` writes ``DIR/bench/mpc.json`` and ``mpc.md``.

The problems: ``problems/examples/xarm7_reach.toml`` and ``problems/crocoddyl/kinova_reach_in_range.toml``
(7-DOF arms, torque-controlled, analytic dynamics, dt = 10 ms, T = 100) with their hard bounds as the plan
stage sets them by default. R-AICO twice: one linearization per tick (``theta = inf``, as FDDP's one
iteration) and the thesis's relinearization inside the sweep (``theta = 0.1``). The controller
(``planning.mpc.MPC``): horizon H = 50 (0.5 s), one iteration per tick, each window warm-started from
the previous one shifted by a step; the first window solved beforehand (``prepare``, 50 iterations, not
timed). The loop is closed on the planning model itself (no simulator in the timed path): every tick
measures the state the previous control led to. Tick time: the wall time of ``MPC.tick``'s solve
(window update, warm start, the solver's iteration, the controller read out), per tick; median and
99th percentile over the run. One process, one run per solver, BLAS single-threaded, on a shared
machine: the ratio means more than the absolute times.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = {"xArm7 reach": "problems/examples/xarm7_reach.toml",
            "Kinova reach (in range)": "problems/crocoddyl/kinova_reach_in_range.toml"}
HORIZON = 50
TARGET_MEDIAN_S, TARGET_P99_S = 1e-3, 2e-3
SOLVERS = (("R-AICO (alpha 1, one linearization per tick)", "raico", {"alpha": 1.0, "theta": math.inf}),
           ("R-AICO (alpha 1, relinearized in the sweep, theta 0.1)", "raico", {"alpha": 1.0}),
           ("FDDP / BoxFDDP", "fddp", None))


def _problem(path: str):
    from stages.plan.stage import PlanConfig, build_problem

    cfg = PlanConfig(problem=str(ROOT / path), dynamics="analytic", q0_std=0.0)
    return build_problem(cfg)[2]


def run_one(problem, solver: str, options, ticks: int) -> dict:
    """One closed loop of ``ticks`` ticks: tick times (s), iterations, the last window cost, whether x stayed finite."""
    from planning.mpc import MPC
    from planning.problem import single_threaded_blas

    mpc = MPC(problem, HORIZON, solver, options, iterations=1, ticks=ticks)
    with single_threaded_blas():
        mpc.prepare(problem.x0, 50)
        x = problem.x0.copy()
        for _ in range(ticks):
            u, _, _ = mpc.tick(x)
            x = problem.dynamics.step(x, u)
            if not np.all(np.isfinite(x)):   # the loop blew up: no more ticks to time
                break
    t = mpc.log.solve_time[:mpc.log.n]
    return {"ticks": int(mpc.log.n), "median_s": float(np.median(t)), "p99_s": float(np.percentile(t, 99)),
            "max_s": float(t.max()), "iterations": int(mpc.log.iterations[:mpc.log.n].sum()),
            "final_window_cost": float(mpc.log.cost[mpc.log.n - 1]), "finite": bool(np.all(np.isfinite(x)))}


def markdown(rows: list[dict], load: tuple[float, float]) -> str:
    lines = [f"7-DOF arms, horizon {HORIZON} at dt = 10 ms, one iteration per tick, the loop closed on the planning "
             f"model; target: median <= {TARGET_MEDIAN_S * 1e3:g} ms, p99 <= {TARGET_P99_S * 1e3:g} ms. Machine: "
             f"{os.cpu_count()} cores, 1-minute load average {load[0]:.2f} at the start, {load[1]:.2f} at the end.", "",
             "| problem | solver | ticks | median tick (ms) | p99 tick (ms) | max (ms) | loop stayed finite | "
             "meets the target |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ok = r["finite"] and r["median_s"] <= TARGET_MEDIAN_S and r["p99_s"] <= TARGET_P99_S
        lines.append(f"| {r['problem']} | {r['solver']} | {r['ticks']} | {r['median_s'] * 1e3:.3f} | "
                     f"{r['p99_s'] * 1e3:.3f} | {r['max_s'] * 1e3:.3f} | {'yes' if r['finite'] else 'no'} | "
                     f"{'yes' if ok else 'no'} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--artifacts", default="artifacts")
    ap.add_argument("--ticks", type=int, default=100)
    args = ap.parse_args(argv)
    rows, start = [], os.getloadavg()[0]
    for name, path in PROBLEMS.items():
        problem = _problem(path)
        for label, solver, opts in SOLVERS:
            rows.append({"problem": name, "solver": label, **run_one(problem, solver, opts, args.ticks)})
    out = Path(args.artifacts) / "bench"
    out.mkdir(parents=True, exist_ok=True)
    (out / "mpc.json").write_text(json.dumps(rows, indent=2, allow_nan=True))
    page = markdown(rows, (start, os.getloadavg()[0]))
    (out / "mpc.md").write_text(page)
    sys.stdout.write(page)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
