"""Task-map plots shared by the plan and execute recordings: one view per task map, its values
against its via-point targets, and the task paths in 3D."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from raico.pipeline.recordings import rerun_io as rec_mod
from raico.planning.term_kinds import default_labels, kind_named

XYZ_COLORS = {"x": (235, 90, 80), "y": (95, 195, 95), "z": (80, 145, 245)}
ANGLE_COLOR = (240, 175, 40)


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


def map_components(m: dict | None, dim: int, name: str, joint_names) -> tuple[list[str], int, str, bool]:
    """(component names, coordinates per point, unit, angle?) of a task-map description: its row's
    labels in the task-map table (``raico.planning.term_kinds``)."""
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
        names, per_point, unit, angle = map_components(m, raw.shape[1], name, list(joint_names))
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
    from raico.plants.taskmaps import FramePlacementError, FramePoints

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
