"""Recordings derived from a stage's stored data: ``recording.rrd`` (Rerun) and ``trajectory.mcap``.

A recorder is ``recorder(folder, artifact, inputs)``: it reads the entry's data files (and
its inputs', e.g. the plan of an execution) and writes the recording files into ``folder``;
the cache moves them beside the data (``Cache.write_derived``). Because recordings are made
from the data, a run first made with ``--no-record`` gets its recording later without
recomputing, and the recording is never part of the data's cache key.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline import recording as rec_mod
from pipeline.mcap_io import write_trajectory_mcap
from pipeline.recorders_fit import record_fit

RECORDING = "recording.rrd"
MCAP = "trajectory.mcap"


def _input(inputs: list, stage: str):
    return next(a for a in inputs if a.stage == stage)


def _episode_times(t: np.ndarray, episodes: int, gap: float) -> np.ndarray:
    """Episodes laid end to end on one ``sim_time`` axis: ``(episodes * K,)`` s."""
    span = t[-1] + gap
    return (np.arange(episodes)[:, None] * span + t[None, :]).reshape(-1)


def record_babble(folder: Path, art, inputs: list) -> None:
    """Every babbling episode laid end to end on ``sim_time``: robot, desired and torque series."""
    from plants.robots import shared_robot

    cfg = art.config
    data = art.arrays("data.npz")
    robot = shared_robot(cfg["plant"])
    q, qdot, u, t = data["q"], data["qdot"], data["u"], data["t"]
    E, K, n = q.shape
    times = _episode_times(t, E, gap=t[1] - t[0])
    Q = q.reshape(-1, n)
    with rec_mod.Recording(folder / RECORDING, properties={"stage": "babble", "key": art.key, **cfg},
                           name=f"babble {cfg['plant']}", time_series=["desired", "torque"],
                           eye=rec_mod.robot_eye(robot)) as rec:
        rec_mod.log_robot_geometry(rec, robot)
        rec_mod.log_body_trajectory(rec, robot, times, Q)
        rec_mod.log_joint_series(rec, robot.joint_names, times, data["q_des"].reshape(-1, n), root="desired")
        rec_mod.log_joint_series(rec, robot.joint_names, times, u.reshape(-1, n), root="torque")
        rec_mod.log_scalars(rec, "episode_index", "sim_time", times, np.repeat(np.arange(E), K))
    write_trajectory_mcap(folder / MCAP, robot, times, Q, qdot.reshape(-1, n), u.reshape(-1, n))


def record_plan(folder: Path, art, inputs: list) -> None:
    """The planned motion, task values against their via-points, controls and cost per iteration."""
    from plants.robots import shared_robot
    from stages.plan.stage import objective_from_description

    cfg = art.config
    d = art.arrays("plan.npz")
    desc = art.document("problem.json")
    robot = shared_robot(desc["plant"])
    objective = objective_from_description(desc, robot)
    n, times, costs = robot.n_q, d["times"], d["costs"]
    X = d["X"] if np.all(np.isfinite(d["X"])) else np.nan_to_num(d["X"], nan=0.0, posinf=0.0, neginf=0.0)
    U = d["U"]
    with rec_mod.Recording(folder / RECORDING, properties={"stage": "plan", "key": art.key, **cfg},
                           name=f"plan {cfg['plant']} {cfg['task']} {cfg['solver']}",
                           time_series=["task", "cost"], eye=rec_mod.robot_eye(robot)) as rec:
        rec_mod.log_robot_geometry(rec, robot)
        rec_mod.log_body_trajectory(rec, robot, times, X[:, :n])
        if costs.size:
            rec_mod.log_scalars(rec, "cost/total", "iteration", np.arange(1, costs.size + 1), costs)
        values = log_task_values(rec, objective, times, X)
        log_task_paths(rec, objective, X)
        rec_mod.log_joint_series(rec, robot.joint_names, times[:-1], U, root="control")
    write_trajectory_mcap(folder / MCAP, robot, times, X[:, :n], X[:, n:],
                          np.vstack([U, np.full((1, n), np.nan)]), task_values=values)


def record_execute(folder: Path, art, inputs: list) -> None:
    """The executed motion against the plan; torques, tracking error and, for the Nao, the CoG
    against the support polygon."""
    from plants.robots import shared_robot
    from stages.plan.stage import objective_from_description

    plan = _input(inputs, "plan")
    desc = plan.document("problem.json")
    pconf = plan.config
    d = art.arrays("rollout.npz")
    robot = shared_robot(desc["plant"])
    objective = objective_from_description(desc, robot)
    n = robot.n_q
    X, X_plan, tau, times = np.nan_to_num(d["X"]), d["X_plan"], d["tau"], d["times"]
    with rec_mod.Recording(folder / RECORDING, properties={"stage": "execute", "key": art.key, "plan": pconf,
                                                            **art.config},
                           name=f"execute {pconf['plant']} {pconf['task']} {pconf['solver']}",
                           time_series=["task", "torque", "error", "cog"],
                           eye=rec_mod.robot_eye(robot)) as rec:
        rec_mod.log_robot_geometry(rec, robot)
        rec_mod.log_body_trajectory(rec, robot, times, X[:, :n])
        values = log_task_values(rec, objective, times, X)
        log_task_values(rec, objective, times, np.nan_to_num(X_plan), root="task_planned")
        if len(tau):
            rec_mod.log_joint_series(rec, robot.joint_names, times[:len(tau)], tau, root="torque")
        err = np.linalg.norm(X[:, :n] - X_plan[:, :n], axis=1)
        rec_mod.log_scalars(rec, "error/planned_vs_executed", "sim_time", times, err)
        if "cog" in d:
            cog, margin = d["cog"], d["cog_margin"]
            rec_mod.log_scalars(rec, "cog/margin", "sim_time", times, np.nan_to_num(margin))
            rec_mod.log_scalars(rec, "cog/xy", "sim_time", times, np.nan_to_num(cog[:, :2]), names=["cog x", "cog y"])
            _log_support(rec, times, d["support"], cog, margin)
    write_trajectory_mcap(folder / MCAP, robot, times, X[:, :n], X[:, n:],
                          np.vstack([tau, np.full((len(times) - len(tau), n), np.nan)]), task_values=values)


def task_series(problem, X: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per via-point term: values ``(T+1, dim)`` along ``X``, its target ``(dim,)`` and active steps."""
    n_q = X.shape[1] // 2
    out = {}
    for term in problem.state_terms:
        if hasattr(term, "taskmap") and np.all(np.isfinite(X)):
            vals, _ = term.taskmap.values_and_jacobians(X[:, :n_q])
            out[term.name] = (vals, term.target, np.flatnonzero(term.active(np.arange(X.shape[0]))))
    return out


def log_task_values(rec, problem, times: np.ndarray, X: np.ndarray, root: str = "task") -> dict:
    """``task/<term>`` values on ``sim_time`` and ``task/<term>/target`` at the via-point times."""
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
    for name, (vals, target, steps) in task_series(problem, X).items():
        if vals.shape[1] != 3 or steps.size > 3:
            continue
        rec_mod.log_points_path(rec, f"world/paths/{name}", vals, color=(250, 200, 30), radius=0.003)
        rec_mod.log_points_path(rec, f"world/targets/{name}", np.atleast_2d(target), color=(230, 40, 40),
                                radius=0.012, line=False)


def _log_support(rec, times: np.ndarray, support: np.ndarray, cog: np.ndarray, margin: np.ndarray) -> None:
    """Support polygon (line strip on the ground) and the CoG's ground projection per step."""
    import rerun as rr

    stream = rec.rec
    for k, poly in enumerate(support):
        poly = poly[np.all(np.isfinite(poly), axis=1)]
        if len(poly) < 3 or not np.all(np.isfinite(cog[k])):
            continue
        stream.set_time("sim_time", duration=float(times[k]))
        ring = np.vstack([poly, poly[:1]])
        inside = margin[k] > 0
        stream.log("world/support_polygon", rr.LineStrips3D([np.c_[ring, np.zeros(len(ring))]],
                                                             colors=[(40, 200, 80) if inside else (230, 50, 50)]))
        stream.log("world/cog_ground", rr.Points3D([[*cog[k, :2], 0.0]], radii=0.008,
                                                   colors=[(255, 220, 0)]))


RECORDERS = {"babble": record_babble, "plan": record_plan, "execute": record_execute, "fit": record_fit}
