"""Timings of FastAnalyticDynamics against AnalyticDynamics (prints a small table).

    .venv/bin/python -m bench.fastdyn_bench [--plant arm5] [--T 1000] [--reps 5]

Medians of ``reps`` runs (the machine is shared and noisy); one BLAS thread. Not a test.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from raico.plants.codegen.derive import compiled_dynamics
from raico.plants.dynamics import AnalyticDynamics
from raico.plants.fast_analytic import FastAnalyticDynamics
from raico.plants.robots import load_robot


def _median_time(fn, reps: int) -> float:
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plant", default="arm5")
    ap.add_argument("--T", type=int, default=1000)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--dt", type=float, default=0.002)
    args = ap.parse_args(argv)

    robot = load_robot(args.plant)
    t0 = time.perf_counter()
    code = compiled_dynamics(robot)  # symbolic derivation + code generation + self-check
    build = time.perf_counter() - t0
    fast, exact = FastAnalyticDynamics(robot, args.dt), AnalyticDynamics(robot, args.dt)

    rng = np.random.default_rng(0)
    n, T = robot.n_q, args.T
    X = np.concatenate([robot.default_q + 0.3 * rng.standard_normal((T, n)),
                        rng.standard_normal((T, n))], axis=1)
    U = 3.0 * rng.standard_normal((T, n))
    fast.linearize_trajectory(X[:2], U[:2])  # warm up
    exact.linearize_trajectory(X[:2], U[:2])

    traj_exact = _median_time(lambda: exact.linearize_trajectory(X, U), args.reps)
    traj_fast = _median_time(lambda: fast.linearize_trajectory(X, U), args.reps)
    k = 200
    point_exact = _median_time(lambda: [exact.linearize(X[i], U[i]) for i in range(k)], args.reps) / k
    point_fast = _median_time(lambda: [fast.linearize(X[i], U[i]) for i in range(k)], args.reps) / k
    step_exact = _median_time(lambda: [exact.step(X[i], U[i]) for i in range(k)], args.reps) / k
    step_fast = _median_time(lambda: [fast.step(X[i], U[i]) for i in range(k)], args.reps) / k

    A, a, B = fast.linearize_trajectory(X[:50], U[:50])
    A0, a0, B0 = exact.linearize_trajectory(X[:50], U[:50])
    err = max(np.max(np.abs(A - A0)) / np.max(np.abs(A0)), np.max(np.abs(B - B0)) / np.max(np.abs(B0)))

    rows = [
        (f"linearize_trajectory T={T}", traj_exact * 1e3, traj_fast * 1e3, "ms"),
        ("linearize (one point)", point_exact * 1e6, point_fast * 1e6, "us"),
        ("step (one point)", step_exact * 1e6, step_fast * 1e6, "us"),
    ]
    print(f"plant {args.plant}: build {build:.2f} s (symbolic derivation, code generation, "
          f"self-check), {code.stats['ops_first'] + code.stats['ops_second']} generated operations, "
          f"cyclic positions {code.stats['cyclic_positions']}")
    print(f"{'':32s} {'AnalyticDynamics':>17s} {'FastAnalytic':>13s} {'speed-up':>9s}")
    for name, slow, quick, unit in rows:
        print(f"{name:32s} {slow:14.3f} {unit} {quick:10.3f} {unit} {slow / quick:8.1f}x")
    print(f"max relative difference of A, B (50 points): {err:.1e}")
    return {"build_s": build, "traj_exact_s": traj_exact, "traj_fast_s": traj_fast,
            "point_exact_s": point_exact, "point_fast_s": point_fast, "max_rel_diff": float(err)}


if __name__ == "__main__":
    main()
