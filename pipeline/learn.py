"""``raico learn``: the learning loop as a sequence of cached stage runs (SPEC §7, thesis §4).

babble -> for each episode: fit (per the schedule, from the previous fit) -> plan (learned
dynamics, uncertainty term, warm-started from the previous plan) -> execute (Drake's Simulator)
-> the executed data join the next fit. Every run goes through the cache, so a killed ``learn``
resumes where it stopped: finished episodes are cache hits. The loop's own artifact
(``learn/<key>/``: ``episodes.json``, the per-episode lists, and a recording on the ``episode``
timeline) is keyed by its config and code version.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from pipeline import runner
from pipeline.cache import Cache
from pipeline.runner import Outcome, as_artifact, code_version, finite_json, run_stage
from pipeline.ui import Reporter

EPISODES_FILE = "episodes.json"


def _learn_version() -> str:
    return runner.source_version("learn", "pipeline.learn", "stages.learn")


def heldout_set(cache: Cache, heldout: Outcome) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The held-out babbling's ``X (K, n_x)``, ``tau (K, n_q)``, ``qddot (K, n_q)``."""
    from stages.fit.stage import babble_segments

    _, segs = babble_segments(as_artifact(cache.require("babble", heldout.key)))
    XU = np.vstack([s.X for s in segs])
    Y = np.vstack([s.Y for s in segs])
    n = Y.shape[1]
    if len(Y) == 0:
        raise ValueError("the held-out babbling holds no finite point")
    return XU[:, :2 * n], XU[:, 2 * n:], Y


def episode_measurements(cfg, robot, fit: Outcome, plan: Outcome, execution: Outcome, cache: Cache,
                         heldout: tuple | None = None) -> dict:
    """One episode's numbers: GP error on the executed motion (a true prediction: the episode's
    data join only the next fit) and on the fixed held-out babbling, per joint and normalized;
    planned-vs-executed RMSE, task error planned and executed, whether the task was achieved in
    execution, how much of the execution may join the data, wall times, training points."""
    from plants.gp import GPModel
    from stages.fit.stage import usable_steps
    from stages.learn import gp_joint_errors, gp_prediction_error, task_error, true_accelerations

    fit_art = as_artifact(cache.require("fit", fit.key))
    model = GPModel.from_arrays(fit_art.arrays("model.npz"))
    roll = as_artifact(cache.require("execute", execution.key)).arrays("rollout.npz")
    X, tau = roll["X"][:-1], roll["tau"]
    K = min(len(X), len(tau))
    X, tau = X[:K], tau[:K]
    dt = float(roll["times"][1] - roll["times"][0])
    ok = np.all(np.isfinite(X), axis=1)
    qdd = np.full((K, robot.n_q), np.nan)
    if ok.any():
        qdd[ok] = true_accelerations(robot, dt, X[ok], tau[ok])
    em, pm = execution.metrics, plan.metrics
    err = task_error(em.get("via_point_errors") or {})
    if cfg.plant == "pendulum":  # SPEC/issue: within 0.1 rad of upright at the end, on the Drake plant
        q_end = roll["X"][-1, 0]
        err = float(abs((q_end - np.pi + np.pi) % (2 * np.pi) - np.pi)) if np.isfinite(q_end) else float("inf")
    per_joint, per_joint_n = gp_joint_errors(model, X, tau, qdd)
    held = {}
    if heldout is not None:
        hj, hn = gp_joint_errors(model, *heldout)
        held = {"gp_error_heldout": gp_prediction_error(model, *heldout), "gp_error_heldout_joint": hj,
                "gp_nrmse_heldout_joint": hn}
    exec_entry = cache.require("execute", execution.key)
    data_steps = usable_steps(as_artifact(exec_entry), dt, K)
    return {"gp_error": gp_prediction_error(model, X, tau, qdd), "gp_error_joint": per_joint,
            "gp_nrmse_joint": per_joint_n, **held,
            "data_steps": int(data_steps), "data_truncated": bool(data_steps < K),
            "rmse_planned_executed": em.get("rmse_planned_executed"),
            "task_error": err, "achieved": bool(execution.status not in ("diverged", "fell") and err <= ACHIEVED_TOL[cfg.plant == "pendulum"]),
            "execution_status": execution.status, "plan_status": plan.status,
            "planned_task_error": task_error(pm.get("via_point_errors") or {}),
            "fit_time_s": fit.metrics.get("fit_time_s"), "plan_time_s": pm.get("wall_time_s"),
            "execute_time_s": (exec_entry.meta.get("timings") or {}).get("compute_s"),
            "n_points": fit.metrics.get("n_points"), "optimized": fit.metrics.get("optimized"),
            "executed_seconds": float(K * dt), "final_cost": pm.get("final_cost"),
            "fit": fit.key, "plan": plan.key, "execute": execution.key}


# achieved in execution: the largest via-point error <= 5 cm; the pendulum: its final angle within 0.1 rad of upright;
# judged on the final state of a run that neither diverged nor fell (a run that lost tracking of its plan but ends
# at the goal achieved the task; its status says it did not follow the plan)
ACHIEVED_TOL = {False: 0.05, True: 0.1}


def learn_key(cfg) -> tuple[dict, str, str]:
    """(key config, code version, key) of the loop's own artifact."""
    from pipeline.cache import stage_key
    from stages.registry import get_stage

    key_config = cfg.key_dict()
    version = "+".join([_learn_version(), *(code_version(get_stage(s)) for s in ("babble", "fit", "plan",
                                                                               "execute"))])
    return key_config, version, stage_key("learn", version, key_config, [])


def lookup(cache: Cache, cfg, *, record: bool = True) -> Outcome | None:
    """The loop's outcome if it is cached (with its recording, if ``record``), else None."""
    from pipeline.recorders import RECORDING

    _, _, key = learn_key(cfg.resolved())
    entry = cache.lookup("learn", key)
    if entry is None or (record and RECORDING not in cache.derived(entry)):
        return None
    m = entry.meta
    return Outcome(stage="learn", key=key, path=str(entry.path), cached=True, status=m.get("status", "ok"),
                   metrics=m.get("metrics", {}), recording=str(entry.path / RECORDING) if record else None,
                   reason="cached")


def learn(cache: Cache, cfg, *, record: bool = True, reporter: Reporter | None = None,
          progress=None) -> Outcome:
    """Run (or resume) the learning loop of ``cfg`` (``stages.learn.LearnConfig``)."""
    from plants.robots import shared_robot
    from stages.execute import ExecuteConfig
    from stages.learn import BABBLE_DT

    reporter = reporter or Reporter(quiet=True)
    cfg.validate()
    cfg = cfg.resolved()
    robot = shared_robot(cfg.plant)
    key_config, version, _ = learn_key(cfg)

    def compute(tmp: Path) -> dict[str, Any]:
        t0 = time.perf_counter()
        babble = runner.run(cache, "babble", cfg.babble_config(), record=False)
        held_out = heldout_set(cache, runner.run(cache, "babble", cfg.heldout_babble_config(), record=False))
        data, prior, warm = [f"babble/{babble.key}"], None, None
        episodes = []
        for k in range(1, cfg.episodes + 1):
            fit = runner.run(cache, "fit", cfg.fit_config(tuple(data), prior), record=False)
            plan = runner.run(cache, "plan", cfg.plan_config(model=f"fit/{fit.key}", warm_start=warm),
                              record=False)
            execution = runner.run(cache, "execute", ExecuteConfig(plan=f"plan/{plan.key}", seed=cfg.seed),
                                   record=False)
            m = episode_measurements(cfg, robot, fit, plan, execution, cache, held_out)
            episodes.append({"episode": k, **m})
            reporter.say(f"learn episode {k}/{cfg.episodes}: GP error {m['gp_error']:.3g} rad/s^2 "
                         f"(held-out {m['gp_error_heldout']:.3g}), "
                         f"task error {m['task_error']:.3g}, RMSE {m['rmse_planned_executed']:.3g} "
                         f"[{execution.status}] ({'cached' if plan.cached and fit.cached else 'ran'})")
            if progress:
                progress(k, cfg.episodes)
            data.append(f"execute/{execution.key}")
            prior = f"fit/{fit.key}"
            if plan.status != "diverged":
                warm = f"plan/{plan.key}"
        doc = {"babble": babble.key, "episodes": episodes, "config": key_config}
        (tmp / EPISODES_FILE).write_text(__import__("json").dumps(finite_json(doc), indent=2))
        babble_s = float((cfg.babble_points - 1) * BABBLE_DT)
        return {"status": "ok", "metrics": {**summary(episodes, time.perf_counter() - t0), "babble_seconds": babble_s}}

    out = run_stage(cache, "learn", version, key_config, [], compute)
    if record:
        out.recording = _ensure_learn_recording(cache, out, robot)
    return out


def summary(episodes: list[dict], wall: float) -> dict:
    """The ``--json`` metrics: per-episode lists and the first success."""
    keys = ("gp_error", "gp_error_heldout", "gp_nrmse_joint", "gp_nrmse_heldout_joint", "rmse_planned_executed",
            "task_error", "planned_task_error", "achieved", "fit_time_s", "plan_time_s", "execute_time_s",
            "n_points", "optimized", "execution_status", "executed_seconds", "data_steps", "data_truncated")
    out: dict[str, Any] = {k: [e.get(k) for e in episodes] for k in keys}
    out["episodes_feeding_data"] = sum(1 for e in episodes if e.get("data_steps", 0) > 0)
    out["episodes_truncated"] = sum(1 for e in episodes if e.get("data_truncated"))
    first = next((e["episode"] for e in episodes if e["achieved"]), None)
    out["first_success_episode"] = first
    out["episodes"] = len(episodes)
    out["wall_time_s"] = wall
    return out


def _ensure_learn_recording(cache: Cache, out: Outcome, robot) -> str | None:
    from pipeline.recorders import RECORDING

    entry = cache.require("learn", out.key)
    if RECORDING not in cache.derived(entry):
        cache.write_derived(entry, lambda tmp: record_learn(tmp, entry, cache, robot))
    return str(entry.path / RECORDING)


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

    from pipeline import recording as rec_mod

    names = list(LEARN_VIEWS)
    v = {name: rrb.TimeSeriesView(origin=f"/{root}", name=name) for name, root in LEARN_VIEWS.items()
         if root != "episode/torque"}
    bars = rrb.BarChartView(origin="/episode/torque", name=names[5])
    gp = rrb.Tabs(v[names[0]], v[names[1]], name="GP error", active_tab=0)
    other = rrb.Tabs(v[names[4]], v[names[6]], name="data", active_tab=0)
    return rec_mod.stage_blueprint(eye, [gp, v[names[2]], v[names[3]], other], [bars], timeline="episode",
                                   robot_share=2.5, play_state="following")


def record_learn(folder: Path, entry, cache: Cache, robot) -> None:
    """Per episode on the ``episode`` timeline (the file opens on it, at the last episode): the GP
    error per joint on the next execution and on the held-out babbling (log10), the distance to the
    target executed and planned, the time per evaluation (fit, plan, execute), the training points,
    the largest torque per joint and the GP's variance along the execution; in 3D the robot at the
    episode's executed final pose (the last finite state; the plan's final pose if none is finite),
    that episode's planned (blue) and executed (orange) end-effector paths (each episode replaces
    the last) and the target. The camera frames the last episode's planned motion."""
    import json

    import rerun as rr

    from pipeline import recording as rec_mod
    from plants.gp import GPModel
    from plants.taskmaps import EndEffectorPosition

    doc = json.loads((entry.path / EPISODES_FILE).read_text())
    eps = doc["episodes"]
    k = np.array([e["episode"] for e in eps])
    n = robot.n_q
    ee = EndEffectorPosition(robot, "ee") if robot.plant.HasFrameNamed("ee") else None
    last_plan = as_artifact(cache.require("plan", eps[-1]["plan"])).arrays("plan.npz")
    eye = rec_mod.robot_eye(robot, last_plan["X"][:, :n])
    with rec_mod.Recording(folder / "recording.rrd", properties={"stage": "learn", "key": entry.key,
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
        executed = "executed" if doc["config"]["plant"] != "pendulum" else "executed_angle_from_upright_rad"
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
            plan = as_artifact(cache.require("plan", e["plan"])).arrays("plan.npz")
            roll = as_artifact(cache.require("execute", e["execute"])).arrays("rollout.npz")
            model = GPModel.from_arrays(as_artifact(cache.require("fit", e["fit"])).arrays("model.npz"))
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
                target = _task_target(cache, e["plan"])
        if target is not None:
            stream.log("world/target", rr.Points3D([target], colors=[(40, 200, 80)], radii=[0.02]), static=True)


def _task_target(cache: Cache, plan_key: str) -> np.ndarray | None:
    """The end-effector via-point target (m) of a plan's task, if its objective has one."""
    doc = as_artifact(cache.require("plan", plan_key)).document("problem.json")
    for t in doc.get("terms", []):
        if t.get("term") == "via" and len(t.get("target", [])) == 3:
            return np.asarray(t["target"], float)
    return None
