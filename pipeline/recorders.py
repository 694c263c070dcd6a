"""Recordings derived from a stage's stored data: ``recording.rrd`` (Rerun) and ``trajectory.mcap``.

A recorder is ``recorder(folder, artifact, inputs)``: it reads the entry's data files (and
its inputs', e.g. the plan of an execution) and writes the recording files into ``folder``;
the cache moves them beside the data (``Cache.write_derived``). Because recordings are made
from the data, a run first made with ``--no-record`` gets its recording later without
recomputing, and the recording is never part of the data's cache key.

Each stage has its own blueprint (``pipeline.rerun_io.stage_blueprint``): the robot on the
left, the plots that matter on the right, on ``sim_time``, where the file opens; and its own
application id per stage, plant and task (``pipeline.rerun_io.application_id``), since a viewer
shows every recording of one application id in one layout.

Plan recordings:

- ``task/<name>``: one entity per task map, its components named (``x``, ``y``, ``z``; a roll
  angle ``roll (unwrapped)``); terms on the same map share it (the arm's ``via_x1`` and
  ``via_x2`` -> ``task/ee``, the Nao's three CoG via-points -> ``task/cog``), otherwise it is
  named after its term. ``task/<name>/target``: the via-point targets as markers at their steps.
  A term held over many steps (the Nao's right sole) plots ``task/<name>/deviation``: the largest
  distance of its points from their targets (m); ``value`` then holds the first point only.
  Angles (roll) are unwrapped along time and shifted by a multiple of 2 pi so that the first
  via-point step keeps the wrapped value the cost saw; the MCAP keeps the raw values.
- ``cost/total``: the cost per iteration on the ``iteration`` timeline, and
  ``cost/log10_per_iteration``: the same (iteration 0: the initial trajectory) as a static bar
  chart of log10(cost), which every timeline shows: a time series of data on ``iteration`` is
  empty while ``sim_time`` is active (Rerun 0.41 has no per-view timeline, and a visible time range
  on ``iteration`` does not help). The cost views are tabs under the robot: the bar chart first.
- The robot's motion is on ``sim_time`` (decimated, see ``pipeline.rerun_io``), with the final
  plan's paths as static lines (``world/paths/<map>``, yellow) and the targets as static dots.
- The ``iteration`` timeline shows each iteration's own trajectory, read from the plan's
  ``X_iterations`` (every iterate decimated in time to the steps ``t_iterations``; iteration 0 is
  the initial guess rolled out): at iteration ``i`` the robot stands at iterate ``i``'s pose at the
  last via-point step (the final step if there is none) and ``world/iterations/<map>`` holds its
  paths as LineStrips3D on ``iteration``: every one-point task map with via-points in all three
  coordinates (the arm's and the pendulum's end effector ``ee``, the Nao's ``cog``), plus the
  hands ``l_gripper`` and ``r_gripper`` of a robot that has them (the Nao). The static final path
  stays visible beside it, so an iterate is seen against the plan. An iteration that diverged
  (a NaN row) logs nothing: the last finite iterate stays on screen; at most
  ``MAX_ITERATION_FRAMES`` iterations are drawn (every s-th one and the last). Nothing of this is
  on ``sim_time``. A plan stored before ``X_iterations`` existed shows its final pose on
  ``iteration`` instead.
- ``joints/<limb>`` and ``control/<limb>``: grouped joint series (``joint_groups``).

Execute recordings plot ``task/<name>/value`` (executed) against ``task/<name>/planned`` and the
targets in one view per task map, the tracking error, the joints and torques by limb, the
status and the events; babble and fit recordings follow the same layout. Learn recordings
(``pipeline/recorder_learn.py``) plot the loop's quantities per episode on ``episode``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline import rerun_io as rec_mod
from pipeline.mcap_io import write_trajectory_mcap
from pipeline.recorder_fit import record_fit
from pipeline.recorder_learn import record_learn
from planning.term_kinds import default_labels, kind_named

RECORDING = "recording.rrd"
MCAP = "trajectory.mcap"
XYZ_COLORS = {"x": (235, 90, 80), "y": (95, 195, 95), "z": (80, 145, 245)}
ANGLE_COLOR = (240, 175, 40)
COST_COLOR = (240, 175, 40)


def _input(inputs: list, stage: str):
    return next(a for a in inputs if a.stage == stage)


def _episode_times(t: np.ndarray, episodes: int, gap: float) -> np.ndarray:
    """Episodes laid end to end on one ``sim_time`` axis: ``(episodes * K,)`` s."""
    span = t[-1] + gap
    return (np.arange(episodes)[:, None] * span + t[None, :]).reshape(-1)


def record_babble(folder: Path, art, inputs: list) -> None:
    """Every babbling episode laid end to end on ``sim_time``: robot (at most ``MAX_POSES`` poses
    per episode), joints, desired joints and torques by limb."""
    from plants.model_file import robot_for
    from stages.babble import robot_description

    cfg = art.config
    data = art.arrays("data.npz")
    robot = robot_for(robot_description(cfg), true=True)
    q, qdot, u, t = data["q"], data["qdot"], data["u"], data["t"]
    E, K, n = q.shape
    times = _episode_times(t, E, gap=t[1] - t[0])
    Q = q.reshape(-1, n)
    poses = (np.arange(E)[:, None] * K + rec_mod.pose_indices(K, rec_mod.n_bodies(robot))[None, :]).reshape(-1)
    sel = rec_mod.plot_indices(E * K)
    groups = rec_mod.joint_groups(robot.joint_names)
    eye = rec_mod.robot_eye(robot, Q[poses])
    plots = [rec_mod.group_views(r, groups, title) for r, title in
             (("joints", "joints (rad)"), ("desired", "desired joints (rad)"), ("torque", "torque (N m)"))]
    blueprint = rec_mod.stage_blueprint(eye, plots)
    with rec_mod.Recording(folder / RECORDING, rec_mod.application_id("babble", cfg["plant"]),
                           properties={"stage": "babble", "key": art.key, **cfg},
                           name=f"babble {cfg['plant']}", blueprint=blueprint) as rec:
        rec_mod.log_robot_geometry(rec, robot)
        rec_mod.log_body_trajectory(rec, robot, times, Q, poses=poses)
        rec_mod.log_joint_series(rec, robot.joint_names, times[sel], data["q_des"].reshape(-1, n)[sel],
                                 root="desired", continuous=rec_mod.continuous_joints(robot))
        rec_mod.log_joint_series(rec, robot.joint_names, times[sel], u.reshape(-1, n)[sel], root="torque")
        rec_mod.log_scalars(rec, "episode_index", "sim_time", times[sel], np.repeat(np.arange(E), K)[sel])
    write_trajectory_mcap(folder / MCAP, robot, times, Q, qdot.reshape(-1, n), u.reshape(-1, n))


def record_plan(folder: Path, art, inputs: list) -> None:
    """The planned motion, task values against their via-points, controls and cost per iteration
    (see the module docstring)."""
    from planning.objective import objective_from_description
    from plants.model_file import robot_for

    cfg = art.config
    d = art.arrays("plan.npz")
    desc = art.document("problem.json")
    robot = robot_for(desc)
    objective = objective_from_description(desc, robot)
    n, times, costs = robot.n_q, d["times"], d["costs"]
    X = d["X"] if np.all(np.isfinite(d["X"])) else np.nan_to_num(d["X"], nan=0.0, posinf=0.0, neginf=0.0)
    U = d["U"]
    plots = task_plots(objective, X, robot.joint_names)
    vias = sorted({s for tp in plots for s, _ in tp.targets})
    eye = rec_mod.robot_eye(robot, X[:, :n])
    groups = rec_mod.joint_groups(robot.joint_names)
    views = [*task_views(plots), rec_mod.group_views("joints", groups, "joints (rad)"),
             rec_mod.group_views("control", groups, "control (" + _control_unit(desc) + ")")]
    blueprint = rec_mod.stage_blueprint(eye, views, [cost_views()])
    metrics = art.metrics or {}
    with rec_mod.Recording(folder / RECORDING, rec_mod.application_id("plan", cfg["plant"], cfg["task"]),
                           properties={"stage": "plan", "key": art.key, **cfg},
                           name=f"plan {cfg['plant']} {cfg['task']} {cfg['solver']}", blueprint=blueprint) as rec:
        rec_mod.log_robot_geometry(rec, robot)
        rec_mod.log_body_trajectory(rec, robot, times, X[:, :n], keep=vias)
        if d.get("X_iterations") is not None and np.ndim(d["X_iterations"]) == 3 and len(d["X_iterations"]):
            log_iterations(rec, robot, objective, d["X_iterations"], d["t_iterations"],
                           vias[-1] if vias else len(times) - 1, d["q0"])
        else:  # a plan stored before X_iterations: its final pose
            rec_mod.log_robot_pose(rec, robot, X[-1, :n], "iteration", 0)
        log_costs(rec, costs, metrics.get("initial_cost"))
        sel = rec_mod.plot_indices(len(times), vias)
        log_task_plots(rec, plots, times, sel)
        log_task_paths(rec, objective, X, plots)
        sel_u = rec_mod.plot_indices(len(U), vias)
        rec_mod.log_joint_series(rec, robot.joint_names, times[:-1][sel_u], U[sel_u], root="control")
    values = {term: tp.raw for tp in plots for term in tp.terms}
    write_trajectory_mcap(folder / MCAP, robot, times, X[:, :n], X[:, n:],
                          np.vstack([U, np.full((1, n), np.nan)]), task_values=values)


MAX_ITERATION_FRAMES = 200  # iterations drawn on the ``iteration`` timeline (every s-th one and the last)
ITERATION_COLORS = ((230, 60, 210), (40, 190, 230), (140, 100, 250), (60, 200, 120))


def iteration_path_maps(robot, objective) -> dict:
    """``{name: task map}`` of the 3-D paths drawn per iteration: every one-point task map with
    via-points (a term active at no more than ``HELD_STEPS`` steps), in all three coordinates
    even where the cost uses fewer (the pendulum's ``ee_xz`` -> ``ee``), named after its frame
    (``cog`` for the centre of gravity), plus the hands ``l_gripper``/``r_gripper`` of a robot that
    has them (the Nao)."""
    from plants.taskmaps import CenterOfMass, FramePoints

    out: dict = {}
    for term in objective.state_terms:
        tm, times = getattr(term, "taskmap", None), getattr(term, "times", None)
        if tm is None or times is None or not 0 < len(times) <= HELD_STEPS:
            continue
        if isinstance(tm, CenterOfMass):
            out.setdefault("cog", CenterOfMass(robot))
        elif isinstance(tm, FramePoints) and len(tm.points) == 1:
            name = rec_mod.entity_name(tm.frame.name())
            if name not in out:
                out[name] = FramePoints(robot, tm.frame.name(), points=tm.points)
    for hand in ("l_gripper", "r_gripper"):
        if hand not in out and robot.plant.HasFrameNamed(hand):
            out[hand] = FramePoints(robot, hand)
    return out


def log_iterations(rec, robot, objective, X_iterations: np.ndarray, steps: np.ndarray, pose_step: int,
                   q0: np.ndarray | None = None) -> None:
    """Each iteration's trajectory on the ``iteration`` timeline (see the module docstring):
    ``X_iterations (iterations + 1, K, n_x)`` at the steps ``steps (K,)``; the robot at the kept
    step ``pose_step`` (or the last kept step before it) and the paths of :func:`iteration_path_maps`
    as ``world/iterations/<name>``. Rows that are not finite log nothing (iteration 0 then shows
    the robot at ``q0``)."""
    Xi = np.asarray(X_iterations, dtype=float)
    steps = np.asarray(steps, dtype=np.int64)
    n = robot.n_q
    its = rec_mod.decimate(len(Xi), MAX_ITERATION_FRAMES)
    Q = Xi[its][:, :, :n]  # (N, K, n_q)
    k = max(int(np.searchsorted(steps, pose_step, side="right")) - 1, 0)
    good = np.all(np.isfinite(Q[:, k]), axis=1)
    poses, at = Q[good, k], its[good]
    if not good[0] and q0 is not None:  # iteration 0 not finite: the robot at its start
        poses, at = np.vstack([np.asarray(q0, float)[None], poses]), np.r_[0, at]
    if len(at):
        rec_mod.log_robot_pose(rec, robot, poses, "iteration", at)
    flat = Q.reshape(-1, n)
    ok = np.all(np.isfinite(flat), axis=1)
    for j, (name, tm) in enumerate(iteration_path_maps(robot, objective).items()):
        P_flat = np.full((len(flat), 3), np.nan)
        if ok.any():
            P_flat[ok] = np.asarray(tm.values_and_jacobians(flat[ok])[0], float).reshape(-1, 3)
        P = P_flat.reshape(len(its), len(steps), 3)
        drawn = np.all(np.isfinite(P), axis=2).sum(axis=1) >= 2
        if drawn.any():
            rec_mod.log_path_series(rec, f"world/iterations/{name}", "iteration", its[drawn], P[drawn],
                                    color=ITERATION_COLORS[j % len(ITERATION_COLORS)], radius=0.004)


def _control_unit(desc: dict) -> str:
    return "rad/s^2" if desc.get("control_kind") == "acceleration" else "N m"


def cost_views():
    """Tabs under the robot: the static bar chart of log10(cost) per iteration (every timeline shows
    it) and the cost on the ``iteration`` timeline."""
    import rerun.blueprint as rrb

    return rrb.Tabs(
        rrb.BarChartView(origin="/cost", contents="/cost/log10_per_iteration", name="log10 cost per iteration",
                         plot_legend=rrb.PlotLegend(visible=False)),
        rrb.TimeSeriesView(origin="/cost", contents="/cost/total", name="cost (iteration timeline)"),
        name="cost", active_tab=0)


def log_costs(rec, costs: np.ndarray, initial: float | None = None) -> None:
    """``cost/total`` on ``iteration`` (1, 2, ...) and ``cost/log10_per_iteration``, a static bar
    chart of log10(cost) against the iteration (0: ``initial``, the initial trajectory's cost, if
    known); non-finite costs get no bar."""
    import rerun as rr

    costs = np.asarray(costs, dtype=float)
    its = np.arange(1, costs.size + 1)
    if costs.size:
        rec_mod.log_scalars(rec, "cost/total", "iteration", its, costs, names=["cost"], colors=[COST_COLOR])
    if initial is not None and np.isfinite(initial):
        its, costs = np.r_[0, its], np.r_[float(initial), costs]
    with np.errstate(all="ignore"):
        bars = np.log10(costs)
    good = np.isfinite(bars)
    if good.any():
        rec.rec.log("cost/log10_per_iteration", rr.BarChart(bars[good], abscissa=its[good].astype(float),
                                                           color=COST_COLOR), static=True)


def record_execute(folder: Path, art, inputs: list) -> None:
    """The executed motion against the plan; torques, tracking error, the status (a text entry,
    and a log entry at the moment of failure on ``sim_time``) and, for the free-standing Nao, the
    robot in the world, its contact points, the contact-based support polygon and the CoG's ground
    projection."""
    from planning.objective import objective_from_description
    from plants.model_file import robot_for

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
                           blueprint=_execute_blueprint(plots, robot.joint_names, eye, free)) as rec:
        sel = rec_mod.plot_indices(len(times), vias)
        if free:  # the free-standing Nao: its own plant (floating base, floor) and stored positions
            from plants.free_nao import shared_free_nao

            nao = shared_free_nao()
            poses = rec_mod.pose_indices(len(times), rec_mod.n_bodies(nao), vias)
            rec_mod.log_robot_geometry(rec, nao)
            rec_mod.log_body_trajectory(rec, nao, times, _hold_last_finite(d["q_free"]), joints=False, poses=poses)
            rec_mod.log_joint_series(rec, robot.joint_names, times[sel], X[sel, :n],
                                     continuous=rec_mod.continuous_joints(robot))
        else:
            rec_mod.log_robot_geometry(rec, robot)
            rec_mod.log_body_trajectory(rec, robot, times, X[:, :n], keep=vias)
        log_task_plots(rec, plots, times, sel)
        log_task_plots(rec, planned, times, sel, series="planned", targets=False)
        if not free:  # the free Nao stands elsewhere in its world than the fixed model the tasks are in
            log_task_paths(rec, objective, X, plots)
            log_task_paths(rec, objective, X_plan, planned, label="planned")
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
        _log_status(rec, art, times)
    values = {term: tp.raw for tp in plots for term in tp.terms}
    write_trajectory_mcap(folder / MCAP, robot, times, X[:, :n], X[:, n:],
                          np.vstack([tau, np.full((len(times) - len(tau), n), np.nan)]), task_values=values)


def _execute_blueprint(plots: list, joint_names, eye, free: bool):
    """The robot above the status text and the event log; on the right the task views (executed
    against planned), the tracking error (and the CoG's margin for the free Nao), joints and torques
    by limb."""
    import rerun.blueprint as rrb

    groups = rec_mod.joint_groups(joint_names)
    error = rrb.TimeSeriesView(origin="/error", name="tracking error (rad)")
    views = [*task_views(plots, planned=True), error,
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


HELD_STEPS = 3  # a term active at more steps is "held": its plot is the deviation, not the targets


@dataclass
class TaskPlot:
    """What is plotted of one task map: at ``task/<entity>``, ``values (K, d)`` named ``names`` (the
    map's plotted components; ``raw (K, dim)``: every component, as the cost sees them), the
    ``targets`` ``[(step, (d,))]`` of its via-point terms, and for terms held over many steps the
    ``deviation (K,)`` (largest distance of a point from its target). ``unit``: m or rad."""

    entity: str
    terms: list[str]
    raw: np.ndarray
    values: np.ndarray
    names: list[str]
    unit: str
    colors: list | None = None
    targets: list[tuple[int, np.ndarray]] = field(default_factory=list)
    deviation: np.ndarray | None = None


def _map_components(m: dict | None, dim: int, name: str, joint_names) -> tuple[list[str], int, str, bool]:
    """(component names, coordinates per point, unit, angle?) of a task-map description: its row's
    labels in the task-map table (``planning.term_kinds``)."""
    row = kind_named((m or {}).get("map"))
    return (row.labels if row is not None else default_labels)(m, dim, name, joint_names)


def task_plots(problem, X: np.ndarray, joint_names=()) -> list[TaskPlot]:
    """The via-point terms of ``problem`` grouped by task map (terms on the same map share a plot,
    named after the map; a map of one term is named after the term), evaluated along ``X``.
    Nothing if ``X`` is not finite."""
    if not np.all(np.isfinite(X)):
        return []
    n_q, K = X.shape[1] // 2, X.shape[0]
    descs = {d["name"]: d for d in getattr(problem, "descriptions", []) if d.get("term") == "via"}
    groups: dict[str, tuple[dict | None, list]] = {}
    for term in problem.state_terms:
        if hasattr(term, "taskmap") and hasattr(term, "target"):   # via-points (not the balance's inequalities)
            m = descs.get(term.name, {}).get("map")
            key = json.dumps(m, sort_keys=True) if m else f"term:{term.name}"
            groups.setdefault(key, (m, []))[1].append(term)
    out = []
    for m, terms in groups.values():
        name = terms[0].name if len(terms) == 1 else (m or {}).get("name", terms[0].name)
        raw, _ = terms[0].taskmap.values_and_jacobians(X[:, :n_q])
        raw = np.asarray(raw, dtype=float).reshape(K, -1)
        names, per_point, unit, angle = _map_components(m, raw.shape[1], name, list(joint_names))
        targets, deviation = [], None
        for term in terms:
            steps = np.flatnonzero(term.active(np.arange(K)))
            if steps.size <= HELD_STEPS:
                targets += [(int(s), term.target[:len(names)]) for s in steps]
            else:
                diff = (raw - term.target).reshape(K, -1, per_point)
                dev = np.linalg.norm(diff, axis=2).max(axis=1)
                deviation = dev if deviation is None else np.maximum(deviation, dev)
        targets.sort(key=lambda st: st[0])
        values = raw[:, :len(names)].copy()
        if angle:
            ref = targets[0][0] if targets else 0
            values = np.column_stack([rec_mod.unwrap(values[:, i], ref) for i in range(values.shape[1])])
        colors = [XYZ_COLORS[c] for c in names] if all(c in XYZ_COLORS for c in names) else \
            [ANGLE_COLOR] if angle else None
        out.append(TaskPlot(rec_mod.entity_name(name), [t.name for t in terms], raw, values, names, unit, colors,
                            targets, deviation))
    return out


def _faded(colors: list | None) -> list | None:
    return None if colors is None else [tuple(int(0.45 * c + 0.55 * 150) for c in rgb) for rgb in colors]


def log_task_plots(rec, plots: list[TaskPlot], times: np.ndarray, sel: np.ndarray | None = None,
                   root: str = "task", series: str = "value", targets: bool = True) -> None:
    """``root/<entity>/<series>`` (at the samples ``sel``), ``.../target`` markers at the via-point
    steps and ``.../deviation`` (``deviation_<series>`` unless ``series`` is ``value``) for the
    plots of :func:`task_plots`. The ``planned`` series is drawn paler and thinner."""
    sel = np.arange(len(times)) if sel is None else sel
    plain = series == "value"
    for tp in plots:
        base = f"{root}/{tp.entity}"
        suffix = "" if plain else f" ({series})"
        rec_mod.log_scalars(rec, f"{base}/{series}", "sim_time", times[sel], tp.values[sel],
                            names=[n + suffix for n in tp.names], colors=tp.colors if plain else _faded(tp.colors),
                            widths=None if plain else 1.0)
        if targets and tp.targets:
            steps = np.array([s for s, _ in tp.targets])
            rec_mod.log_scalars(rec, f"{base}/target", "sim_time", times[steps],
                                np.array([t for _, t in tp.targets]), names=[n + "*" for n in tp.names],
                                colors=tp.colors, points=True)
        if tp.deviation is not None:
            rec_mod.log_scalars(rec, f"{base}/deviation" + ("" if plain else f"_{series}"), "sim_time", times[sel],
                                tp.deviation[sel], names=[f"deviation from target{suffix} ({tp.unit})"],
                                colors=None if plain else [(150, 150, 150)], widths=None if plain else 1.0)


def task_views(plots: list[TaskPlot], root: str = "task", planned: bool = False) -> list:
    """One time series view per task map: values and targets, or the deviation of a held term
    (``planned``: also the planned series)."""
    import rerun.blueprint as rrb

    views = []
    for tp in plots:
        base = f"/{root}/{tp.entity}"
        if tp.deviation is not None and not tp.targets:
            contents = [f"{base}/deviation", *([f"{base}/deviation_planned"] if planned else [])]
            title = f"{tp.entity}: deviation ({tp.unit})"
        else:
            contents = [f"{base}/value", f"{base}/target", *([f"{base}/planned"] if planned else [])]
            title = f"{tp.entity} ({tp.unit})" if tp.unit else tp.entity
        views.append(rrb.TimeSeriesView(origin=base, contents=contents, name=title))
    return views


def log_task_paths(rec, problem, X: np.ndarray, plots: list[TaskPlot] | None = None, label: str = "") -> None:
    """3-D task maps of one point with via-points (CoG, end effector): the path as a static line in
    the 3D view (``world/paths/<map>``; with a ``label`` ``world/paths/<map>_<label>``, pale blue),
    the targets as dots (``world/targets/<map>``)."""
    for tp in task_plots(problem, X) if plots is None else plots:
        if tp.raw.shape[1] != 3 or not tp.targets:
            continue
        name = f"{tp.entity}_{label}" if label else tp.entity
        rec_mod.log_points_path(rec, f"world/paths/{name}", tp.raw, color=(140, 180, 240) if label else (250, 200, 30),
                                radius=0.003)
        if not label:
            rec_mod.log_points_path(rec, f"world/targets/{tp.entity}", np.array([t for _, t in tp.targets]),
                                    color=(230, 40, 40), radius=0.012, line=False)
    _log_placement_paths(rec, problem, X, label)


def _log_placement_paths(rec, problem, X: np.ndarray, label: str = "") -> None:
    """Frames with a placement target (crocoddyl's frame-placement residual): the frame origin's path
    (``world/paths/<frame>``) and the target positions (``world/targets/<frame>``), as for points."""
    from plants.taskmaps import FramePlacementError, FramePoints

    if not np.all(np.isfinite(X)):
        return
    targets: dict[str, tuple] = {}
    for term in problem.state_terms:
        m = getattr(term, "taskmap", None)
        if isinstance(m, FramePlacementError):
            entry = targets.setdefault(m.frame.name(), (m, []))
            entry[1].append(m.p_target)
    n_q = X.shape[1] // 2
    for frame, (m, points) in targets.items():
        path = FramePoints(m.robot, frame).values_and_jacobians(X[:, :n_q])[0]
        name = rec_mod.entity_name(frame)
        rec_mod.log_points_path(rec, f"world/paths/{name}_{label}" if label else f"world/paths/{name}", path,
                                color=(140, 180, 240) if label else (250, 200, 30), radius=0.003)
        if not label:
            rec_mod.log_points_path(rec, f"world/targets/{name}", np.unique(np.array(points), axis=0),
                                    color=(230, 40, 40), radius=0.012, line=False)


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


RECORDERS = {"babble": record_babble, "plan": record_plan, "execute": record_execute, "fit": record_fit,
             "learn": record_learn}
