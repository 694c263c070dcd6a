"""The learned model's MPC tick: the model file plus the residual GP, compiled per step against the Python path.

The plans of the residual-GP loop of ``experiments/ur5_payload_push_mpc_learn.toml`` (its MPC point, seed 0, the
episodes' learned models: the GP refit on more data each episode) are controlled by MPC R-AICO (horizon 50, one
iteration per tick, the uncertainty term in the window) in a closed loop on the controller's own model (the plant
is the learned model: the tick's cost, not the task, is measured), once with the compiled step of the model file
plus the residual GP (``raico.plants.learned.ResidualKernel``: the sweeps' relinearizations, the rollouts and the
window's linearization in C) and once stepping it in Python (``ResidualDynamics.compiled = False``). Per tick: CPU
time (``time.process_time``, this process) and wall time of the solve; medians and p90 over the ticks; the two
paths' windows compared. The page: ``artifacts/bench/learned_tick.md`` (+ ``.json``).

    python -m bench.learned_tick [--ticks 100] [--artifacts artifacts]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
HORIZON = 50


def learned_plans(artifacts: str) -> list:
    """The plan artifacts of the MPC point's loop, seed 0 (run or found in the bench's cache, shared with
    ``bench.mpc_learn``), one per episode, and each episode's GP size."""
    from bench.mpc_learn import variants
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.runner import run
    from raico.stages.learn import LearnConfig

    base, points = variants()
    point = next(p for p in points if p.get("controller") == "mpc")
    cfg = {**base, **{k: v for k, v in point.items() if k != "label"}, "seed": 0}
    cfg["push"] = tuple(cfg["push"])
    cache = Cache(Path(artifacts) / "bench" / "mpc_learn")
    out = run(cache, "learn", LearnConfig(**cfg), record=False)
    eps = json.loads((Path(out.path) / "episodes.json").read_text())["episodes"]
    return [(e["episode"], e["n_points"], cache.require("plan", e["plan"])) for e in eps]


def closed_loop(plan, compiled: bool, ticks: int) -> dict:
    """MPC on the plan's learned model, ticked ``ticks`` times in a closed loop on that model; per-tick CPU and
    wall times (s) and the last window."""
    from raico.planning.mpc import MPC
    from raico.plants.learned import ResidualDynamics
    from raico.stages.execute.stage import planning_problem

    saved = ResidualDynamics.compiled
    ResidualDynamics.compiled = compiled
    try:
        problem = planning_problem(plan)
        P = plan.arrays("plan.npz")
        ticks = min(ticks, problem.T)
        mpc = MPC(problem, HORIZON, "raico", iterations=1)
        mpc.start_from(P["X"], P["U"], P["o"], P["O"])
        cpu, x = np.empty(ticks), P["X"][0].copy()
        windows = []
        for k in range(ticks):
            c0 = time.process_time()
            u, _, _ = mpc.tick(x)
            cpu[k] = time.process_time() - c0
            windows.append(mpc.X.copy())
            x = problem.dynamics.step(x, u)
        return {"cpu": cpu, "wall": mpc.log.solve_time[:ticks].copy(), "windows": np.array(windows),
                "compiled": learned_kernel(problem) is not None}
    finally:
        ResidualDynamics.compiled = saved


def learned_kernel(problem):
    """The compiled kernel the problem's model uses (None: the Python path)."""
    c = getattr(problem.dynamics, "c_linearizer", None)
    return None if c is None else c()


def measure(artifacts: str, ticks: int = 100) -> dict:
    """Both paths on every episode's plan; the numbers of the page."""
    load0 = os.getloadavg()[0]
    rows = []
    for episode, n_points, plan in learned_plans(artifacts):
        fast, slow = closed_loop(plan, True, ticks), closed_loop(plan, False, ticks)
        scale = float(np.abs(slow["windows"]).max())
        rows.append({"episode": episode, "n_points": n_points, "ticks": len(fast["cpu"]),
                     "compiled_built": fast["compiled"] and not slow["compiled"],
                     "cpu_ms": [1e3 * float(np.median(r["cpu"])) for r in (slow, fast)],
                     "cpu_p90_ms": [1e3 * float(np.percentile(r["cpu"], 90)) for r in (slow, fast)],
                     "wall_ms": [1e3 * float(np.median(r["wall"])) for r in (slow, fast)],
                     "window_diff": float(np.abs(fast["windows"] - slow["windows"]).max()) / scale})
    return {"rows": rows, "horizon": HORIZON, "load": f"{load0:.2f} at the start, {os.getloadavg()[0]:.2f} at the end"}


def page(doc: dict) -> str:
    """The markdown block."""
    lines = [f"MPC R-AICO (horizon {doc['horizon']}, one iteration per tick, the uncertainty term in the window) on "
             "the learned model of each episode of the residual-GP loop of "
             "`experiments/ur5_payload_push_mpc_learn.toml` (seed 0), ticked in a closed loop on that model; "
             "the model file plus the residual GP stepped in Python, then compiled (`residual_step.c`). CPU time "
             "of the tick in this process; wall time of the solve. Load average "
             f"{doc['load']} (2 cores shared: wall times under load).", "",
             "| episode's model | GP points | ticks | CPU per tick, median: Python / compiled (ms) | p90 (ms) | "
             "wall per tick, median (ms) | speed-up (CPU) | windows' largest difference (relative) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in doc["rows"]:
        c, p, w = r["cpu_ms"], r["cpu_p90_ms"], r["wall_ms"]
        lines.append(f"| {r['episode']} | {r['n_points']} | {r['ticks']} | {c[0]:.1f} / {c[1]:.1f} | "
                     f"{p[0]:.1f} / {p[1]:.1f} | {w[0]:.1f} / {w[1]:.1f} | {c[0] / c[1]:.2f}x | "
                     f"{r['window_diff']:.1e} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ticks", type=int, default=100)
    ap.add_argument("--artifacts", default=str(ROOT / "artifacts"))
    args = ap.parse_args()
    out = Path(args.artifacts) / "bench"
    out.mkdir(parents=True, exist_ok=True)
    doc = measure(args.artifacts, args.ticks)
    (out / "learned_tick.json").write_text(json.dumps(doc, indent=1))
    (out / "learned_tick.md").write_text(page(doc))
    print(page(doc))


if __name__ == "__main__":
    main()
