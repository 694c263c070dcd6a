"""Recording of a learn artifact: the loop's quantities per episode on the ``episode`` timeline.

Made from ``episodes.json`` and the fit, plan and execute entries it names (read from the same
cache as the learn entry, through the runner's ``lookup``), like every recording from stored data
(:mod:`raico.pipeline.recordings`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from raico.pipeline.recordings import rerun_io as rec_mod

LEARN_VIEWS = {  # view name -> entity root (the learn recording's plots, one quantity and unit each)
    "GP error on the next execution, log10 (rad/s^2)": "gp_error_log10",
    "GP error on held-out babbling, log10 (rad/s^2)": "gp_error_heldout_log10",
    "distance to the target (m)": "distance",
    "time per evaluation (s)": "time",
    "training points": "points",
    "largest |torque| per joint this episode (N m; bars in joint order)": "episode/torque",
    "GP variance along the execution (of the data's)": "variance",
}


def learn_blueprint(eye):
    """The learn recording's layout: the robot (framed on the last plan's motion) beside one view per
    quantity, on the ``episode`` timeline (log10 where the values span decades)."""
    import rerun.blueprint as rrb

    names = list(LEARN_VIEWS)
    v = {name: rrb.TimeSeriesView(origin=f"/{root}", name=name) for name, root in LEARN_VIEWS.items()
         if root != "episode/torque"}
    bars = rrb.BarChartView(origin="/episode/torque", name=names[5])
    gp = rrb.Tabs(v[names[0]], v[names[1]], name="GP error", active_tab=0)
    other = rrb.Tabs(v[names[4]], v[names[6]], name="data", active_tab=0)
    return rec_mod.stage_blueprint(eye, [gp, v[names[2]], v[names[3]], other], [bars], timeline="episode",
                                   robot_share=2.5, play_state="following")


def record_learn(folder: Path, art, inputs: list, lookup) -> None:
    """Per episode on the ``episode`` timeline (the file opens on it, at the last episode): the GP
    error per joint on the next execution and on the held-out babbling (log10), the distance to the
    target executed and planned, the time per evaluation (fit, plan, execute), the training points,
    the largest torque per joint and the GP's variance along the execution; in 3D the robot at the
    episode's executed final pose (the last finite state; the plan's final pose if none is finite),
    that episode's planned (blue) and executed (orange) end-effector paths (each episode replaces
    the last) and the target. The camera frames the last episode's planned motion. ``lookup(stage, key)``:
    an entry of the learn entry's cache (its episodes' fit, plan and execute runs) as an artifact."""
    import rerun as rr

    from raico.plants.gp import GPModel
    from raico.plants.taskmaps import EndEffectorPosition
    from raico.stages.learn import EPISODES_FILE, LearnConfig

    doc = art.document(EPISODES_FILE)
    robot = LearnConfig.from_dict(doc["config"]).robots()[0]
    eps = doc["episodes"]
    k = np.array([e["episode"] for e in eps])
    n = robot.n_q
    frame = "ee" if robot.plant.HasFrameNamed("ee") else _task_frame(lookup, eps[-1]["plan"])
    ee = EndEffectorPosition(robot, frame) if frame is not None else None
    last_plan = lookup("plan", eps[-1]["plan"]).arrays("plan.npz")
    eye = rec_mod.robot_eye(robot, last_plan["X"][:, :n])
    with rec_mod.Recording(folder / "recording.rrd", properties={"stage": "learn", "key": art.key,
                                                                 **doc["config"]},
                           name=f"learn {doc['config']['plant']} {doc['config']['task']}",
                           blueprint=learn_blueprint(eye)) as rec:
        rec_mod.log_robot_geometry(rec, robot)
        joints = [rec_mod.entity_name(j) for j in robot.joint_names]

        def series(key: str) -> np.ndarray:
            return np.array([np.nan if e.get(key) is None else float(e[key]) for e in eps])

        def per_joint(key: str) -> np.ndarray:
            return np.array([e.get(key) or [np.nan] * n for e in eps], float).reshape(len(eps), n)

        with np.errstate(divide="ignore", invalid="ignore"):
            rec_mod.log_scalars(rec, "gp_error_log10", "episode", k, np.log10(per_joint("gp_error_joint")), joints)
            rec_mod.log_scalars(rec, "gp_error_heldout_log10", "episode", k,
                                np.log10(per_joint("gp_error_heldout_joint")), joints)
        crit = LearnConfig.from_dict(doc["config"]).achieved()  # the task's own end-angle criterion
        executed = "executed" if crit is None else f"executed_{crit['joint']}_angle_error_rad"
        for name, key in ((executed, "task_error"), ("planned", "planned_task_error")):
            rec_mod.log_scalars(rec, f"distance/{rec_mod.entity_name(name)}", "episode", k, series(key))
        for name in ("fit", "plan", "execute"):
            rec_mod.log_scalars(rec, f"time/{name}", "episode", k, series(f"{name}_time_s"))
        rec_mod.log_scalars(rec, "points/training", "episode", k, series("n_points"))
        stride = int(doc["config"].get("stride") or 1)
        rec_mod.log_scalars(rec, "points/added_from_this_execution", "episode", k, np.ceil(series("data_steps") / stride))
        stream = rec.rec
        target = None
        for e in eps:
            plan = lookup("plan", e["plan"]).arrays("plan.npz")
            roll = lookup("execute", e["execute"]).arrays("rollout.npz")
            model = GPModel.from_arrays(lookup("fit", e["fit"]).arrays("model.npz"))
            stream.set_time("episode", sequence=int(e["episode"]))
            Xe = roll["X"]
            ok = np.all(np.isfinite(Xe), axis=1)
            final = Xe[ok][-1, :n] if ok.any() else plan["X"][-1, :n]
            if np.all(np.isfinite(final)):
                rec_mod.log_robot_pose(rec, robot, final, "episode", int(e["episode"]))
            if ee is not None:
                for label, X, color in (("planned", plan["X"], (80, 160, 255)), ("executed", Xe, (250, 120, 30))):
                    good = np.all(np.isfinite(X), axis=1)
                    if good.sum() > 1:
                        pts, _ = ee.values_and_jacobians(X[good, :n])
                        rec_mod.log_points_path(rec, f"world/paths/{label}", pts, color=color, radius=0.004,
                                                static=False)
            tau = np.abs(np.asarray(roll["tau"], float))
            tau = tau[np.all(np.isfinite(tau), axis=1)]
            stream.log("episode/torque", rr.BarChart(tau.max(axis=0) if len(tau) else np.zeros(n)))
            K = min(len(roll["tau"]), int(ok[:-1].sum()))
            if K:
                _, var = model.predict(np.hstack([Xe[:K], roll["tau"][:K]]))
                var = var / np.asarray(model.y_std) ** 2
                for j, name in enumerate(joints):
                    stream.log(f"variance/{name}", rr.Scalars(float(np.mean(var[:, j]))))
            if target is None and ee is not None:
                target = _task_target(lookup, e["plan"])
        if target is not None:
            stream.log("world/target", rr.Points3D([target], colors=[(40, 200, 80)], radii=[0.02]), static=True)


def _task_frame(lookup, plan_key: str) -> str | None:
    """The frame of a plan's first 3-D frame-position via-point (a model file's robot has no ``ee``)."""
    doc = lookup("plan", plan_key).document("problem.json")
    for t in doc.get("terms", []):
        m = t.get("map") or {}
        if t.get("term") == "via" and m.get("map") == "frame_points" and len(t.get("target", [])) == 3:
            return m.get("frame")
    return None


def _task_target(lookup, plan_key: str) -> np.ndarray | None:
    """The end-effector via-point target (m) of a plan's task, if its objective has one."""
    doc = lookup("plan", plan_key).document("problem.json")
    for t in doc.get("terms", []):
        if t.get("term") == "via" and len(t.get("target", [])) == 3:
            return np.asarray(t["target"], float)
    return None
