"""``raico compare``: up to nine runs in one Rerun recording, on one timeline, side by side.

Rerun's viewer cannot align separate recordings on one time axis, so raico writes one: each run (a
plan, or an execution) under its own entity path named by the options that differ between the runs
(``runs/<label>``, e.g. ``runs/alpha=0.5, solver=raico``), its motion on ``sim_time`` from 0, and a
generated blueprint: a grid of 3D views, one per run (its robot and its task-space path in the run's
colour), beside overlaid time series, one view per joint with every run's angle in its colour, and a
tab with every run's log10 cost per iteration (on the ``iteration`` timeline: Rerun 0.41 plots a view
against the active timeline only, so that tab shows its lines once ``iteration`` is selected in the
time panel; the robots then stand at their final poses).

Entity layout, for each run::

    runs/<label>/world/robot/<body>[/<geometry>]   the robot (static geometry, poses on sim_time)
    runs/<label>/world/paths/<map>                 the run's task-space path (static, its colour)
    runs/<label>/world/targets/<map>               the via-point targets (static, red)
    runs/<label>/joints/<joint>                    the joint angle on sim_time (rad), series named <label>
    runs/<label>/cost                              log10 of the cost on iteration, series named <label>
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from raico.pipeline.errors import BadInput, check_folder

MAX_RUNS = 9
STAGES = ("plan", "execute")   # what can be compared: stages with a trajectory
# one colour per run (Tableau 10 without its grey), RGB
RUN_COLORS = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
              (227, 119, 194), (188, 189, 34), (23, 190, 207))


@dataclass
class Run:
    """One run to compare: its entry, the options it used (a plan's config; an execution's plan config
    beside its own as ``execute.option``) and its label (the options that differ)."""

    entry: Any
    options: dict[str, Any]
    label: str = ""

    @property
    def ref(self) -> str:
        return f"{self.entry.stage}/{self.entry.key}"


def _config(entry) -> dict[str, Any]:
    return dict((entry.meta or {}).get("config") or {})


def load_runs(cache, refs: list[str]) -> list[Run]:
    """The runs of ``refs`` (``KEY``, a key prefix or ``STAGE/KEY`` of plans or executions), each once, in
    order; :class:`BadInput` on more than :data:`MAX_RUNS`, an unknown key or a stage without a trajectory."""
    from raico.pipeline.engine.runner import find_entry
    from raico.stages.registry import get_stage

    if not refs:
        raise BadInput("give the runs to compare: KEY... or --exp NAME [--where ...]")
    refs = list(dict.fromkeys(refs))
    if len(refs) > MAX_RUNS:
        raise BadInput(f"{len(refs)} runs: raico compare shows at most {MAX_RUNS} in one recording "
                       "(give fewer keys, or narrow --exp with --where)")
    runs, seen = [], set()
    for ref in refs:
        entry = find_entry(cache, ref, stage=STAGES)
        if (entry.stage, entry.key) in seen:
            continue
        seen.add((entry.stage, entry.key))
        options = _config(entry)
        if entry.stage == "execute":
            inputs = set(get_stage("execute").config_cls.INPUTS)
            plan = find_entry(cache, (entry.meta.get("inputs") or [""])[0], stage="plan")
            options = {**_config(plan), **{f"execute.{k}": v for k, v in options.items() if k not in inputs}}
        runs.append(Run(entry, options))
    return runs


def runs_of_experiment(cache, name: str, where: str | None, stage: str | None = None) -> list[str]:
    """The keys (``STAGE/KEY``) of an experiment's runs that match ``where``: the first stage's, or
    ``stage``'s; :class:`BadInput` if the stage has no runs in the table or more than :data:`MAX_RUNS` match."""
    from raico.pipeline.experiments import expfile

    df, _ = expfile.read_table(cache, name)
    df = expfile.query(df, where)
    cols = expfile.key_columns(df)
    col = f"{stage}.key" if stage else next((c for c in cols if c[:-4] in STAGES), None)
    if col is None or col not in df.columns or col[:-4] not in STAGES:
        raise BadInput(f"--stage {stage}: the table of '{name}' has no {stage} runs (stages with a trajectory: "
                       f"{', '.join(c[:-4] for c in cols if c[:-4] in STAGES) or 'none'})")
    keys = [k for k in df[col] if isinstance(k, str)]
    if not keys:
        raise BadInput(f"no {col[:-4]} run of '{name}' matches" + (f" --where '{where}'" if where else ""))
    if len(keys) > MAX_RUNS:
        raise BadInput(f"{len(keys)} runs of '{name}' match: raico compare shows at most {MAX_RUNS} in one recording "
                       "(narrow them with --where, e.g. \"seed == 0\")")
    return [f"{col[:-4]}/{k}" for k in keys]


def label_runs(runs: list[Run]) -> None:
    """Each run's label: the options whose values differ between the runs (``option=value``, those
    a run does not use left out: iLQG's alpha), or its stage and key when every option is the same."""
    from raico.pipeline.experiments.expfile import unused_in
    from raico.pipeline.experiments.plots import option_text

    names = list(dict.fromkeys(k for r in runs for k in r.options))
    values = {k: {_hashable(r.options.get(k)) for r in runs} for k in names}
    differ = [k for k in names if len(values[k]) > 1]
    labels = []
    for r in runs:
        first = {k: v for k, v in r.options.items() if not k.startswith("execute.")}
        skip = unused_in("plan", first, differ, values) if differ else set()
        parts = [f"{k}={option_text(r.options.get(k))}" for k in differ if k not in skip]
        labels.append(", ".join(parts))
    if len(set(labels)) < len(labels) or not all(labels):   # leaving out unused options made two alike
        labels = [", ".join(f"{k}={option_text(r.options.get(k))}" for k in differ) for r in runs]
    if len(set(labels)) < len(labels) or not all(labels):   # the same options: the keys tell them apart
        labels = [f"{r.entry.stage} {r.entry.key[:8]}" for r in runs]
    for r, lab in zip(runs, labels):
        r.label = lab


def _hashable(v: Any) -> Any:
    return tuple(v) if isinstance(v, list) else v


def label_path(label: str) -> str:
    import rerun as rr

    return f"runs/{rr.escape_entity_path_part(label)}"


def _trajectory(cache, run: Run) -> dict[str, Any]:
    """What is drawn of a run: plant, times (s), Q (rad), the objective, the cost per iteration."""
    from raico.pipeline.engine.artifacts import as_artifact
    from raico.pipeline.engine.runner import find_entry

    art = as_artifact(run.entry)
    if run.entry.stage == "plan":
        d = art.arrays("plan.npz", ("times", "X", "costs"))
        desc = art.document("problem.json")
        costs = d["costs"]
    else:
        plan = as_artifact(find_entry(cache, art.inputs[0], stage="plan"))
        d = art.arrays("rollout.npz", ("times", "X"))
        desc = plan.document("problem.json")
        costs = plan.arrays("plan.npz", ("costs",))["costs"]
    return {"plant": desc["plant"], "desc": desc, "times": np.asarray(d["times"], float),
            "X": np.asarray(d["X"], float), "costs": np.asarray(costs, float)}


def write(cache, runs: list[Run], path: Path) -> Path:
    """The recording of ``runs`` (labelled by :func:`label_runs`) at ``path``, with its blueprint."""
    import rerun as rr
    import rerun.blueprint as rrb

    from raico.pipeline.recordings import rerun_io as rec_mod
    from raico.pipeline.recordings.tasks import task_plots
    from raico.planning.objective import objective_from_description
    from raico.plants.robots import robot_for

    data = [_trajectory(cache, r) for r in runs]
    joints_of: dict[str, list[str]] = {}
    views3d, digest = [], hashlib.sha256("".join(r.ref for r in runs).encode()).hexdigest()[:12]
    for r, d, color in zip(runs, data, RUN_COLORS):
        robot = robot_for(d["desc"])  # a built-in plant by name, a model file's robot by its spec
        n = robot.n_q
        X = np.nan_to_num(d["X"], nan=0.0, posinf=0.0, neginf=0.0)
        d.update(robot=robot, Q=X[:, :n], objective=objective_from_description(d["desc"], robot), color=color)
        d["plots"] = task_plots(d["objective"], X, robot.joint_names)
        eye = rec_mod.robot_eye(robot, d["Q"])
        controls = rrb.EyeControls3D(position=list(map(float, eye[0])), look_target=list(map(float, eye[1])),
                                     eye_up=[0.0, 0.0, 1.0])
        base = label_path(r.label)
        views3d.append(rrb.Spatial3DView(origin=f"/{base}/world", contents=f"/{base}/world/**", name=r.label,
                                         eye_controls=controls))
        for joint in robot.joint_names:
            joints_of.setdefault(joint, []).append(f"/{base}/joints/{rec_mod.entity_name(joint)}")
    # no legends over the angles (nine entries would hide them): a run's colour is its path's in its 3D view,
    # and hovering a line names it; the cost tab keeps its legend
    joint_views = [rrb.TimeSeriesView(origin="/runs", contents=paths, name=f"{j} (rad)",
                                      plot_legend=rrb.PlotLegend(visible=False)) for j, paths in joints_of.items()]
    angles = rrb.Vertical(*joint_views, name="joint angles (sim_time)") if len(joint_views) <= 6 else \
        rrb.Tabs(*joint_views, name="joint angles (sim_time)", active_tab=0)
    cost = rrb.TimeSeriesView(origin="/runs", contents=[f"/{label_path(r.label)}/cost" for r in runs],
                              name="log10 cost per iteration (iteration timeline)")
    columns = math.ceil(math.sqrt(len(runs)))
    blueprint = rrb.Blueprint(
        rrb.Horizontal(rrb.Grid(*views3d, grid_columns=columns), rrb.Tabs(angles, cost, active_tab=0, name="plots"),
                       column_shares=[3, 2]),
        rrb.TimePanel(state="collapsed", timeline="sim_time", play_state="paused"), collapse_panels=True)
    props = {"stage": "compare", "runs": {r.label: r.ref for r in runs}}
    with rec_mod.Recording(path, rec_mod.application_id("compare", digest), props,
                           name=f"compare {len(runs)} runs", blueprint=blueprint) as rec:
        for r, d in zip(runs, data):
            base, robot, color = label_path(r.label), d["robot"], d["color"]
            times, Q = d["times"], d["Q"]
            rec.rec.log(f"{base}/world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
            vias = sorted({s for tp in d["plots"] for s, _ in tp.targets})
            rec_mod.log_robot_geometry(rec, robot, prefix=f"{base}/world/robot")
            rec_mod.log_body_trajectory(rec, robot, times, Q, prefix=f"{base}/world/robot", joints=False, keep=vias)
            rec_mod.log_robot_pose(rec, robot, Q[-1], "iteration", 0, prefix=f"{base}/world/robot")
            sel = rec_mod.plot_indices(len(times), vias)
            wraps = rec_mod.continuous_joints(robot)
            for j, name in enumerate(robot.joint_names):
                q = rec_mod.unwrap(Q[:, j]) if wraps[j] else Q[:, j]
                rec_mod.log_scalars(rec, f"{base}/joints/{rec_mod.entity_name(name)}", "sim_time", times[sel], q[sel],
                                    names=[r.label], colors=[color])
            c = d["costs"]
            ok = np.isfinite(c) & (c > 0)
            if ok.any():
                rec_mod.log_scalars(rec, f"{base}/cost", "iteration", np.arange(1, c.size + 1)[ok], np.log10(c[ok]),
                                    names=[r.label], colors=[color])
            for tp in d["plots"]:
                if tp.raw.shape[1] == 3 and tp.targets:
                    rec_mod.log_points_path(rec, f"{base}/world/paths/{tp.entity}", tp.raw, color=color, radius=0.004)
                    rec_mod.log_points_path(rec, f"{base}/world/targets/{tp.entity}",
                                            np.array([t for _, t in tp.targets]), color=(230, 40, 40), radius=0.012,
                                            line=False)
    return path


def default_path(cache, runs: list[Run]) -> Path:
    """``artifacts/compare/<12 hex of the runs' keys>.rrd``: the same runs, the same file."""
    digest = hashlib.sha256("\n".join(r.ref for r in runs).encode()).hexdigest()[:12]
    return cache.root / "compare" / f"{digest}.rrd"


def compare(cache, keys: list[str], exp: str | None = None, where: str | None = None, stage: str | None = None,
            out: Path | None = None) -> tuple[Path, list[Run]]:
    """``raico compare``: the recording of the runs ``keys`` (or those of experiment ``exp`` that ``where``
    keeps, of ``stage``) at ``out`` (default :func:`default_path`), and the runs with their labels;
    :class:`BadInput` on bad input."""
    if exp is None and (where is not None or stage is not None):
        raise BadInput("--where and --stage go with --exp NAME")
    if exp is not None and keys:
        raise BadInput("give keys or --exp NAME, not both")
    if stage is not None and stage not in STAGES:
        raise BadInput(f"--stage {stage}: choose one of {', '.join(STAGES)}")
    if out is not None and Path(out).suffix != ".rrd":
        raise BadInput(f"--out {out}: a .rrd file")
    refs = runs_of_experiment(cache, exp, where, stage) if exp is not None else list(keys or [])
    runs = load_runs(cache, refs)
    label_runs(runs)
    out = Path(out) if out is not None else default_path(cache, runs)
    check_folder(out.parent, "output folder")
    return write(cache, runs, out), runs
