"""Each stage's files: data (.npz), recording.rrd, trajectory.mcap, run through the cache.

The stage functions in ``stages/`` compute; the functions here give them a cache key, write
their outputs into the cache's temporary folder and return the outcome.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.cache import Cache, Entry
from pipeline.errors import BadInput, MissingArtifact
from pipeline.runner import Outcome, run_stage, source_version
from pipeline.ui import Reporter

RECORDING = "recording.rrd"
MCAP = "trajectory.mcap"


def find_entry(cache: Cache, ref: str, stage: str | None = None) -> Entry:
    """A valid entry from ``STAGE/KEY`` or a bare ``KEY`` (searched in ``stage`` or everywhere)."""
    if "/" in ref:
        st, key = ref.split("/", 1)
        return cache.require(st, key)
    matches = [r for r in cache.list(stage) if r.key.startswith(ref)]
    valid = [r for r in matches if r.valid]
    if not valid:
        if matches:
            return cache.require(matches[0].stage, matches[0].key)  # raises with the reason
        where = f"stage '{stage}'" if stage else "any stage"
        raise MissingArtifact(f"no artifact with key '{ref}' in {where} under {cache.root}")
    if len({(r.stage, r.key) for r in valid}) > 1:
        raise BadInput(f"key prefix '{ref}' is ambiguous: give more characters or STAGE/KEY")
    return cache.require(valid[0].stage, valid[0].key)


def save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    with open(path, "wb") as f:
        np.savez_compressed(f, **arrays)


def run_babble(cache: Cache, cfg, record: bool = True, reporter: Reporter | None = None) -> Outcome:
    """Babble stage through the cache: ``data.npz`` (+ recording and MCAP of all episodes)."""
    from stages import babble

    reporter = reporter or Reporter(quiet=True)
    config = {**cfg.to_dict(), "record": record}

    def compute(tmp: Path) -> dict:
        with reporter.progress(f"babble {cfg.plant}", cfg.episodes) as update:
            data = babble.run(cfg, progress=update)
        save_npz(tmp / "data.npz", data.arrays())
        if record:
            write_babble_recording(tmp, cfg, data)
        return {"status": "ok", "metrics": data.metrics()}

    version = source_version(babble.CODE_VERSION, "plants", "stages.babble")
    return run_stage(cache, "babble", version, config, [], compute)


def _episode_times(t: np.ndarray, episodes: int, gap: float) -> np.ndarray:
    """Episodes laid end to end on one ``sim_time`` axis: ``(episodes * K,)`` s."""
    span = t[-1] + gap
    return (np.arange(episodes)[:, None] * span + t[None, :]).reshape(-1)


def write_babble_recording(folder: Path, cfg, data) -> None:
    from pipeline import recording as rec_mod
    from pipeline.mcap_io import write_trajectory_mcap
    from plants.robots import load_robot

    robot = load_robot(cfg.plant)
    E, K, n = data.q.shape
    times = _episode_times(data.t, E, gap=data.t[1] - data.t[0])
    Q = data.q.reshape(-1, n)
    with rec_mod.Recording(folder / RECORDING, properties={"stage": "babble", **cfg.to_dict()},
                           name=f"babble {cfg.plant}", time_series=["desired", "torque"],
                           eye=rec_mod.robot_eye(robot)) as rec:
        rec_mod.log_robot_geometry(rec, robot)
        rec_mod.log_body_trajectory(rec, robot, times, Q)
        rec_mod.log_joint_series(rec, robot.joint_names, times, data.q_des.reshape(-1, n), root="desired")
        rec_mod.log_joint_series(rec, robot.joint_names, times, data.u.reshape(-1, n), root="torque")
        rec_mod.log_scalars(rec, "episode_index", "sim_time", times, np.repeat(np.arange(E), K))
    write_trajectory_mcap(folder / MCAP, robot, times, Q, data.qdot.reshape(-1, n), data.u.reshape(-1, n))


def task_series(problem, X: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per via-point term: values ``(T+1, dim)`` along ``X``, its target ``(dim,)`` and active steps."""
    n_q = problem.n_x // 2
    out = {}
    for term in problem.state_terms:
        if hasattr(term, "taskmap") and np.all(np.isfinite(X)):
            vals, _ = term.taskmap.values_and_jacobians(X[:, :n_q])
            out[term.name] = (vals, term.target, np.flatnonzero(term.active(np.arange(X.shape[0]))))
    return out


def log_task_values(rec, problem, times: np.ndarray, X: np.ndarray, root: str = "task") -> dict:
    """``task/<term>`` values on ``sim_time`` and ``task/<term>/target`` at the via-point times."""
    from pipeline import recording as rec_mod

    series = task_series(problem, X)
    for name, (vals, target, steps) in series.items():
        dims = [f"{name}[{i}]" for i in range(vals.shape[1])]
        rec_mod.log_scalars(rec, f"{root}/{name}/value", "sim_time", times, vals, names=dims)
        if steps.size <= 3:
            rec_mod.log_scalars(rec, f"{root}/{name}/target", "sim_time", times[steps],
                                np.tile(target, (steps.size, 1)), names=[d + "*" for d in dims])
    return {name: v for name, (v, _, _) in series.items()}


def log_task_paths(rec, problem, X: np.ndarray) -> None:
    """3-D task maps (CoG, end effector): the path as a line in the 3D view, targets as dots."""
    from pipeline import recording as rec_mod

    for name, (vals, target, steps) in task_series(problem, X).items():
        if vals.shape[1] != 3 or steps.size > 3:
            continue
        rec_mod.log_points_path(rec, f"world/paths/{name}", vals, color=(250, 200, 30), radius=0.003)
        rec_mod.log_points_path(rec, f"world/targets/{name}", np.atleast_2d(target), color=(230, 40, 40),
                                radius=0.012, line=False)


def run_plan(cache: Cache, cfg, record: bool = True, reporter: Reporter | None = None) -> Outcome:
    """Plan stage through the cache: ``plan.npz`` (+ recording and MCAP of the planned motion)."""
    from stages.plan import stage as plan

    reporter = reporter or Reporter(quiet=True)
    cfg = cfg.normalized()
    config = {**cfg.to_dict(), "record": record}

    def compute(tmp: Path) -> dict:
        with reporter.progress(f"plan {cfg.plant} {cfg.task} {cfg.solver}", cfg.iterations) as update:
            out = plan.run(cfg, progress=update)
        save_npz(tmp / "plan.npz", out.arrays())
        if record:
            write_plan_recording(tmp, out)
        return {"status": out.result.status, "metrics": out.metrics()}

    version = source_version(plan.CODE_VERSION, "plants", "stages.plan")
    return run_stage(cache, "plan", version, config, [], compute)


def write_plan_recording(folder: Path, out) -> None:
    from pipeline import recording as rec_mod
    from pipeline.mcap_io import write_trajectory_mcap

    robot, r, n = out.robot, out.result, out.robot.n_q
    times = out.times
    X = r.X if np.all(np.isfinite(r.X)) else np.nan_to_num(r.X, nan=0.0, posinf=0.0, neginf=0.0)
    with rec_mod.Recording(folder / RECORDING, properties={"stage": "plan", **out.config.to_dict()},
                           name=f"plan {out.config.plant} {out.config.task} {out.config.solver}",
                           time_series=["task", "cost"], eye=rec_mod.robot_eye(robot)) as rec:
        rec_mod.log_robot_geometry(rec, robot)
        rec_mod.log_body_trajectory(rec, robot, times, X[:, :n])
        if r.history:
            it = np.array([h.iteration for h in r.history])
            rec_mod.log_scalars(rec, "cost/total", "iteration", it, r.costs)
        values = log_task_values(rec, out.problem, times, X)
        log_task_paths(rec, out.problem, X)
        rec_mod.log_joint_series(rec, robot.joint_names, times[:-1], r.U, root="control")
    write_trajectory_mcap(folder / MCAP, robot, times, X[:, :n], X[:, n:],
                          np.vstack([r.U, np.full((1, n), np.nan)]), task_values=values)


def load_npz(entry: Entry, name: str) -> dict[str, np.ndarray]:
    from pipeline.errors import CorruptArtifact

    try:
        with np.load(entry.path / name, allow_pickle=False) as f:
            return {k: f[k] for k in f.files}
    except Exception as e:  # noqa: BLE001 - any unreadable file is a corrupt artifact
        raise CorruptArtifact(f"cannot read {entry.stage}/{entry.key}/{name}: {e}") from None


def run_execute(cache: Cache, plan_ref: str, cfg, record: bool = True,
                reporter: Reporter | None = None) -> Outcome:
    """Execute stage through the cache: ``rollout.npz`` (+ recording and MCAP)."""
    from stages import execute

    reporter = reporter or Reporter(quiet=True)
    plan_entry = find_entry(cache, plan_ref, stage="plan")
    if plan_entry.stage != "plan":
        raise BadInput(f"{plan_ref} is a {plan_entry.stage} artifact, not a plan")
    config = {**cfg.to_dict(), "record": record}

    def compute(tmp: Path) -> dict:
        plan = load_npz(plan_entry, "plan.npz")
        pconf = plan_entry.meta["config"]
        with reporter.progress(f"execute {pconf['plant']} {pconf['task']} in Drake", len(plan["o"])) as update:
            out = execute.run(cfg, pconf, plan, progress=update)
        save_npz(tmp / "rollout.npz", out.arrays())
        if record:
            write_execute_recording(tmp, out, pconf, cfg)
        return {"status": out.metrics["status"], "metrics": out.metrics}

    version = source_version(execute.CODE_VERSION, "plants", "stages.execute", "stages.plan")
    return run_stage(cache, "execute", version, config, [f"plan/{plan_entry.key}"], compute)


def write_execute_recording(folder: Path, out, pconf: dict, cfg) -> None:
    from pipeline import recording as rec_mod
    from pipeline.mcap_io import write_trajectory_mcap
    from stages.plan.stage import PlanConfig

    pcfg = PlanConfig.from_dict(pconf)
    problem, robot = out.problem, out.robot
    n = robot.n_q
    X = np.nan_to_num(out.X)
    times = out.times
    with rec_mod.Recording(folder / RECORDING, properties={"stage": "execute", "plan": pconf, **cfg.to_dict()},
                           name=f"execute {pcfg.plant} {pcfg.task} {pcfg.solver}",
                           time_series=["task", "torque", "error", "cog"],
                           eye=rec_mod.robot_eye(robot)) as rec:
        rec_mod.log_robot_geometry(rec, robot)
        rec_mod.log_body_trajectory(rec, robot, times, X[:, :n])
        values = log_task_values(rec, problem, times, X)
        log_task_values(rec, problem, times, np.nan_to_num(out.X_plan), root="task_planned")
        if len(out.tau):
            rec_mod.log_joint_series(rec, robot.joint_names, times[:len(out.tau)], out.tau, root="torque")
        err = np.linalg.norm(X[:, :n] - out.X_plan[:, :n], axis=1)
        rec_mod.log_scalars(rec, "error/planned_vs_executed", "sim_time", times, err)
        if out.cog is not None:
            rec_mod.log_scalars(rec, "cog/margin", "sim_time", times, np.nan_to_num(out.cog_margin))
            rec_mod.log_scalars(rec, "cog/xy", "sim_time", times, np.nan_to_num(out.cog[:, :2]),
                                names=["cog x", "cog y"])
            _log_support(rec, times, out)
    write_trajectory_mcap(folder / MCAP, robot, times, X[:, :n], X[:, n:],
                          np.vstack([out.tau, np.full((len(times) - len(out.tau), n), np.nan)]),
                          task_values=values)


def _log_support(rec, times: np.ndarray, out) -> None:
    """Support polygon (line strip on the ground) and the CoG's ground projection per step."""
    import rerun as rr

    stream = rec.rec
    for k, poly in enumerate(out.support or []):
        stream.set_time("sim_time", duration=float(times[k]))
        ring = np.vstack([poly, poly[:1]])
        inside = out.cog_margin[k] > 0
        stream.log("world/support_polygon", rr.LineStrips3D([np.c_[ring, np.zeros(len(ring))]],
                                                             colors=[(40, 200, 80) if inside else (230, 50, 50)]))
        stream.log("world/cog_ground", rr.Points3D([[*out.cog[k, :2], 0.0]], radii=0.008,
                                                   colors=[(255, 220, 0)]))


EVALUATE_VERSION = "evaluate-1"


def run_evaluate(cache: Cache, plan_ref: str, rollout_ref: str | None = None,
                 reporter: Reporter | None = None) -> Outcome:
    """Evaluate one run (SPEC §8): final cost, via-point errors, iterations to converge, wall time
    and, with a rollout, planned-vs-executed RMSE; writes ``evaluation.json`` and ``cost.png``."""
    plan_entry = find_entry(cache, plan_ref, stage="plan")
    inputs = [f"plan/{plan_entry.key}"]
    rollout = None
    if rollout_ref:
        rollout = find_entry(cache, rollout_ref, stage="execute")
        if rollout.meta.get("inputs") != inputs:
            raise BadInput(f"rollout {rollout.key} was not executed from plan {plan_entry.key}")
        inputs.append(f"execute/{rollout.key}")

    def compute(tmp: Path) -> dict:
        plan = load_npz(plan_entry, "plan.npz")
        pm = plan_entry.meta.get("metrics", {})
        costs = plan["costs"]
        rel = np.abs(np.diff(costs)) / np.maximum(np.abs(costs[1:]), 1e-300)
        to_converge = int(np.argmax(rel < 1e-3) + 2) if np.any(rel < 1e-3) else None
        metrics = {"plan": plan_entry.key, "config": plan_entry.meta.get("config"),
                   "status": plan_entry.meta.get("status"), "initial_cost": pm.get("initial_cost"),
                   "final_cost": pm.get("final_cost"), "cost_ratio": pm.get("cost_ratio"),
                   "iterations": pm.get("iterations"), "iterations_to_0.1%": to_converge,
                   "wall_time_s": pm.get("wall_time_s"), "via_point_errors": pm.get("via_point_errors")}
        if rollout is not None:
            rm = rollout.meta.get("metrics", {})
            metrics.update(rollout=rollout.key, executed_via_point_errors=rm.get("via_point_errors"),
                           rmse_planned_executed=rm.get("rmse_planned_executed"),
                           **{k: rm[k] for k in rm if k.startswith("cog_") or k == "torque_saturation"})
        (tmp / "evaluation.json").write_text(__import__("json").dumps(metrics, indent=2, default=float))
        _cost_png(tmp / "cost.png", costs, pm.get("initial_cost"), plan_entry.meta.get("config", {}))
        return {"status": "ok", "metrics": metrics}

    return run_stage(cache, "evaluate", EVALUATE_VERSION, {}, inputs, compute)


def _cost_png(path: Path, costs: np.ndarray, initial: float | None, cfg: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.4))
    it = np.arange(0, len(costs) + 1)
    ax.semilogy(it, np.r_[initial if initial else np.nan, costs], marker=".")
    ax.set_xlabel("iteration (0 = initial trajectory)")
    ax.set_ylabel("cost")
    ax.set_title(f"{cfg.get('plant')} {cfg.get('task')} {cfg.get('solver')} ({cfg.get('dynamics')})", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
