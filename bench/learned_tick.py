"""The learned model's MPC tick: the model file plus the residual GP, compiled per step against the Python path.

The plans of the residual-GP loop of ``experiments/ur5_payload_push_mpc_learn.toml`` (its MPC point, seed 0, the
episodes' learned models: the GP refit on more data each episode) are controlled by MPC R-AICO (horizon 50, one
iteration per tick, the uncertainty term in the window) in a closed loop on the controller's own model (the plant
is the learned model: the tick's cost, not the task, is measured), once with the compiled step of the model file
plus the residual GP (``raico.plants.learned.ResidualKernel``: the sweeps' relinearizations, the rollouts and the
window's linearization in C) and once stepping it in Python (``ResidualDynamics.compiled = False``). Per tick: CPU
time (``time.process_time``, this process) and wall time of the solve; medians and p90 over the ticks; the two
paths' windows compared. Then episode 1 of the loop with a sparse GP, without and with the online update
(``online_rows``). The page: ``artifacts/bench/learned_tick.md`` (+ ``.json``).

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
INDUCING = 100       # the online rows' sparse GP: fixed inducing points
ONLINE_EVERY = 10    # planning steps between the online updates
ONLINE_SEEDS = 3


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
    online = online_rows(artifacts)
    return {"rows": rows, "online": online, "horizon": HORIZON,
            "load": f"{load0:.2f} at the start, {os.getloadavg()[0]:.2f} at the end"}


def online_rows(artifacts: str, seeds: int = ONLINE_SEEDS) -> list[dict]:
    """Episode 1 of the MPC point's loop with a sparse GP (``INDUCING`` fixed inducing points), without and with
    the online update every ``ONLINE_EVERY`` planning steps, per seed: the executed distance, the status, the MPC
    model's one-step error along the execution, the median tick and the updates made."""
    from bench.mpc_learn import REACH_TERM, one_step_error, variants
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.runner import run
    from raico.stages.learn import LearnConfig

    base, points = variants()
    point = next(p for p in points if p.get("controller") == "mpc")
    cache = Cache(Path(artifacts) / "bench" / "mpc_learn")
    rows = []
    for seed in range(seeds):
        for every in (0, ONLINE_EVERY):
            cfg = {**base, **{k: v for k, v in point.items() if k != "label"}, "seed": seed, "episodes": 1,
                   "gp": "sparse", "inducing": INDUCING, "online_every": every}
            cfg["push"] = tuple(cfg["push"])
            out = run(cache, "learn", LearnConfig(**cfg), record=False)
            ep = json.loads((Path(out.path) / "episodes.json").read_text())["episodes"][0]
            ex = cache.require("execute", ep["execute"])
            r, m = ex.arrays("rollout.npz"), ex.metrics
            rows.append({"seed": seed, "online_every": every, "distance_m": m["via_point_errors"][REACH_TERM],
                         "status": ex.status, "one_step_error": one_step_error(r["X"], r.get("mpc_predicted")),
                         "tick_s": m.get("mpc_median_tick_s"), "updates": m.get("mpc_online_updates", 0)})
    return rows


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
    if doc.get("online"):
        lines += ["", f"The online update (`--online-every {ONLINE_EVERY}`) in episode 1 of the same loop with a sparse "
                  f"GP ({INDUCING} fixed inducing points; `--gp sparse`), per seed, without and with it:", "",
                  "| seed | online update | executed distance to the target (cm) | status | MPC's model, one-step error, "
                  "median (rad/s) | updates | median tick, wall (ms) |", "|---|---|---|---|---|---|---|"]
        for r in doc["online"]:
            every = f"every {r['online_every']} steps" if r["online_every"] else "none"
            err = "-" if r["one_step_error"] is None else f"{r['one_step_error']:.3g}"
            tick = "-" if not r["tick_s"] else f"{1e3 * r['tick_s']:.0f}"
            lines.append(f"| {r['seed']} | {every} | {100 * r['distance_m']:.2f} | {r['status']} | {err} | "
                         f"{r['updates']} | {tick} |")
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
