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
    """The executed motion against the plan; torques, tracking error, the status (a text entry,
    and a log entry at the moment of failure on ``sim_time``) and, for the free-standing Nao, the
    robot in the world, its contact points, the contact-based support polygon and the CoG's ground
    projection."""
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
    free = "q_free" in d
    series = ["task", "torque", "error", *(["cog"] if free else [])]
    eye = rec_mod.robot_eye(robot)
    with rec_mod.Recording(folder / RECORDING, properties={"stage": "execute", "key": art.key, "plan": pconf,
                                                            **art.config},
                           name=f"execute {pconf['plant']} {pconf['task']} {pconf['solver']}",
                           time_series=series, eye=eye) as rec:
        rec.rec.send_blueprint(_execute_blueprint(series, eye), make_active=True, make_default=True)
        if free:  # the free-standing Nao: its own plant (floating base, floor) and stored positions
            from plants.free_nao import shared_free_nao

            nao = shared_free_nao()
            rec_mod.log_robot_geometry(rec, nao)
            rec_mod.log_body_trajectory(rec, nao, times, _hold_last_finite(d["q_free"]), joints=False)
            rec_mod.log_joint_series(rec, robot.joint_names, times, X[:, :n])
        else:
            rec_mod.log_robot_geometry(rec, robot)
            rec_mod.log_body_trajectory(rec, robot, times, X[:, :n])
        values = log_task_values(rec, objective, times, X)
        log_task_values(rec, objective, times, np.nan_to_num(X_plan), root="task_planned")
        if len(tau):
            rec_mod.log_joint_series(rec, robot.joint_names, times[:len(tau)], tau, root="torque")
        err = np.linalg.norm(X[:, :n] - X_plan[:, :n], axis=1)
        rec_mod.log_scalars(rec, "error/planned_vs_executed", "sim_time", times, err)
        if free:
            cog, margin = d["cog"], d["cog_margin"]
            rec_mod.log_scalars(rec, "cog/margin", "sim_time", times, np.nan_to_num(margin))
            rec_mod.log_scalars(rec, "cog/xy", "sim_time", times, np.nan_to_num(cog[:, :2]), names=["cog x", "cog y"])
            _log_support(rec, times, d["support"], cog, margin, d["contact_points"])
        _log_status(rec, art, times)
    write_trajectory_mcap(folder / MCAP, robot, times, X[:, :n], X[:, n:],
                          np.vstack([tau, np.full((len(times) - len(tau), n), np.nan)]), task_values=values)


def _execute_blueprint(time_series: list[str], eye):
    """The default layout (3D view beside the time series) with the status text and the event log."""
    import rerun.blueprint as rrb

    plots = [rrb.TimeSeriesView(origin=f"/{r}", name=r) for r in ["joints", *time_series]]
    controls = rrb.EyeControls3D(position=list(map(float, eye[0])), look_target=list(map(float, eye[1])),
                                 eye_up=[0.0, 0.0, 1.0])
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="/world", contents="/world/**", name="robot", eye_controls=controls),
            rrb.Vertical(rrb.TextDocumentView(origin="/status", name="status"),
                         rrb.TextLogView(origin="/events", name="events"), *plots,
                         row_shares=[1, 1, *[2] * len(plots)]),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def _hold_last_finite(Q: np.ndarray) -> np.ndarray:
    """Rows that are not finite replaced by the last finite one (the first finite one before it)."""
    Q = np.array(Q, float)
    good = np.all(np.isfinite(Q), axis=1)
    if not good.any():
        return np.nan_to_num(Q)
    last = Q[np.flatnonzero(good)[0]]
    for k in range(len(Q)):
        if good[k]:
            last = Q[k]
        else:
            Q[k] = last
    return Q


def _log_status(rec, art, times: np.ndarray) -> None:
    """``status``: a text entry (status, reason, thresholds); ``events``: the moment of failure on ``sim_time``."""
    import rerun as rr

    m = art.metrics or {}
    status = art.status
    lines = [f"# execution status: {status}", "", str(m.get("reason", ""))]
    if m.get("failure_time") is not None:
        lines += ["", f"moment of failure: t = {m['failure_time']:.3g} s (sim_time)"]
    if "stood" in m:
        lines += ["", f"stood: {m['stood']}; CoG inside the contact polygon in {m.get('cog_inside_fraction', 0):.0%} "
                  f"of the samples"]
    if m.get("thresholds"):
        lines += ["", "thresholds: " + ", ".join(f"{k} = {v:g}" for k, v in m["thresholds"].items())]
    rec.rec.log("status", rr.TextDocument("\n".join(lines), media_type="text/markdown"), static=True)
    stream = rec.rec
    stream.set_time("sim_time", duration=float(times[0]))
    stream.log("events", rr.TextLog(f"start: plan executed ({art.config.get('x0_noise', 0)} rad x0 noise, "
                                    f"{art.config.get('process_noise', 0)} N m process noise)", level="INFO"))
    t_fail = m.get("failure_time")
    if status != "ok" and t_fail is not None:
        stream.set_time("sim_time", duration=float(t_fail))
        stream.log("events", rr.TextLog(f"{status}: {m.get('reason', '')}", level="ERROR"))
    stream.set_time("sim_time", duration=float(times[-1]))
    stream.log("events", rr.TextLog(f"end: status {status}", level="INFO" if status == "ok" else "WARN"))


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


def _log_support(rec, times: np.ndarray, support: np.ndarray, cog: np.ndarray, margin: np.ndarray,
                 contacts: np.ndarray) -> None:
    """Per step: the support polygon of the sole corners in contact (a line strip on the ground,
    green while the CoG projection is inside, red outside; a segment or a point when fewer corners
    touch; cleared when none do), the contact points, and the CoG's ground projection (a large
    marker joined to the CoG by a vertical line)."""
    import rerun as rr

    stream = rec.rec
    for k, poly in enumerate(support):
        stream.set_time("sim_time", duration=float(times[k]))
        poly = poly[np.all(np.isfinite(poly), axis=1)]
        inside = bool(margin[k] > 0)
        color = (40, 200, 80) if inside else (230, 50, 50)
        if len(poly) >= 2:
            ring = np.vstack([poly, poly[:1]]) if len(poly) >= 3 else poly
            stream.log("world/support_polygon", rr.LineStrips3D([np.c_[ring, np.full(len(ring), 1e-3)]],
                                                                 colors=[color], radii=0.003))
        elif len(poly) == 1:
            stream.log("world/support_polygon", rr.Points3D([[*poly[0], 1e-3]], colors=[color], radii=0.006))
        else:
            stream.log("world/support_polygon", rr.Clear(recursive=False))
        pts = contacts[k][np.all(np.isfinite(contacts[k]), axis=1)]
        stream.log("world/contact_points", rr.Points3D(pts, colors=[(60, 120, 255)], radii=0.007)
                   if len(pts) else rr.Clear(recursive=False))
        if np.all(np.isfinite(cog[k])):
            ground = [*cog[k, :2], 1e-3]
            stream.log("world/cog_ground", rr.Points3D([ground], radii=0.014, colors=[(255, 210, 0)],
                                                       labels=["CoG"]))
            stream.log("world/cog_line", rr.LineStrips3D([[cog[k], ground]], colors=[(255, 210, 0)], radii=0.002))


RECORDERS = {"babble": record_babble, "plan": record_plan, "execute": record_execute, "fit": record_fit}
