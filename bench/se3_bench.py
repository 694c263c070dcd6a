"""The frame pose errors (``FramePlacementError``, ``FrameRotationError``) on the Kinova reach
(``raico/problems/crocoddyl/kinova_reach.toml``): their batch (the SO(3) / SE(3) logarithms evaluated for
all rows at once) against the same batch with the logarithms row by row, and a whole R-AICO
iteration on that problem beside crocoddyl FDDP's.

``python -m bench.se3_bench [--out FILE]`` prints the rows (medians over repetitions; the machine is
shared and noisy) and with ``--out`` writes them as JSON in ``bench/run.py``'s row format. Not part
of ``make bench``; nothing here fails on a slow machine.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

PROBLEM = "raico/problems/crocoddyl/kinova_reach.toml"
FRAME = "j2s6s200_end_effector"
K = 101   # the problem's T + 1 steps


def _median_s(f, reps: int) -> tuple[float, list[float]]:
    f()   # warm up (builds and loads the kernels once)
    samples = []
    for _ in range(reps):
        t0 = time.perf_counter()
        f()
        samples.append(time.perf_counter() - t0)
    return statistics.median(samples), samples


def _rows_one_by_one(tm, Qp: np.ndarray):
    """The compiled batch with the logarithms row by row (``_residual``): what the batch did before
    it evaluated them for all rows at once."""
    kernels = tm.tree_kernels()
    b = kernels.tree.body(tm._body_name)
    R, Jw = kernels.frame_rotation_batch(Qp, b, tm._R_BF)
    pos, Jv = kernels.frame_points_batch(Qp, b, tm._R_BF, tm._p_BF, tm._origin)
    if not tm._needs_translation:
        return [tm._residual(R[k], None, None, Jw[k]) for k in range(len(Qp))]
    return [tm._residual(R[k], pos[k, 0], Jv[k], Jw[k]) for k in range(len(Qp))]


def rows(reps: int = 30) -> list[tuple[str, float, list[float]]]:
    from raico.planning.solvers import SOLVERS, solve
    from raico.plants.taskmaps import FramePlacementError, FrameRotationError
    from raico.stages.plan.stage import PlanConfig, build_problem, robot_and_task

    cfg = PlanConfig(problem=PROBLEM, iterations=30).normalized()
    robot, _ = robot_and_task(cfg)
    rng = np.random.default_rng(0)
    Q = robot.default_q + 0.3 * rng.standard_normal((K, robot.n_q))
    out = []
    maps = [FramePlacementError(robot, FRAME, np.eye(3), [0.6, 0.2, 0.5]), FrameRotationError(robot, FRAME, np.eye(3))]
    for tm in maps:
        kind = type(tm).__name__
        med, s = _median_s(lambda tm=tm: tm.values_and_jacobians(Q), reps)
        out.append((f"kinova {kind}.values_and_jacobians, K={K} (compiled kernels, batched logarithms)", med, s))
        med, s = _median_s(lambda tm=tm: _rows_one_by_one(tm, Q @ robot.P.T), reps)
        out.append((f"kinova {kind}: the same with the logarithms row by row (scalar functions)", med, s))
        tm._kernels = False   # Drake's calls row by row
        med, s = _median_s(lambda tm=tm: tm.values_and_jacobians(Q), max(3, reps // 5))
        out.append((f"kinova {kind}.values_and_jacobians, K={K} (Drake's calls, batched logarithms)", med, s))
    _, _, problem, _, _ = build_problem(cfg)
    solvers = [("R-AICO a=1", "raico", cfg.solver_options())]
    if "fddp" in SOLVERS:
        solvers.append(("crocoddyl FDDP (x0 held)", "fddp", {"iterations": 30}))
    for label, name, opts in solvers:
        res = solve(problem, name, opts)
        s = [h.time_s for h in res.history]
        out.append((f"kinova reach (T=100): one {label} iteration (median of {len(s)})", statistics.median(s), s))
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="write the rows as JSON here")
    ap.add_argument("--reps", type=int, default=30)
    args = ap.parse_args(argv)
    results = []
    for name, med, samples in rows(args.reps):
        print(f"{name:90s} median {1e3 * med:9.3f} ms", flush=True)
        results.append({"benchmark": name, "median_s": med, "samples_s": samples, "target_s": None,
                        "ratio_to_target": None})
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"results": results}, indent=1))


if __name__ == "__main__":
    main()
