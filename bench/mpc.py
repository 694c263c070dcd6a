"""Receding-horizon control's tick time on a 7-DOF arm: R-AICO against crocoddyl's FDDP in one harness.

``python -m bench.mpc [--artifacts DIR] [--ticks N] [--split-only]`` writes ``DIR/bench/mpc.json``, ``mpc.md``,
``mpc_split.md`` / ``.json`` (the preparation / feedback split's latency against the whole tick; ``--split-only``:
only these),
``mpc_predicted_horizons.png`` (the xArm7 tracking a moving target in Drake: the predicted windows, the
executed paths, the solve time per tick) and ``mpc_pushed_arm5.png`` (arm5's reach pushed in Drake under the
plan's controller and under MPC); the Drake runs cached in ``DIR/bench/mpc``.

The problems: ``raico/problems/examples/xarm7_reach.toml``, ``raico/problems/crocoddyl/kinova_reach_in_range.toml``
and ``raico/problems/examples/xarm7_track.toml`` (7-DOF arms, torque-controlled, analytic dynamics, dt = 10 ms,
T = 100; the tracking T = 200) with their hard bounds as the plan stage sets them by default. R-AICO twice: one linearization per tick (``theta = inf``, as FDDP's one
iteration) and the thesis's relinearization inside the sweep (``theta = 0.1``). The controller
(``raico.planning.mpc.MPC``): horizon H = 50 (0.5 s), one iteration per tick, each window warm-started from
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
PROBLEMS = {"xArm7 reach": "raico/problems/examples/xarm7_reach.toml",
            "Kinova reach (in range)": "raico/problems/crocoddyl/kinova_reach_in_range.toml",
            "xArm7 tracking a moving target": "raico/problems/examples/xarm7_track.toml"}
HORIZON = 50
TARGET_MEDIAN_S, TARGET_P99_S = 1e-3, 2e-3
SOLVERS = (("R-AICO (alpha 1, one linearization per tick)", "raico", {"alpha": 1.0, "theta": math.inf}),
           ("R-AICO (alpha 1, relinearized in the sweep, theta 0.1)", "raico", {"alpha": 1.0}),
           ("FDDP / BoxFDDP", "fddp", None))


def _problem(path: str):
    from raico.stages.plan.stage import PlanConfig, build_problem

    cfg = PlanConfig(problem=str(ROOT / path), dynamics="analytic", q0_std=0.0)
    return build_problem(cfg)[2]


def run_one(problem, solver: str, options, ticks: int, phases: bool = False) -> dict:
    """One closed loop of ``ticks`` ticks: tick times (s; wall and the thread's CPU time, which the other
    processes of a loaded machine do not inflate), iterations, the last window cost, whether x stayed finite;
    ``phases``: the CPU time of the tick's parts (:func:`_phase_clock`, R-AICO's workspace only)."""
    import time

    from raico.planning.mpc import MPC
    from raico.planning.problem import single_threaded_blas

    mpc = MPC(problem, HORIZON, solver, options, iterations=1, ticks=ticks)
    cpu = np.full(ticks, np.nan)
    with single_threaded_blas():
        mpc.prepare(problem.x0, 50)
        clock = _phase_clock(mpc) if phases else None
        x = problem.x0.copy()
        for k in range(ticks):
            c0 = time.thread_time()
            u, _, _ = mpc.tick(x)
            cpu[k] = time.thread_time() - c0
            x = problem.dynamics.step(x, u)
            if not np.all(np.isfinite(x)):   # the loop blew up: no more ticks to time
                break
    n = mpc.log.n
    t, cpu = mpc.log.solve_time[:n], cpu[:n]
    out = {"ticks": int(n), "median_s": float(np.median(t)), "p99_s": float(np.percentile(t, 99)),
           "max_s": float(t.max()), "cpu_median_s": float(np.median(cpu)), "cpu_p99_s": float(np.percentile(cpu, 99)),
           "iterations": int(mpc.log.iterations[:n].sum()),
           "final_window_cost": float(mpc.log.cost[n - 1]), "finite": bool(np.all(np.isfinite(x)))}
    if clock is not None:
        out["phases_s"] = {name: v / n for name, v in clock.items()}
        out["phases_s"]["rest of the tick (Python: the tick's bookkeeping, calls, records)"] = (
            float(cpu.sum()) / n - sum(out["phases_s"].values()))
    return out


def split_latency(problem, solver: str, options, ticks: int) -> dict:
    """:func:`run_one`'s loop with the split tick (``MPC(..., split=True)``): per tick the thread's CPU time and
    the wall time of the feedback phase (measurement in, control out: ``SplitTick.feedback``) and the CPU time
    of the preparation (``SplitTick.prepare``); the first tick (its window solved whole in the feedback) left
    out of the statistics."""
    import time

    from raico.planning.mpc import MPC
    from raico.planning.problem import single_threaded_blas

    mpc = MPC(problem, HORIZON, solver, options, iterations=1, ticks=ticks, split=True)
    fb, wall, prep, empty = (np.full(ticks, np.nan) for _ in range(4))
    with single_threaded_blas():
        mpc.prepare(problem.x0, 50)
        sp, x = mpc.split, problem.x0.copy()
        for k in range(ticks):
            w0, c0 = time.perf_counter(), time.thread_time()
            u = sp.feedback(x)
            c1, w1 = time.thread_time(), time.perf_counter()
            x = problem.dynamics.step(x, u)     # the control out: the plant moves while the next tick is prepared
            sp.prepare()
            fb[k], wall[k], prep[k] = c1 - c0, w1 - w0, time.thread_time() - c1
            e0 = time.thread_time()
            empty[k] = time.thread_time() - e0     # the clock's own share of an interval
            if not np.all(np.isfinite(x)):
                break
    n = mpc.log.n
    f, w, p = fb[1:n], wall[1:n], prep[1:n]
    return {"ticks": int(n), "feedback_cpu_median_s": float(np.median(f)), "feedback_cpu_p99_s": float(np.percentile(f, 99)),
            "feedback_median_s": float(np.median(w)), "feedback_p99_s": float(np.percentile(w, 99)),
            "prepare_cpu_median_s": float(np.median(p)), "finite": bool(np.all(np.isfinite(x))),
            "empty_interval_cpu_median_s": float(np.median(empty[1:n])),
            "final_window_cost": float(mpc.log.cost[n - 1])}


def split_rows(ticks: int) -> list[dict]:
    """Per problem and R-AICO configuration: the whole tick (:func:`run_one`) and the split (:func:`split_latency`),
    one after the other in this process."""
    rows = []
    for name, path in PROBLEMS.items():
        problem = _problem(path)
        for label, solver, opts in SOLVERS:
            if solver == "fddp":
                continue
            rows.append({"problem": name, "solver": label, "whole": run_one(problem, solver, opts, ticks),
                         "split": split_latency(problem, solver, opts, ticks)})
    return rows


def split_markdown(rows: list[dict], load: tuple[float, float]) -> str:
    clock = float(np.median([r["split"]["empty_interval_cpu_median_s"] for r in rows]))
    lines = [f"The preparation / feedback split (`MPC(..., split=True)`, `--rti`): the feedback phase (measurement in, "
             f"control out: `u = o_0 + O_0 x`) against today's whole tick, in the loop above (horizon {HORIZON}, one "
             "iteration per tick, the loop closed on the planning model; the first tick, solved whole, left out). "
             f"Machine: {os.cpu_count()} cores, 1-minute load average {load[0]:.2f} at the start, {load[1]:.2f} at the "
             "end (shared). CPU: the thread's time (`time.thread_time`; an empty interval measures "
             f"{clock * 1e6:.1f} us, included in the feedback's); wall: `time.perf_counter`.", "",
             "| problem | solver | whole tick CPU median (ms) | whole tick CPU p99 (ms) | feedback CPU median (us) | "
             "feedback CPU p99 (us) | feedback wall median (us) | feedback wall p99 (us) | preparation CPU median (ms) | "
             "loop finite (whole / split) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        w, s = r["whole"], r["split"]
        lines.append(f"| {r['problem']} | {r['solver']} | {w['cpu_median_s'] * 1e3:.3f} | {w['cpu_p99_s'] * 1e3:.3f} | "
                     f"{s['feedback_cpu_median_s'] * 1e6:.1f} | {s['feedback_cpu_p99_s'] * 1e6:.1f} | "
                     f"{s['feedback_median_s'] * 1e6:.1f} | {s['feedback_p99_s'] * 1e6:.1f} | "
                     f"{s['prepare_cpu_median_s'] * 1e3:.3f} | {'yes' if w['finite'] else 'no'} / "
                     f"{'yes' if s['finite'] else 'no'} |")
    return "\n".join(lines) + "\n"


def write_split(out: Path, ticks: int) -> str:
    start = os.getloadavg()[0]
    rows = split_rows(ticks)
    page = split_markdown(rows, (start, os.getloadavg()[0]))
    (out / "mpc_split.json").write_text(json.dumps(rows, indent=2, allow_nan=True))
    (out / "mpc_split.md").write_text(page)
    return page


def window_end(problem, substeps: int = 10) -> dict:
    """Why FDDP's loop leaves the finite states on a problem: its first window (``prepare``, 50 iterations from
    ``x0`` held) against R-AICO's (alpha 1): each window's cost, its largest joint velocity (rad/s) at the
    window's last step and 10 steps before it, and the same controls stepped at ``dt / substeps`` on the robot's
    analytic model (the discretization's share); and the loops' fates (``run_one``'s ticks, finite)."""
    from raico.planning.mpc import MPC
    from raico.plants.dynamics import AnalyticDynamics

    fine = AnalyticDynamics(problem.dynamics.robot, problem.dynamics.dt / substeps)
    n = problem.n_x // 2
    out = {}
    for label, solver, opts in (("FDDP / BoxFDDP", "fddp", None), ("R-AICO (alpha 1)", "raico", {"alpha": 1.0})):
        mpc = MPC(problem, HORIZON, solver, opts, iterations=1, ticks=1)
        mpc.prepare(problem.x0, 50)
        x, v_fine = problem.x0.copy(), 0.0
        for u in mpc.U:
            for _ in range(substeps):
                x = fine.step(x, u)
            v_fine = max(v_fine, float(np.abs(x[n:]).max()))
        out[label] = {"cost": float(mpc.window.cost(mpc.X, mpc.U)),
                      "v_end": float(np.abs(mpc.X[-1, n:]).max()), "v_before": float(np.abs(mpc.X[-11, n:]).max()),
                      "v_fine_max": v_fine, "u_max": float(np.abs(mpc.U).max())}
    return out


PHASES = {"shift (messages, controller, multipliers)": ("ws", "shift"),
          "warm start: the shifted controller rolled out from the measured state": ("ws", "start_at"),
          "task rows: cost and its derivatives (compiled)": ("sw", "_cost"),
          "linearization: dynamics, checks, boxes' model (compiled), control and task messages (numpy)": ("sw", "linearize_all"),
          "sweep (compiled kernel)": ("sw", "sweep"),
          "rollout of the new controller, clipped": ("ws", "_rollout"),
          "constraints' multipliers update (compiled boxes)": ("al", "update"),
          "the window's term times refreshed (Python, each term asked; where they changed)": ("ws", "refresh_times")}


def _phase_clock(mpc) -> dict[str, float]:
    """Wrap the parts of R-AICO's tick (:data:`PHASES`) on this controller's objects with a CPU-time clock
    (``time.thread_time``); returns the dict the totals (s) accumulate in. ``start_at`` includes one rollout,
    counted there and not under the rollout's line."""
    import time

    ws = mpc._ws
    if ws is None:
        return {}
    owners = {"ws": ws, "sw": ws.sw, "problem": ws.problem, "al": ws.al}
    total: dict[str, float] = {}
    depth = [0]

    def wrap(name: str, fn):
        total[name] = 0.0

        def timed(*a, **kw):
            if depth[0]:
                return fn(*a, **kw)
            depth[0] += 1
            c0 = time.thread_time()
            try:
                return fn(*a, **kw)
            finally:
                total[name] += time.thread_time() - c0
                depth[0] -= 1
        return timed

    for name, (owner, attr) in PHASES.items():
        obj = owners[owner]
        if obj is not None:
            setattr(obj, attr, wrap(name, getattr(obj, attr)))
    return total


PUSH = "hand:30:0.9:0.1"   # arm5's reach: 30 N on the hand along world x from 0.9 s for 0.1 s
PUSH_HORIZON = 100


def pushed_arm5(cache) -> dict:
    """arm5's reach (R-AICO, 30 iterations) executed in Drake pushed on the hand: the plan's controller and
    MPC (R-AICO, horizon 100, one iteration per 2 ms period); the final target's error (m) of each and the
    arrays the figure draws."""
    from raico.pipeline.engine.runner import run
    from raico.stages.execute.config import ExecuteConfig
    from raico.stages.plan.stage import PlanConfig

    plan = run(cache, "plan", PlanConfig(plant="arm5", task="reach", solver="raico", iterations=30), record=False)
    out: dict = {"plan": plan.path}
    configs = {"plan's controller": ExecuteConfig(plan=plan.key, push=(PUSH,)),
               "MPC R-AICO": ExecuteConfig(plan=plan.key, push=(PUSH,), controller="mpc", horizon=PUSH_HORIZON,
                                           solver="raico")}
    for name, cfg in configs.items():
        ex = run(cache, "execute", cfg, record=False)
        out[name] = {"path": ex.path, "status": ex.status,
                     "final_error_m": ex.metrics["via_point_errors"]["via_x2@1000"],
                     "first_via_error_m": ex.metrics["via_point_errors"]["via_x1@500"],
                     "median_tick_s": ex.metrics.get("mpc_median_tick_s")}
    return out


DRAKE_SOLVERS = (("R-AICO (alpha 1, relinearized in the sweep, theta 0.1)", "raico"), ("FDDP / BoxFDDP", "fddp"))


def xarm7_in_drake(cache) -> dict:
    """The xArm7's reach planned (R-AICO) and executed in Drake under MPC (horizon 50, one iteration per 10 ms
    period) with R-AICO and with FDDP: the loop's real-time factor (simulated time over the loop's wall time:
    Drake's steps, the ticks, the logs), the ticks' median and p99, the reach's final error (m), the status."""
    from raico.pipeline.engine.runner import run
    from raico.stages.execute.config import ExecuteConfig
    from raico.stages.plan.stage import PlanConfig

    plan = run(cache, "plan", PlanConfig(problem=str(ROOT / PROBLEMS["xArm7 reach"]), solver="raico",
                                         iterations=50), record=False)
    out: dict = {}
    for label, solver in DRAKE_SOLVERS:
        ex = run(cache, "execute", ExecuteConfig(plan=plan.key, controller="mpc", horizon=HORIZON, solver=solver),
                 record=False)
        m = ex.metrics
        errors = m.get("via_point_errors") or {}
        out[label] = {"status": ex.status, "rtf": m.get("mpc_real_time_factor"),
                      "median_tick_s": m.get("mpc_median_tick_s"), "p99_tick_s": m.get("mpc_p99_tick_s"),
                      "final_error_m": max(errors.values()) if errors else None}
    return out


TRACK = "raico/problems/examples/xarm7_track.toml"
TRACK_RUNS = (("plan's controller", {}),
              ("MPC R-AICO", {"controller": "mpc", "horizon": HORIZON, "solver": "raico"}),
              ("MPC FDDP", {"controller": "mpc", "horizon": HORIZON, "solver": "fddp"}))


def _track_errors(metrics: dict) -> np.ndarray:
    """The moving target's per-step errors (m) of an execution's metrics (its terms ``track_t<step>``)."""
    e = metrics.get("via_point_errors") or {}
    return np.array([v for k, v in sorted(e.items(), key=lambda kv: int(kv[0].split("_t")[-1].split("@")[0]))
                     if k.startswith("track_t")])


def xarm7_track(cache) -> dict:
    """The xArm7 tracking a moving target with a payload its model does not know (``TRACK``), planned by
    R-AICO (50 iterations) and executed in Drake by the plan's own controller and under MPC (R-AICO, FDDP;
    horizon 50, one iteration per 10 ms period): per run the tracking error's mean, max and final (m), the
    status, the ticks' median and p99, the loop's real-time factor, its artifact's path."""
    from raico.pipeline.engine.runner import run
    from raico.planning.costs import via_point_errors
    from raico.planning.objective import objective_from_description
    from raico.stages.execute.config import ExecuteConfig
    from raico.stages.plan.stage import PlanConfig

    plan = run(cache, "plan", PlanConfig(problem=str(ROOT / TRACK), solver="raico", iterations=50), record=False)
    out: dict = {"plan": plan.path, "plan_key": plan.key}
    desc = json.loads((Path(plan.path) / "problem.json").read_text())
    planned = None
    for label, kw in TRACK_RUNS:
        ex = run(cache, "execute", ExecuteConfig(plan=plan.key, **kw), record=False)
        m, e = ex.metrics, _track_errors(ex.metrics)
        out[label] = {"path": ex.path, "status": ex.status, "mean_error_m": float(e.mean()),
                      "max_error_m": float(e.max()), "final_error_m": float(e[-1]),
                      "median_tick_s": m.get("mpc_median_tick_s"), "p99_tick_s": m.get("mpc_p99_tick_s"),
                      "rtf": m.get("mpc_real_time_factor")}
        if planned is None:
            planned = np.load(Path(ex.path) / "rollout.npz")["X_plan"]
    e = _track_errors({"via_point_errors": via_point_errors(objective_from_description(desc), planned)})
    out["planned"] = {"mean_error_m": float(e.mean()), "max_error_m": float(e.max()), "final_error_m": float(e[-1])}
    return out


def horizon_figure(track: dict, path: Path) -> None:
    """From the tracking runs' records (``rollout.npz``: the executed states, every tick's predicted window,
    its solve time): the end effector's path in the circle's plane with MPC R-AICO's predicted windows as a
    fading path (every 4th tick, the older paler), the executed paths of the three controllers and the
    target; beside it each tick's solve time against the period, R-AICO's and FDDP's."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from raico.pipeline.recordings.tasks import task_plots
    from raico.planning.objective import objective_from_description

    objective = objective_from_description(json.loads((Path(track["plan"]) / "problem.json").read_text()))

    def ee(X: np.ndarray):
        return next(p for p in task_plots(objective, np.asarray(X, float)) if p.raw.shape[1] == 3 and p.targets)

    rolls = {label: np.load(Path(track[label]["path"]) / "rollout.npz") for label, _ in TRACK_RUNS}
    mpc = rolls["MPC R-AICO"]
    a, b = 1, 2    # the circle's plane (world y, z)
    fig, (ax, at) = plt.subplots(1, 2, figsize=(12, 6.4), gridspec_kw={"width_ratios": [1, 1.25]})
    pred = mpc["mpc_predicted"]
    every = 4
    drawn = range(0, len(pred), every)
    for i in drawn:
        P = ee(pred[i]).raw
        f = i / max(len(pred) - 1, 1)
        ax.plot(P[:, a], P[:, b], color=plt.cm.viridis(f), alpha=0.15 + 0.35 * f, lw=0.8)
    ax.plot([], [], color=plt.cm.viridis(0.6), lw=0.8,
            label=f"MPC R-AICO's predicted windows (every {every} ticks; colour: tick)")
    tp = ee(mpc["X_plan"])
    T = np.array([t for _, t in tp.targets])
    ax.plot(T[:, a], T[:, b], "k:", lw=1.2, label="moving target")
    for label, style in (("plan's controller", dict(color="tab:red")), ("MPC R-AICO", dict(color="tab:green")),
                         ("MPC FDDP", dict(color="tab:blue", ls="--"))):
        P = ee(rolls[label]["X"]).raw
        ax.plot(P[:, a], P[:, b], lw=1.5, label=f"{label}: mean error {track[label]['mean_error_m'] * 100:.2f} cm",
                **style)
    lo, hi = T[:, [a, b]].min(axis=0) - 0.03, T[:, [a, b]].max(axis=0) + 0.03
    ax.set(aspect="equal", xlabel="end effector y (m)", ylabel="end effector z (m)", xlim=(lo[0], hi[0]),
           ylim=(lo[1], hi[1]), title="xArm7 tracking a moving target (5 cm circle, 1 turn/s),\n"
                                      "0.5 kg payload its model does not know, in Drake")
    ax.legend(fontsize=7.5, loc="upper left", bbox_to_anchor=(0.0, -0.12))
    for label, color in (("MPC R-AICO", "tab:green"), ("MPC FDDP", "tab:blue")):
        r = rolls[label]
        solve = r["mpc_solve_time"] * 1e3
        period = float(r["times"][-1]) / len(solve)
        at.plot(np.arange(len(solve)) * period, solve, color=color, lw=0.9,
                label=f"{label} (median {np.median(solve):.1f} ms)")
    at.axhline(period * 1e3, color="k", ls="--", lw=1, label=f"period ({period * 1e3:.0f} ms)")
    at.set(xlabel="time (s)", ylabel="solve time per tick (ms)", yscale="log", yticks=[1, 2, 5, 10, 20, 50, 100, 200],
           yticklabels=["1", "2", "5", "10", "20", "50", "100", "200"],
           title="solve time per tick against the period (wall time, a shared machine)")
    at.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    at.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def recorded_entities(cache, track: dict) -> dict[str, int]:
    """The MPC R-AICO tracking run recorded (its Rerun recording derived from the stored run): the chunks per
    entity of the predicted windows (``world/predicted/...``) and of the solve times (``mpc/tick``)."""
    import collections

    from rerun.chunk import RrdReader

    from raico.pipeline.engine.runner import run
    from raico.stages.execute.config import ExecuteConfig

    ex = run(cache, "execute", ExecuteConfig(plan=track["plan_key"], **dict(TRACK_RUNS)["MPC R-AICO"]), record=True)
    chunks = collections.Counter(str(c.entity_path) for c in RrdReader(str(ex.recording)).stream())
    return {e: n for e, n in sorted(chunks.items()) if e.startswith(("/world/predicted", "/mpc"))}


def figure(pushed: dict, path: Path) -> None:
    """The hand's path (in the plane it moves in most) of the pushed arm5: planned, under the plan's controller, under MPC, and
    MPC's predicted windows every 50 ticks (pale: early, dark: late); the via-points as crosses."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from raico.pipeline.recordings.tasks import task_plots
    from raico.planning.objective import objective_from_description

    desc = json.loads((Path(pushed["plan"]) / "problem.json").read_text())
    objective = objective_from_description(desc)

    def hand(X: np.ndarray) -> np.ndarray:
        tp = next(p for p in task_plots(objective, np.asarray(X, float)) if p.entity == "ee")
        return tp.raw

    pd_roll = np.load(Path(pushed["plan's controller"]["path"]) / "rollout.npz")
    mpc_roll = np.load(Path(pushed["MPC R-AICO"]["path"]) / "rollout.npz")
    fig, ax = plt.subplots(figsize=(7, 5.5))
    spread = np.ptp(np.vstack([hand(pd_roll["X_plan"]), hand(mpc_roll["X"]), hand(pd_roll["X"])]), axis=0)
    a, b = sorted(np.argsort(spread)[-2:])   # the plane the hand moves in most
    pred = mpc_roll["mpc_predicted"]
    every = 50
    for i in range(0, len(pred), every):
        P = hand(pred[i])
        ax.plot(P[:, a], P[:, b], color=plt.cm.Blues(0.25 + 0.75 * i / len(pred)), lw=0.8)
    ax.plot([], [], color=plt.cm.Blues(0.8), lw=0.8, label=f"MPC's predicted windows (every {every} ticks)")
    for X, style, label in ((pd_roll["X_plan"], dict(color="0.6", ls="--"), "planned"),
                            (pd_roll["X"], dict(color="tab:red"), "plan's controller, pushed"),
                            (mpc_roll["X"], dict(color="tab:green"), "MPC (R-AICO), pushed")):
        P = hand(X)
        ax.plot(P[:, a], P[:, b], lw=1.6, label=label, **style)
    tp = next(p for p in task_plots(objective, np.asarray(pd_roll["X_plan"], float)) if p.entity == "ee")
    for _, target in tp.targets:
        ax.plot(target[a], target[b], "kx", ms=9, mew=2)
    e_pd, e_mpc = (pushed[k]["final_error_m"] * 100 for k in ("plan's controller", "MPC R-AICO"))
    v_pd, v_mpc = (pushed[k]["first_via_error_m"] * 100 for k in ("plan's controller", "MPC R-AICO"))
    ax.set(aspect="equal", xlabel=f"hand {'xyz'[a]} (m)", ylabel=f"hand {'xyz'[b]} (m)",
           title=f"arm5's reach pushed ({PUSH}); plan's controller / MPC (horizon {PUSH_HORIZON} steps):\n"
                 f"final target off by {e_pd:.1f} / {e_mpc:.1f} cm, first via-point by {v_pd:.1f} / {v_mpc:.1f} cm")
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def markdown(rows: list[dict], load: tuple[float, float], pushed: dict | None = None, drake: dict | None = None,
             track: dict | None = None, ends: dict | None = None) -> str:
    lines = [f"7-DOF arms, horizon {HORIZON} at dt = 10 ms, one iteration per tick, the loop closed on the planning "
             f"model; target: median <= {TARGET_MEDIAN_S * 1e3:g} ms, p99 <= {TARGET_P99_S * 1e3:g} ms. Machine: "
             f"{os.cpu_count()} cores, 1-minute load average {load[0]:.2f} at the start, {load[1]:.2f} at the end "
             "(shared: wall times include the waits for a core; CPU time is the tick's own thread's).", "",
             "| problem | solver | ticks | median tick (ms) | p99 tick (ms) | CPU median (ms) | CPU p99 (ms) | "
             "median / FDDP's | loop stayed finite | meets the target (wall) |", "|---|---|---|---|---|---|---|---|---|---|"]
    fddp = {r["problem"]: r for r in rows if r["solver"].startswith("FDDP")}
    for r in rows:
        ok = r["finite"] and r["median_s"] <= TARGET_MEDIAN_S and r["p99_s"] <= TARGET_P99_S
        f = fddp.get(r["problem"])
        ratio = "-" if f is None or r is f else f"{r['median_s'] / f['median_s']:.2f}"
        lines.append(f"| {r['problem']} | {r['solver']} | {r['ticks']} | {r['median_s'] * 1e3:.3f} | "
                     f"{r['p99_s'] * 1e3:.3f} | {r['cpu_median_s'] * 1e3:.3f} | {r['cpu_p99_s'] * 1e3:.3f} | {ratio} | "
                     f"{'yes' if r['finite'] else 'no'} | {'yes' if ok else 'no'} |")
    for r in rows:
        if "phases_s" not in r:
            continue
        lines += ["", f"Where R-AICO's tick goes ({r['problem']}, {r['solver']}; CPU time per tick, mean):", "",
                  "| part | ms | share |", "|---|---|---|"]
        tot = sum(r["phases_s"].values())
        for name, v in r["phases_s"].items():
            lines.append(f"| {name} | {v * 1e3:.3f} | {100 * v / tot:.0f}% |")
    if ends is not None:
        lines += ["", "Why FDDP's loop leaves the finite states on the xArm7's reach: the first window (50 iterations "
                  "from the start held), FDDP's and R-AICO's; the largest joint velocity 10 steps before the window's "
                  "end and at its end, and the largest along the same controls stepped at 1 ms on the same model:", "",
                  "| problem | solver | window cost | max joint velocity 10 steps before the end (rad/s) | "
                  "at the end (rad/s) | same controls at 1 ms: max (rad/s) | max torque (N m) |",
                  "|---|---|---|---|---|---|---|"]
        for problem, per in ends.items():
            for label, r in per.items():
                lines.append(f"| {problem} | {label} | {r['cost']:.3g} | {r['v_before']:.2f} | {r['v_end']:.1f} | "
                             f"{r['v_fine_max']:.2f} | {r['u_max']:.2f} |")
    if drake is not None:
        lines += ["", "The xArm7's reach in Drake under MPC (horizon 50, one iteration per 10 ms period, the plan "
                  "R-AICO's); real-time factor: simulated time over the loop's wall time (>= 1: faster than real time):",
                  "", "| solver | real-time factor | median tick (ms) | p99 tick (ms) | final error (cm) | status |",
                  "|---|---|---|---|---|---|"]
        for name, r in drake.items():
            err = "-" if r["final_error_m"] is None else f"{r['final_error_m'] * 100:.2f}"
            lines.append(f"| {name} | {r['rtf']:.2f} | {r['median_tick_s'] * 1e3:.2f} | {r['p99_tick_s'] * 1e3:.2f} | "
                         f"{err} | {r['status']} |")
    if track is not None:
        lines += ["", "The xArm7 tracking a moving target (`raico/problems/examples/xarm7_track.toml`: a 5 cm circle, "
                  "one turn a second for 2 s, a 0.5 kg payload the model does not know), planned by R-AICO (50 "
                  "iterations) and executed in Drake; MPC: horizon 50, one iteration per 10 ms period. Tracking error: "
                  "the end effector's distance to the target at each step from 0.1 s to 1.99 s:", "",
                  "| controller | mean tracking error (cm) | max (cm) | at the end (cm) | status | median tick (ms) | "
                  "p99 tick (ms) | real-time factor |", "|---|---|---|---|---|---|---|---|"]
        p = track["planned"]
        lines.append(f"| the plan on its own model (no payload) | {p['mean_error_m'] * 100:.2f} | {p['max_error_m'] * 100:.2f} | "
                     f"{p['final_error_m'] * 100:.2f} | - | - | - | - |")
        for label, _ in TRACK_RUNS:
            r = track[label]

            def ms(v):
                return "-" if v is None else f"{v * 1e3:.2f}"
            rtf = "-" if r["rtf"] is None else f"{r['rtf']:.2f}"
            lines.append(f"| {label} | {r['mean_error_m'] * 100:.2f} | {r['max_error_m'] * 100:.2f} | "
                         f"{r['final_error_m'] * 100:.2f} | {r['status']} | {ms(r['median_tick_s'])} | "
                         f"{ms(r['p99_tick_s'])} | {rtf} |")
        lines += ["", "![predicted horizons of the tracking xArm7](mpc_predicted_horizons.png)"]
        if track.get("recorded"):
            ents = ", ".join(f"`{e}` ({n})" for e, n in track["recorded"].items())
            lines += ["", f"Its Rerun recording (MPC R-AICO) holds the entities (chunks): {ents}."]
    if pushed is not None:
        lines += ["", f"Pushed in Drake: arm5's reach (R-AICO, 30 iterations), `--push {PUSH}`; the final via-point's "
                  "error, the first one's (1 s, the push ends at it) and the execution's status:", "",
                  "| controller | final target error (cm) | first via-point error (cm) | status | median tick (ms) |",
                  "|---|---|---|---|---|"]
        for name in ("plan's controller", "MPC R-AICO"):
            r = pushed[name]
            tick = "-" if r["median_tick_s"] is None else f"{r['median_tick_s'] * 1e3:.2f}"
            lines.append(f"| {name} | {r['final_error_m'] * 100:.2f} | {r['first_via_error_m'] * 100:.2f} | "
                         f"{r['status']} | {tick} |")
        lines += ["", "![the pushed arm5](mpc_pushed_arm5.png)"]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--artifacts", default="artifacts")
    ap.add_argument("--ticks", type=int, default=100)
    ap.add_argument("--split-only", action="store_true", help="only the split's latency table (mpc_split.md)")
    args = ap.parse_args(argv)
    from raico.pipeline.engine.cache import Cache

    out = Path(args.artifacts) / "bench"
    out.mkdir(parents=True, exist_ok=True)
    split_page = write_split(out, args.ticks)
    if args.split_only:
        sys.stdout.write(split_page)
        return 0
    rows, start = [], os.getloadavg()[0]
    ends = {}
    for name, path in PROBLEMS.items():
        problem = _problem(path)
        if name in ("xArm7 reach", "xArm7 tracking a moving target"):
            ends[name] = window_end(problem)
        for i, (label, solver, opts) in enumerate(SOLVERS):
            rows.append({"problem": name, "solver": label, **run_one(problem, solver, opts, args.ticks)})
            if i == 0:     # a second run with the parts clocked (the clocks' own calls kept out of the rows' times)
                rows[-1]["phases_s"] = run_one(problem, solver, opts, args.ticks, phases=True)["phases_s"]
    drake = xarm7_in_drake(Cache(out / "mpc"))
    track = xarm7_track(Cache(out / "mpc"))
    horizon_figure(track, out / "mpc_predicted_horizons.png")
    track["recorded"] = recorded_entities(Cache(out / "mpc"), track)
    pushed = pushed_arm5(Cache(out / "mpc"))
    figure(pushed, out / "mpc_pushed_arm5.png")
    (out / "mpc.json").write_text(json.dumps({"rows": rows, "drake": drake, "track": track, "pushed": pushed,
                                              "window_end": ends}, indent=2, allow_nan=True))
    page = markdown(rows, (start, os.getloadavg()[0]), pushed, drake, track, ends)
    (out / "mpc.md").write_text(page)
    sys.stdout.write(page)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
