"""The execute stage's recording: the executed motion against the plan, torques, tracking error,
the status and events; a standing robot's support polygon, CoG and ZMP."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from raico.pipeline.recordings import MCAP, RECORDING
from raico.pipeline.recordings import rerun_io as rec_mod
from raico.pipeline.recordings.mcap_io import write_trajectory_mcap
from raico.pipeline.recordings.scene import log_scene, scene_views
from raico.pipeline.recordings.tasks import XYZ_COLORS, log_task_paths, log_task_plots, task_plots, task_views


def _input(inputs: list, stage: str):
    return next(a for a in inputs if a.stage == stage)


def record_execute(folder: Path, art, inputs: list, lookup=None) -> None:
    """The executed motion against the plan; torques, tracking error, the status (a text entry,
    and a log entry at the moment of failure on ``sim_time``) and, for a floating robot, the
    robot in the world, its contact points, the contact-based support polygon and the CoG's ground
    projection."""
    from raico.planning.objective import objective_from_description
    from raico.plants.robots import robot_for

    plan = _input(inputs, "plan")
    desc = plan.document("problem.json")
    pconf = plan.config
    d = art.arrays("rollout.npz")
    robot = robot_for(desc)
    objective = objective_from_description(desc, robot)
    n = robot.n_q
    X, X_plan, tau, times = np.nan_to_num(d["X"]), d["X_plan"], d["tau"], d["times"]
    free = "q_free" in d
    plots = task_plots(objective, X, robot.joint_names)
    planned = task_plots(objective, np.nan_to_num(X_plan), robot.joint_names)
    vias = sorted({s for tp in plots for s, _ in tp.targets})
    eye = rec_mod.robot_eye(robot, X[:, :n])
    with rec_mod.Recording(folder / RECORDING, rec_mod.application_id("execute", pconf["plant"], pconf["task"]),
                           properties={"stage": "execute", "key": art.key, "plan": pconf, **art.config},
                           name=f"execute {pconf['plant']} {pconf['task']} {pconf['solver']}",
                           blueprint=_execute_blueprint(plots, robot.joint_names, eye, free,
                                                        [*scene_views(objective), *_mpc_views(d)])) as rec:
        sel = rec_mod.plot_indices(len(times), vias)
        if free:  # a floating robot: its own plant (floating base, floor) and stored positions
            from raico.plants.floating import shared_floating

            floating = shared_floating(robot.spec)
            poses = rec_mod.pose_indices(len(times), rec_mod.n_bodies(floating), vias)
            rec_mod.log_robot_geometry(rec, floating)
            rec_mod.log_body_trajectory(rec, floating, times, _hold_last_finite(d["q_free"]), joints=False, poses=poses)
            rec_mod.log_joint_series(rec, robot.joint_names, times[sel], X[sel, :n],
                                     continuous=rec_mod.continuous_joints(robot))
        else:
            rec_mod.log_robot_geometry(rec, robot)
            rec_mod.log_body_trajectory(rec, robot, times, X[:, :n], keep=vias)
        log_task_plots(rec, plots, times, sel)
        log_task_plots(rec, planned, times, sel, series="planned", targets=False)
        if not free:  # a floating robot stands elsewhere in its world than the fixed model the tasks are in
            log_task_paths(rec, objective, X, plots)
            log_task_paths(rec, objective, X_plan, planned, label="planned")
            log_scene(rec, objective, times, X, sel)
        if len(tau):
            sel_u = rec_mod.plot_indices(len(tau), vias)
            rec_mod.log_joint_series(rec, robot.joint_names, times[:len(tau)][sel_u], tau[sel_u], root="torque")
        err = np.linalg.norm(X[:, :n] - X_plan[:, :n], axis=1)
        rec_mod.log_scalars(rec, "error/planned_vs_executed", "sim_time", times[sel], err[sel],
                            names=["|q - q_plan| (rad)"])
        if free:
            cog, margin = d["cog"], d["cog_margin"]
            rec_mod.log_scalars(rec, "cog/margin", "sim_time", times[sel], np.nan_to_num(margin)[sel],
                                names=["CoG margin in the support polygon (m)"])
            rec_mod.log_scalars(rec, "cog/xy", "sim_time", times[sel], np.nan_to_num(cog[:, :2])[sel],
                                names=["cog x", "cog y"], colors=[XYZ_COLORS["x"], XYZ_COLORS["y"]])
            zmp = d["zmp"] if "zmp" in d else np.full((len(times), 2), np.nan)
            zmp_margin = d["zmp_margin"] if "zmp_margin" in d else np.full(len(times), np.nan)
            rec_mod.log_scalars(rec, "cog/zmp_margin", "sim_time", times[sel], zmp_margin[sel],
                                names=["ZMP margin in the support polygon (m)"], colors=[ZMP_COLOR])
            rec_mod.log_scalars(rec, "contact/force", "sim_time", times[sel], d["sole_force"][sel],
                                names=["left sole (N)", "right sole (N)"])
            _log_support(rec, times, d["support"], cog, margin, d["contact_points"], poses, zmp)
        if "mpc_solve_time" in d:
            _log_mpc(rec, objective, d, plots, times, free)
        _log_status(rec, art, times)
    values = {term: tp.raw for tp in plots for term in tp.terms}
    write_trajectory_mcap(folder / MCAP, robot, times, X[:, :n], X[:, n:],
                          np.vstack([tau, np.full((len(times) - len(tau), n), np.nan)]), task_values=values)


def _mpc_views(d) -> list:
    """The MPC's solve time per tick, for a ``--controller mpc`` rollout (none otherwise)."""
    import rerun.blueprint as rrb

    return [rrb.TimeSeriesView(origin="/mpc", name="MPC solve time per tick (ms)")] if "mpc_solve_time" in d else []


PREDICTIONS = 100   # predicted horizons drawn at most (evenly spread over the run)
FADE = (255, 130, 50)   # alpha of the latest predicted horizon and of the two before it


def _log_mpc(rec, objective, d, plots: list, times: np.ndarray, free: bool) -> None:
    """Receding-horizon control (``--controller mpc``): each tick's solve time against the period
    (``mpc/tick``), and in the 3-D view the predicted path of each 3-D task map of the window at every
    tick drawn, with the two before it fading (``world/predicted/<map>/<age>``)."""
    solve = d["mpc_solve_time"]
    ticks = len(solve)
    if ticks == 0:
        return
    period = float(times[-1]) / ticks
    t_tick = np.arange(ticks) * period
    sel = rec_mod.plot_indices(ticks)
    rec_mod.log_scalars(rec, "mpc/tick", "sim_time", t_tick[sel],
                        np.column_stack([solve[sel] * 1e3, np.full(len(sel), period * 1e3)]),
                        names=["solve time (ms)", "period (ms)"])
    pred = d["mpc_predicted"] if "mpc_predicted" in d else None
    if pred is None or free:
        return
    wanted = {tp.entity for tp in plots if tp.raw.shape[1] == 3 and tp.targets}
    stream = rec.rec
    drawn = rec_mod.decimate(ticks, PREDICTIONS)
    for j, i in enumerate(drawn):
        stream.set_time("sim_time", duration=float(t_tick[i]))
        for age in range(len(FADE)):
            if j - age < 0:
                continue
            window = np.asarray(pred[drawn[j - age]], float)
            for tp in task_plots(objective, window):
                if tp.entity in wanted:
                    rec_mod.log_points_path(rec, f"world/predicted/{tp.entity}/{age}", tp.raw,
                                            color=(40, 200, 120, FADE[age]), radius=0.002, static=False)


def _execute_blueprint(plots: list, joint_names, eye, free: bool, extra: list | tuple = ()):
    """The robot above the status text and the event log; on the right the task views (executed
    against planned), the tracking error (and the CoG's margin for a floating robot), joints and torques
    by limb."""
    import rerun.blueprint as rrb

    groups = rec_mod.joint_groups(joint_names)
    error = rrb.TimeSeriesView(origin="/error", name="tracking error (rad)")
    views = [*task_views(plots, planned=True), error, *extra,
             *([rrb.TimeSeriesView(origin="/cog", name="CoG and ZMP (m)"),
                rrb.TimeSeriesView(origin="/contact", name="ground force on the soles (N)")] if free else []),
             rec_mod.group_views("joints", groups, "joints (rad)"),
             rec_mod.group_views("torque", groups, "torque (N m)")]
    below = [rrb.Horizontal(rrb.TextDocumentView(origin="/status", name="status"),
                            rrb.TextLogView(origin="/events", name="events"))]
    return rec_mod.stage_blueprint(eye, views, below)


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


ZMP_COLOR = (200, 60, 200)  # the zero-moment point: magenta on the ground, its margin series alike


def _log_support(rec, times: np.ndarray, support: np.ndarray, cog: np.ndarray, margin: np.ndarray,
                 contacts: np.ndarray, steps: np.ndarray | None = None, zmp: np.ndarray | None = None) -> None:
    """Per step: the support polygon of the sole corners in contact (a line strip on the ground,
    green while the CoG projection is inside, red outside; a segment or a point when fewer corners
    touch; cleared when none do), the contact points, the CoG's ground projection (a large
    marker joined to the CoG by a vertical line) and the zero-moment point (magenta, where there is a
    ground force); at the ``steps`` (default: all) where the robot's pose is logged."""
    import rerun as rr

    stream = rec.rec
    for k in (range(len(support)) if steps is None else steps):
        poly = support[k]
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
        if zmp is not None:
            stream.log("world/zmp", rr.Points3D([[*zmp[k], 2e-3]], radii=0.01, colors=[ZMP_COLOR], labels=["ZMP"])
                       if np.all(np.isfinite(zmp[k])) else rr.Clear(recursive=False))
