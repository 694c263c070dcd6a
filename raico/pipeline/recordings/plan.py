"""The plan stage's recording (see :mod:`raico.pipeline.recordings` for what every recording shares;
docs/stages.md shows the views).

- ``task/<name>``: one entity per task map, its components named; terms on the same map share it,
  otherwise it is named after its term. ``task/<name>/target``: the via-point targets at their steps;
  a term held over many steps plots ``task/<name>/deviation`` (the largest distance of its points
  from their targets, m). Angles (roll) are unwrapped along time and shifted by a multiple of 2 pi
  so that the first via-point step keeps the wrapped value the cost saw; the MCAP keeps raw values.
- ``cost/total``: the cost per iteration on the ``iteration`` timeline, and
  ``cost/log10_per_iteration``: the same (iteration 0: the initial trajectory) as a static bar
  chart of log10(cost), which every timeline shows: a time series of data on ``iteration`` is
  empty while ``sim_time`` is active (Rerun 0.41 has no per-view timeline, and a visible time range
  on ``iteration`` does not help). The cost views are tabs under the robot: the bar chart first.
- The robot's motion is on ``sim_time`` (decimated, see ``raico.pipeline.recordings.rerun_io``), with the final
  plan's paths as static lines (``world/paths/<map>``, yellow) and the targets as static dots.
- The ``iteration`` timeline shows each iteration's own trajectory, read from the plan's
  ``X_iterations`` (iteration 0: the initial guess rolled out): at iteration ``i`` the robot stands at
  iterate ``i``'s pose at the last via-point step and ``world/iterations/<map>`` holds its paths (every
  one-point task map with via-points in all three coordinates, and ``robot.hands``) beside the static
  final path. A diverged iteration logs nothing; at most ``MAX_ITERATION_FRAMES`` iterations are drawn
  (every s-th one and the last). A plan stored before ``X_iterations`` existed shows its final pose.
- ``joints/<limb>`` and ``control/<limb>``: grouped joint series (``joint_groups``).
- A plan with collision terms: the scene, the robot's collision geometry, the closest-distance
  segments and the smallest distance (:mod:`raico.pipeline.recordings.scene`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from raico.pipeline.recordings import MCAP, RECORDING
from raico.pipeline.recordings import rerun_io as rec_mod
from raico.pipeline.recordings.mcap_io import write_trajectory_mcap
from raico.pipeline.recordings.scene import log_scene, scene_views
from raico.pipeline.recordings.tasks import HELD_STEPS, log_task_paths, log_task_plots, task_plots, task_views

COST_COLOR = (240, 175, 40)


def record_plan(folder: Path, art, inputs: list, lookup=None) -> None:
    """The planned motion, task values against their via-points, controls and cost per iteration
    (see the module docstring)."""
    from raico.planning.objective import objective_from_description
    from raico.plants.robots import robot_for

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
    views = [*task_views(plots), *scene_views(objective), rec_mod.group_views("joints", groups, "joints (rad)"),
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
        log_scene(rec, objective, times, X, sel)
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
    (``cog`` for the centre of gravity), plus the robot's hands (``robot.hands``: the Nao's ``l_gripper`` and
    ``r_gripper``)."""
    from raico.plants.taskmaps import CenterOfMass, FramePoints

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
    for hand in robot.hands:
        if hand not in out:
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
