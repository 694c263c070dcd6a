"""The learned model in the loop: the UR5 with an unmodelled 5 kg payload, pushed, under MPC on a learned residual.

``experiments/ur5_payload_push_mpc_learn.toml`` (its problem ``raico/problems/examples/ur5_payload_5kg.toml``, the
push ``tool0:20:0.5:0.1``). Rows: the model file's plan executed on the true robot, pushed, under the plan's own
controller and under MPC on the model file (R-AICO; crocoddyl's FDDP where installed), one run each (no seed
enters them); then per point of the experiment file the residual-GP loop over ``--seeds`` seeds: its episodes'
executions under MPC on the episode's learned model (model file + residual GP + uncertainty term), or under the
plan's controller. Per episode: the executed distance to the reach target, the status, the training points fed,
the MPC's median tick. Aimed at (stated before the first run): the learned MPC within 1 cm after at most 2
episodes, the model file's plan more than 3 cm off, the model-file MPC farther off than the learned one. One run
in a cache of its own; the page is ``artifacts/bench/mpc_learn.md`` (+ ``.json``, ``.png``). ``--experiment``: another
experiment file of the scenario (its page ``mpc_learn<suffix>.md``, the suffix its name's after the first's, e.g.
``experiments/ur5_payload_push_mpc_learn_grav.toml``, the effort toward gravity: ``mpc_learn_grav.md``).

    python -m bench.mpc_learn [--experiment FILE] [--seeds 10] [--jobs 1] [--render]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FIRST = ROOT / "experiments" / "ur5_payload_push_mpc_learn.toml"
EXPERIMENT = FIRST   # the scenario's experiment file (``--experiment``)
REACH = 0.01         # m: the goal
EPISODES_TARGET = 2  # within REACH after at most this many episodes
OPEN_LOOP_MISS = 0.03  # m: the model file's plan should miss by more than this
REACH_TERM = "reach@100"   # the problem's final position term (m)
HORIZON = 50         # the model-file MPC's horizon, as the experiment file's
OPTIMUM_ITERATIONS = (50, 100, 150, 200)  # the cold plans of the problem on the true robot (its own optimum's row)


def variants() -> tuple[dict, list[dict]]:
    """The experiment file's ``[base]`` and its points (:func:`bench.learning_common.experiment_points`)."""
    from bench.learning_common import experiment_points

    return experiment_points(EXPERIMENT)


def page_name(experiment: Path) -> str:
    """The page's name (no extension) of ``experiment``: ``mpc_learn`` for the first file, ``mpc_learn`` plus the
    part of another's name after the first's (``..._grav.toml``: ``mpc_learn_grav``)."""
    stem = Path(experiment).stem
    return "mpc_learn" + (stem.removeprefix(FIRST.stem) if stem.startswith(FIRST.stem) else f"_{stem}")


def effort_target() -> str:
    """What the problem file's ``[costs.effort]`` costs the torque against: ``zero`` or ``gravity`` (the model file's)."""
    import tomllib

    base, _ = variants()
    t = tomllib.loads(Path(base["problem"]).read_text()).get("costs", {}).get("effort", {}).get("target")
    return "gravity" if t == "gravity" else "zero"


def final_target() -> str:
    """The experiment file's MPC point's ``final_target`` (``receding`` or ``fixed``; the execute default if
    not given)."""
    from raico.stages.execute.config import ARM_FINAL_TARGET

    _, points = variants()
    return next((p.get("final_target") or ARM_FINAL_TARGET for p in points if p.get("controller") == "mpc"),
                ARM_FINAL_TARGET)


def one_step_error(X: np.ndarray, predicted: np.ndarray | None) -> float | None:
    """The controller's model against the robot along the executed path: per tick, the largest error of the
    window's predicted next joint velocities (rad/s) against the executed ones; their median (None: no MPC)."""
    if predicted is None or len(predicted) == 0:
        return None
    n = X.shape[1] // 2
    k = min(len(predicted), len(X) - 1)
    return float(np.nanmedian(np.abs(predicted[:k, 1, n:] - X[1:k + 1, n:]).max(axis=1)))


def model_file_rows(artifacts: str) -> list[dict]:
    """The model file's plan (the planner's defaults for a problem file) executed pushed on the true robot: the
    plan's controller, MPC R-AICO and MPC FDDP (a row saying why where it cannot run)."""
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.runner import run
    from raico.stages.execute.config import ExecuteConfig
    from raico.stages.plan.stage import PlanConfig

    base, _ = variants()
    cache = Cache(Path(artifacts) / "bench" / "mpc_learn")
    plan = run(cache, "plan", PlanConfig(problem=base["problem"]), record=False)
    push = tuple(base["push"])
    end = final_target()
    rows = []
    mpc = {"controller": "mpc", "horizon": HORIZON, "final_target": end}
    for label, over in (("plan's controller", {}),
                        ("MPC R-AICO, horizon 50", {**mpc, "solver": "raico"}),
                        ("MPC FDDP, horizon 50", {**mpc, "solver": "fddp"})):
        try:
            ex = run(cache, "execute", ExecuteConfig(plan=plan.key, push=push, **over), record=False)
        except Exception as e:   # crocoddyl not installed, or its loop failing: say so in the row
            rows.append({"label": label, "error": f"{type(e).__name__}: {e}"})
            continue
        m = ex.metrics
        with np.load(Path(ex.path) / "rollout.npz") as f:
            err = one_step_error(f["X"], f["mpc_predicted"] if "mpc_predicted" in f.files else None)
        rows.append({"label": label, "distance_m": m["via_point_errors"][REACH_TERM], "status": ex.status,
                     "planned_m": plan.metrics["via_point_errors"][REACH_TERM],
                     "tick_s": m.get("mpc_median_tick_s"), "one_step_error": err})
    other = "fixed" if end == "receding" else "receding"
    rows += [oracle_row(cache, plan.key, push, h, t) for h, t in ((HORIZON, end), (HORIZON, other), (100, end))]
    return rows


def true_dynamics(problem, pf) -> None:
    """Give ``problem`` the true robot's own dynamics (the problem file's ``[robot.true]``, its substeps)."""
    from raico.plants.dynamics_registry import make_dynamics
    from raico.plants.model_file import shared_model
    from raico.stages.plan.stage import actuated

    true = shared_model(pf.true_spec())
    problem.dynamics = actuated(make_dynamics("analytic", true, pf.dt / pf.substeps), true, pf.substeps)


def optimum_rows(artifacts: str) -> list[dict]:
    """The problem's own optimum on the true robot: cold R-AICO plans of the problem on the true dynamics
    (``OPTIMUM_ITERATIONS``), their planned distance to the target and the cost's terms. Where the lower cost
    lies farther from the target, a controller minimizing the problem's cost on a perfect model misses so."""
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.runner import run
    from raico.planning.problem_file import read_problem
    from raico.planning.solvers import solve
    from raico.stages.execute.stage import planning_problem
    from raico.stages.plan.stage import PlanConfig

    base, _ = variants()
    cache = Cache(Path(artifacts) / "bench" / "mpc_learn")
    plan = run(cache, "plan", PlanConfig(problem=base["problem"]), record=False)
    pf = read_problem(base["problem"])
    rows = []
    for its in OPTIMUM_ITERATIONS:
        problem = planning_problem(cache.require("plan", plan.key))
        true_dynamics(problem, pf)
        r = solve(problem, "raico", {"iterations": its})
        reach = problem.term(REACH_TERM.split("@")[0])
        d = float(np.linalg.norm(reach._errors(r.X[-1:])[0]))
        rows.append({"iterations": its, "status": r.status, "distance_m": d,
                     "cost": {k: float(v) for k, v in problem.cost_terms(r.X, r.U).items()}})
    return rows


def oracle_row(cache, plan_key: str, push: tuple, horizon: int, end: str) -> dict:
    """MPC R-AICO whose model is the true robot's own dynamics (the payload known: what a perfect learner would
    give the controller), from the model file's plan, pushed alike: how close the controller itself gets. Run in
    this process, not stored (its model is no stage's option)."""
    from raico.planning.problem_file import read_problem
    from raico.stages.execute.config import ExecuteConfig
    from raico.stages.execute.stage import execute, planning_problem
    from raico.stages.plan.stage import PLAN_FILE, PROBLEM_FILE

    base, _ = variants()
    art = cache.require("plan", plan_key)
    problem = planning_problem(art)
    true_dynamics(problem, read_problem(base["problem"]))
    cfg = ExecuteConfig(plan=plan_key, push=push, controller="mpc", horizon=horizon, solver="raico", final_target=end)
    out = execute(cfg, art.document(PROBLEM_FILE), art.arrays(PLAN_FILE), plan_status=art.status, planning=problem)
    m = out.metrics
    return {"label": f"MPC R-AICO, horizon {horizon}, final target {end}", "model": "the true robot's dynamics (oracle)",
            "distance_m": m["via_point_errors"][REACH_TERM], "status": m["status"],
            "tick_s": m.get("mpc_median_tick_s"), "one_step_error": one_step_error(out.X, out.mpc.get("mpc_predicted"))}


def run_seed(job: tuple[str, int, dict, str]) -> dict:
    """One seed's loop of one point: per-episode numbers (``raico.stages.learn``'s episodes.json)."""
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.runner import run
    from raico.stages.learn import LearnConfig

    global EXPERIMENT
    artifacts, seed, point, experiment = job
    EXPERIMENT = Path(experiment)   # the worker's own module (a spawned process starts from the default)
    base, _ = variants()
    over = {k: v for k, v in point.items() if k != "label"}
    cfg = {**base, **over, "seed": seed}
    cfg["push"] = tuple(cfg["push"])
    cache = Cache(Path(artifacts) / "bench" / "mpc_learn")
    t0 = time.perf_counter()
    out = run(cache, "learn", LearnConfig(**cfg), record=False)
    eps = json.loads((Path(out.path) / "episodes.json").read_text())["episodes"]
    arts = [cache.require("execute", e["execute"]) for e in eps]
    ex = [a.metrics for a in arts]
    rolls = [a.arrays("rollout.npz") for a in arts]
    return {"label": point["label"], "seed": seed, "wall_s": time.perf_counter() - t0,
            "distance_m": [m["via_point_errors"][REACH_TERM] for m in ex],
            "status": [e["execution_status"] for e in eps], "data_steps": [e["data_steps"] for e in eps],
            "n_points": [e["n_points"] for e in eps], "gp_error": [e["gp_error"] for e in eps],
            "tick_s": [m.get("mpc_median_tick_s") for m in ex],
            "one_step_error": [one_step_error(r["X"], r.get("mpc_predicted")) for r in rolls],
            "fit_s": [e["fit_time_s"] for e in eps], "plan_s": [e["plan_time_s"] for e in eps],
            "execute_s": [e["execute_time_s"] for e in eps]}


def first_within(r: dict) -> int | None:
    """The first episode whose execution ended within ``REACH`` (None: none)."""
    return next((k + 1 for k, d in enumerate(r["distance_m"]) if d <= REACH), None)


def page(doc: dict) -> str:
    """The markdown block: the model file's rows, one row per loop, the per-seed distances."""
    base_rows, runs = doc["model_file"], doc["runs"]
    problem = doc.get("problem", "raico/problems/examples/ur5_payload_5kg.toml")
    lines = [f"UR5 carrying an unmodelled 5 kg at the tool (`{problem}`, the effort term toward "
             f"{'the model file' + chr(39) + 's gravity torque, u - g(q)' if doc.get('effort') == 'gravity' else 'zero torque'}), pushed "
             f"(`{' '.join(doc['push'])}`: 20 N on the tool for 0.1 s mid-reach); the loop of "
             f"`{doc.get('experiment', 'experiments/ur5_payload_push_mpc_learn.toml')}` ({doc['settings']}); MPC: horizon {HORIZON} steps, "
             f"one R-AICO iteration per 10 ms period, the final target {doc.get('final_target', 'receding')} "
             "(`--final-target`); "
             f"{doc['seeds']} seeds; load average {doc['load']} (2 cores "
             "shared: times under load; the times of steps found in the cache are those of their own runs). Aimed at before the run: the learned MPC within 1 cm after at most "
             f"{EPISODES_TARGET} episodes, the model file's plan more than {100 * OPEN_LOOP_MISS:g} cm off, the "
             "model-file MPC farther off than the learned one.", "",
             "| controller | model | executed distance to the target (cm) | status | median tick (ms) | model's "
             "one-step error, median (rad/s) |",
             "|---|---|---|---|---|---|"]
    for r in base_rows:
        if "error" in r:
            lines.append(f"| {r['label']} | model file | not run: {r['error'].splitlines()[0]} | - | - | - |")
            continue
        tick = f"{1e3 * r['tick_s']:.1f}" if r.get("tick_s") else "-"
        err = f"{r['one_step_error']:.3g}" if r.get("one_step_error") is not None else "-"
        lines.append(f"| {r['label']} | {r.get('model', 'model file')} | {100 * r['distance_m']:.2f} | {r['status']} | "
                     f"{tick} | {err} |")
    lines.append("| MPC FDDP, learned model | - | not run: crocoddyl's window is the model file's in Pinocchio; "
                 "the GP residual has no action model there | - | - | - |")
    if doc.get("optimum"):
        lines += ["", "The problem's own optimum on the true robot (cold R-AICO plans on the true dynamics, no push):",
                  "", "| R-AICO iterations | status | planned distance to the target (cm) | cost: reach | effort | "
                  "level | total |", "|---|---|---|---|---|---|---|"]
        for o in doc["optimum"]:
            c = o["cost"]
            lines.append(f"| {o['iterations']} | {o['status']} | {100 * o['distance_m']:.2f} | {c.get('reach', 0):.1f} "
                         f"| {c.get('effort', 0):.1f} | {c.get('level', 0):.1f} | {sum(c.values()):.1f} |")
    lines += ["", "The residual-GP loop, per episode (medians over the seeds; cm):", "",
              f"| episodes' controller | seeds within 1 cm by episode {EPISODES_TARGET} | executed distance per "
              "episode, median (cm) | worst seed per episode (cm) | execution statuses | data steps fed per "
              "episode, median | MPC's model, one-step error per episode, median (rad/s) | MPC median tick (ms), "
              "median | fit + plan + execute per episode, median (s) |",
              "|---|---|---|---|---|---|---|---|---|"]
    for lab in dict.fromkeys(r["label"] for r in runs):
        rs = [r for r in runs if r["label"] == lab]
        D = 100 * np.array([r["distance_m"] for r in rs], float)
        hit = sum(f is not None and f <= EPISODES_TARGET for f in (first_within(r) for r in rs))
        from collections import Counter
        st = ", ".join(f"{k} {v}" for k, v in sorted(Counter(s for r in rs for s in r["status"]).items()))
        ticks = [t for r in rs for t in r["tick_s"] if t]
        tk = f"{1e3 * np.median(ticks):.0f}" if ticks else "-"
        per = [a + b + c for r in rs for a, b, c in zip(r["fit_s"], r["plan_s"], r["execute_s"])]
        errs = [r.get("one_step_error") for r in rs]
        one = ("-" if not errs or errs[0] is None or errs[0][0] is None else
               " / ".join(f"{v:.3g}" for v in np.median(np.array(errs, float), 0)))
        lines.append(f"| {lab} | {hit} of {len(rs)} | {' / '.join(f'{v:.2f}' for v in np.median(D, 0))} | "
                     f"{' / '.join(f'{v:.2f}' for v in D.max(0))} | {st} | "
                     f"{' / '.join(f'{v:g}' for v in np.median([r['data_steps'] for r in rs], 0))} | {one} | {tk} | "
                     f"{np.median(per):.1f} |")
    lines += ["", "Per seed: executed distance per episode (cm) and statuses.", "",
              "| episodes' controller | seed | distance (cm) | statuses |", "|---|---|---|---|"]
    for r in runs:
        lines.append(f"| {r['label']} | {r['seed']} | {' '.join(f'{100 * d:.2f}' for d in r['distance_m'])} | "
                     f"{' '.join(r['status'])} |")
    return "\n".join(lines) + "\n"


def plot(doc: dict, path: Path) -> None:
    """Executed distance per episode (cm, log): each seed thin, the median thick, per loop; the model file's rows
    and the 1 cm goal as horizontal lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FormatStrFormatter, FuncFormatter, MaxNLocator

    runs = doc["runs"]
    fig, ax = plt.subplots(figsize=(11, 4.6))
    for i, lab in enumerate(dict.fromkeys(r["label"] for r in runs)):
        rs = [r for r in runs if r["label"] == lab]
        D = 100 * np.array([r["distance_m"] for r in rs], float)
        k = np.arange(1, D.shape[1] + 1)
        for d in D:
            ax.plot(k, d, "-", color=f"C{i}", lw=0.6, alpha=0.4)
        ax.plot(k, np.median(D, 0), "o-", color=f"C{i}", lw=2, label=f"learned residual, {lab} (median, {len(rs)} seeds)")
    for j, r in enumerate(r for r in doc["model_file"] if "error" not in r):
        ax.axhline(100 * r["distance_m"], color=f"C{j + 3}", ls=":", lw=1.4,
                   label=f"{r.get('model', 'model file')}, {r['label']} ({100 * r['distance_m']:.1f} cm)")
    ax.axhline(100 * REACH, color="g", ls="--", lw=1, label="1 cm")
    ax.set(yscale="log", xlabel="episode", ylabel="executed distance to the target (cm)",
           title=f"UR5, unmodelled 5 kg, pushed 20 N mid-reach; effort toward {doc.get('effort', 'zero')}")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
    ax.yaxis.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:g}" if f"{v:g}".lstrip("0.")[:1] in "25" else ""))
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def learned_tick(artifacts: str) -> None:
    """The learned model's tick, compiled against the Python path, on this run's loop (``bench.learned_tick``:
    its page ``artifacts/bench/learned_tick.md``)."""
    from bench import learned_tick as lt

    doc = lt.measure(artifacts)
    out = Path(artifacts) / "bench"
    (out / "learned_tick.json").write_text(json.dumps(doc, indent=1))
    (out / "learned_tick.md").write_text(lt.page(doc))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--experiment", default=str(FIRST), help="the scenario's experiment file")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--jobs", type=int, default=1, help="loops run at once (processes)")
    ap.add_argument("--artifacts", default=str(ROOT / "artifacts"))
    ap.add_argument("--render", action="store_true", help="only write the page and plot again from mpc_learn.json")
    args = ap.parse_args()
    global EXPERIMENT
    EXPERIMENT = Path(args.experiment).resolve()
    name = page_name(EXPERIMENT)
    out = Path(args.artifacts) / "bench"
    out.mkdir(parents=True, exist_ok=True)
    if not args.render:
        base, points = variants()
        load0 = os.getloadavg()[0]
        rows = model_file_rows(args.artifacts)
        optimum = optimum_rows(args.artifacts)
        jobs = [(args.artifacts, s, p, str(EXPERIMENT)) for s in range(args.seeds) for p in points]
        settings = {k: v for k, v in base.items() if k not in ("problem", "push")}
        runs: list[dict] = []
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            for r in pool.map(run_seed, jobs):   # in order; the page so far written after each loop
                runs.append(r)
                load = f"{load0:.2f} at the start, {os.getloadavg()[0]:.2f} at the end"
                seeds = len({x["seed"] for x in runs})
                (out / f"{name}.json").write_text(json.dumps(
                    {"model_file": rows, "optimum": optimum, "final_target": final_target(), "runs": runs, "settings": settings, "push": base["push"], "seeds": seeds,
                     "load": load, "problem": os.path.relpath(base["problem"], ROOT),
                     "experiment": os.path.relpath(EXPERIMENT, ROOT), "effort": effort_target()}, indent=1))
        if EXPERIMENT == FIRST.resolve():   # the learned model's tick, on the first scenario's loop
            learned_tick(args.artifacts)
    doc = json.loads((out / f"{name}.json").read_text())
    (out / f"{name}.md").write_text(page(doc))
    plot(doc, out / f"{name}.png")
    print(page(doc))


if __name__ == "__main__":
    main()
