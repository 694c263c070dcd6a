"""Figures in the thesis's style and claims tables, measured and honest.

Every claim is checked by a stated criterion on the measured numbers; the verdict is
``holds`` or ``does not hold`` and the numbers that decided it go into the table.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np

from raico.pipeline.engine.atomic import atomic_path, write_file_atomic
from raico.pipeline.engine.cache import Cache
from raico.pipeline.experiments.plots import clip_range, cost_at_times
from raico.thesis.claims import FDDP_ACCEPT_ANY, FDDP_HELD, FDDP_ILQG_SCHEDULE, FDDP_ROLLOUT, executed_achieved
from raico.thesis.figures import (
    BASELINE_LABELS,
    EXPERIMENTS,
    NOISE_RUNS,
    NOISE_SWEEPS,
    RECORDED_SEEDS,
    Experiment,
    cost_curves,
    summarize,
)


def save_figure(fig, path: Path, dpi: int = 100) -> None:
    """Write ``fig`` to ``path`` atomically and release it."""
    import matplotlib.pyplot as plt

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi)
    plt.close(fig)


# ----------------------------------------------------------------------------- colours
# One colour per solver variant in every figure, keyed by the variant's label (raico.thesis.figures.Variant.label).
SOLVER_COLORS: dict[str, str] = {
    "iLQG": "tab:blue",
    "AICO": "tab:orange",
    "AICO (no sweep relinearization)": "tab:brown",
    "R-AICO a=1": "tab:green",
    "R-AICO a=10": "tab:red",
    FDDP_HELD: "tab:purple",
    FDDP_ROLLOUT: "tab:pink",
    FDDP_ACCEPT_ANY: "tab:gray",
    FDDP_ILQG_SCHEDULE: "tab:olive",
    "R-AICO a=1, gamma=2": "black",
    "AICO, finite differences": "#e6550d",
    "AICO, belief rate 0.5": "#9c9ede",
    "AICO, controller rate 0.5": "#e7969c",
    "R-AICO a=1, rollout start": "#637939",
    "R-AICO adaptive (a0=1, rollout start)": "#8c6d31",
    # the start moved by 1e-9 rad (the perturbation test): a darker shade of the solver's colour
    "iLQG, start +1e-09 rad": "#08519c", "AICO, start +1e-09 rad": "#a63603",
    "R-AICO a=1, start +1e-09 rad": "#006d2c",
    # the thesis's set-up beside raico's: a lighter shade of the solver's colour
    **{f"{k}, {setup}": c for k, c in (("iLQG", "#aec7e8"), ("AICO", "#ffbb78"), ("R-AICO a=1", "#98df8a"),
                                         ("R-AICO a=10", "#ff9896")) for setup in ("zero posture", "thesis's cost")},
}
SOLVER_COLOR_PREFIXES: tuple[tuple[str, str], ...] = (("R-AICO adaptive", "tab:cyan"),)
# labels of neither table: a colour from these, chosen by a hash of the label (the same in every figure unless
# it is taken there already, then the next free one)
FALLBACK_COLORS = ("#393b79", "#637939", "#8c6d31", "#843c39", "#7b4173", "#3182bd", "#e6550d", "#31a354",
                   "#756bb1", "#636363", "#9c9ede", "#bd9e39")


def _fallback_index(label: str) -> int:
    import zlib

    return zlib.crc32(label.encode("utf-8")) % len(FALLBACK_COLORS)


def solver_color(label: str) -> str:
    """The colour of a solver variant: ``SOLVER_COLORS``, else the first matching prefix of
    ``SOLVER_COLOR_PREFIXES``, else a ``FALLBACK_COLORS`` entry chosen by a hash of the label."""
    if label in SOLVER_COLORS:
        return SOLVER_COLORS[label]
    for prefix, color in SOLVER_COLOR_PREFIXES:
        if label.startswith(prefix):
            return color
    return FALLBACK_COLORS[_fallback_index(label)]


def figure_colors(labels) -> dict[str, str]:
    """``solver_color`` of each label of one figure, distinct within it: the labels of ``SOLVER_COLORS``
    keep theirs; another label whose colour is taken already (two labels sharing a prefix, a hash
    collision) gets the next free fallback colour (labels taken in sorted order: deterministic)."""
    labels = list(dict.fromkeys(labels))
    out = {lab: SOLVER_COLORS[lab] for lab in labels if lab in SOLVER_COLORS}
    taken = set(out.values())
    for lab in sorted(lab for lab in labels if lab not in out):
        color = solver_color(lab)
        if color in taken:
            i = _fallback_index(lab)
            free = [c for k in range(len(FALLBACK_COLORS)) if (c := FALLBACK_COLORS[(i + k) % len(FALLBACK_COLORS)])
                    not in taken]
            color = free[0] if free else color
        out[lab] = color
        taken.add(color)
    return {lab: out[lab] for lab in labels}


# ----------------------------------------------------------------------------- what the cost panels draw
def median_band(C: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per column of ``C`` (runs x iterations, or x times): the median and the 25th and 75th
    percentiles over the runs with a finite value there (NaN where none has one).

    The median is ``raico.stages.evaluate.summary.median``, the tables' statistic: on ``cost_curves``
    (runs that stopped early hold their last cost, diverged runs drop out once they diverge) the
    last point is the table's median final cost."""
    from raico.stages.evaluate.summary import median

    C = np.asarray(C, float)
    n = C.shape[1] if C.ndim == 2 else 0
    m, lo, hi = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    for j in range(n):
        col = C[:, j][np.isfinite(C[:, j])]
        if col.size:
            m[j] = median(col)
            lo[j], hi[j] = np.percentile(col, [25, 75])
    return m, lo, hi


def mean_std(C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per column of ``C`` (runs x iterations): the mean and the standard deviation over the runs with a finite
    value there (the thesis's statistic for its cost figures; NaN where none has one)."""
    C = np.asarray(C, float)
    n = C.shape[1] if C.ndim == 2 else 0
    m, sd = np.full(n, np.nan), np.full(n, np.nan)
    for j in range(n):
        col = C[:, j][np.isfinite(C[:, j])]
        if col.size:
            m[j], sd[j] = float(np.mean(col)), float(np.std(col))
    return m, sd


def diverged_path(costs: np.ndarray, initial_cost: float | None, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """A diverged run up to its last iterate before the divergence: iterations ``0 .. k-1`` (the run
    diverged in iteration ``k = iterations``; 0 is the initial guess rolled out, cost
    ``initial_cost``) and their costs; non-finite entries left out."""
    k = max(int(iterations), 1)
    c = np.asarray(costs, float)
    y = np.concatenate([[np.nan if initial_cost is None else float(initial_cost)], c[:k - 1]])
    it = np.arange(y.size)
    ok = np.isfinite(y) & (y > 0)
    return it[ok], y[ok]


def cost_panel_data(cache: Cache, exp: Experiment, plans: list[dict]) -> list[dict]:
    """What the cost-per-iteration panel draws, one dict per variant with runs: ``label``, ``color``,
    ``runs``, ``iterations`` (1..n), ``mean``/``std`` (``mean_std`` of ``cost_curves``), ``median``/``q25``/``q75``
    (``median_band``), ``thesis`` (one of the thesis's solvers at the figure's budget) and ``diverged``: a
    ``diverged_path`` per diverged run."""
    from raico.thesis.claims import THESIS_SOLVERS

    colors = figure_colors(v.label for v in exp.variants)
    out = []
    for v in exp.variants:
        runs = [p for p in plans if p["variant"] == v]
        C = cost_curves(cache, plans, v)
        if C.size == 0:
            continue
        m, lo, hi = median_band(C)
        mean, sd = mean_std(C)
        div = [diverged_path(C[i], p["outcome"].metrics.get("initial_cost"),
                             p["outcome"].metrics.get("iterations") or C.shape[1])
               for i, p in enumerate(runs) if p["outcome"].status == "diverged"]
        with np.errstate(all="ignore"):
            low = np.array([np.min(c[np.isfinite(c)]) if np.isfinite(c).any() else np.nan for c in C.T])
        out.append({"label": v.label, "color": colors[v.label], "runs": C.shape[0],
                    "iterations": np.arange(1, C.shape[1] + 1), "mean": mean, "std": sd, "lowest": low, "median": m,
                    "q25": lo, "q75": hi, "diverged": div, "thesis": v.label in THESIS_SOLVERS and v.iterations is None})
    return out


def wall_panel_data(cache: Cache, exp: Experiment, plans: list[dict], points: int = 300) -> list[dict]:
    """What the cost-against-wall-time panel draws, per variant: ``label``, ``color``, ``runs``,
    ``times`` (a log-spaced grid common to the figure), ``median``/``q25``/``q75`` of
    ``cost_at_times`` (NaN where fewer than half the runs have finished an iteration, or have a finite
    cost) and ``diverged``: per diverged run its iterations' end times and costs up to the last
    iterate before the divergence."""
    colors = figure_colors(v.label for v in exp.variants)
    curves = [(v, cost_curves(cache, plans, v), cost_curves(cache, plans, v, "elapsed")) for v in exp.variants]
    finite_ends = [E[np.isfinite(E)] for _, _, E in curves if E.size]
    ends = np.concatenate(finite_ends) if finite_ends else np.zeros(0)
    ends = ends[ends > 0]
    if ends.size == 0:
        return []
    grid = np.geomspace(ends.min(), ends.max(), points)
    out = []
    for v, C, E in curves:
        if C.size == 0 or E.shape != C.shape:
            continue
        at = cost_at_times(C, E, grid)
        m, lo, hi = median_band(at)
        few = np.sum(np.isfinite(at), 0) * 2 <= C.shape[0]
        m[few], lo[few], hi[few] = np.nan, np.nan, np.nan
        runs = [p for p in plans if p["variant"] == v]
        div = []
        for i, p in enumerate(runs):
            if p["outcome"].status == "diverged":
                k = max(int(p["outcome"].metrics.get("iterations") or C.shape[1]), 1)
                t, y = E[i, :k - 1], C[i, :k - 1]
                ok = np.isfinite(t) & np.isfinite(y) & (t > 0) & (y > 0)
                div.append((t[ok], y[ok]))
        out.append({"label": v.label, "color": colors[v.label], "runs": C.shape[0], "times": grid, "median": m,
                    "q25": lo, "q75": hi, "diverged": div})
    return out


TIME_PER_ITERATION_RATIO = 2.0  # the wall-time panel is drawn where variants differ more than this


def time_per_iteration(cache: Cache, exp: Experiment, plans: list[dict]) -> dict[str, float]:
    """Per variant the median over its runs of the wall time per iteration (s): a run's last
    iteration's end over its number of iterations."""
    out = {}
    for v in exp.variants:
        per = []
        for p in plans:
            if p["variant"] != v:
                continue
            n = int(p["outcome"].metrics.get("iterations") or 0)
            t = p["outcome"].metrics.get("wall_time_s")
            if n > 0 and t is not None and math.isfinite(t):
                per.append(t / n)
        if per:
            out[v.label] = float(np.median(per))
    return out


def wants_wall_panel(exp: Experiment, per_iteration: dict[str, float]) -> bool:
    """Cost against wall time where it says something cost per iteration does not: with the crocoddyl
    baseline, or where the variants' median time per iteration differs more than
    ``TIME_PER_ITERATION_RATIO``-fold."""
    if any(v.solver in BASELINE_LABELS for v in exp.variants):
        return True
    t = [x for x in per_iteration.values() if x > 0]
    return len(t) > 1 and max(t) > TIME_PER_ITERATION_RATIO * min(t)


# ----------------------------------------------------------------------------- the experiment figure
def _clipped_limits(drawn: list[np.ndarray], first: list[float]) -> tuple[tuple[float, float] | None, str]:
    """The log cost axis of a panel: the finite values drawn that do not explode (``raico plot``'s
    :func:`raico.pipeline.experiments.plots.clip_range`; ``first``: each variant's first finite median), padded a quarter
    decade, and what it leaves out ("" if nothing)."""
    v = np.concatenate([np.ravel(np.asarray(x, float)) for x in drawn]) if drawn else np.zeros(0)
    v = v[np.isfinite(v) & (v > 0)]   # NaN and non-positive values are gaps in the lines, not clipped
    clip = clip_range(v, log=True, first=np.asarray(first, float))
    clip.what = "drawn point"
    if clip.lo is None:
        return None, ""
    kept = v[v <= clip.hi]
    lim = (10 ** (np.log10(kept.min()) - 0.25), 10 ** (np.log10(kept.max()) + 0.25))
    return lim, clip.text()


def _first_finite(y: np.ndarray) -> float:
    y = np.asarray(y, float)
    ok = np.isfinite(y) & (y > 0)
    return float(y[ok][0]) if ok.any() else float("nan")


def _runs_phrase(rows: list[dict]) -> str:
    ns = sorted({r["runs"] for r in rows})
    return f"{ns[0]} runs" if len(ns) == 1 else "the runs of each variant"


def figure_panels(exp: Experiment, rows: list[dict], wall: bool, executed: bool) -> list[str]:
    """The panels of an experiment's figure, in order: the thesis's solvers at the figure's budget (``cost``), the
    variants beyond the thesis (``beyond``: long budgets, crocoddyl, ablations) where the figure has any, cost
    against wall time (``wall``), on the balancing Nao the planned CoG against its via-points as the thesis's Fig.
    3.4C (``cog_plan``), and the free-standing executions (``cog``, ``executed``: beyond the thesis)."""
    panels = ["cost"] + (["beyond"] if any(not r["thesis"] for r in rows) else []) + (["wall"] if wall else [])
    if exp.plant == "nao" and exp.task == "balance":
        panels.append("cog_plan")
    if executed and exp.plant == "nao":
        panels += ["cog", "executed"]
    return panels


def write_figure(cache: Cache, exp: Experiment, plans: list[dict], path: Path, executions: list | None = None) -> None:
    """The experiment's figure: cost per iteration as the thesis draws it (mean and standard deviation over the
    initial states, log scale; the median dashed; diverged runs thin, to their last iterate before the divergence,
    marked x), the thesis's solvers at the figure's budget in one panel and the variants beyond the thesis in
    another; cost against wall time where the variants' time per iteration differs (``wants_wall_panel``); on the
    balancing Nao the planned CoG against its via-points (Fig. 3.4C); for executed Nao plans the executed CoG and
    the executed via-point errors (beyond the thesis). One colour per variant (``figure_colors``), one legend below
    the panels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    executions = executions or []
    rows = cost_panel_data(cache, exp, plans)
    per_it = time_per_iteration(cache, exp, plans)
    panels = figure_panels(exp, rows, wants_wall_panel(exp, per_it), bool(executions))
    n = len(panels)
    shape = (1, n) if n <= 3 else (2, 2) if n == 4 else (2, 3)
    fig, axes = plt.subplots(*shape, figsize=(5.6 * shape[1], 4.3 * shape[0] + 0.9), squeeze=False,
                             layout="constrained")
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    ax_of = dict(zip(panels, axes.ravel()))

    thesis = [r for r in rows if r["thesis"]]
    # the budget the runs had (--quick: its profile's, not the full figure's)
    budget = next((p["iterations"] for p in plans if p.get("iterations") and p["variant"].iterations is None),
                  exp.iterations)
    cost_panel(ax_of["cost"], exp, thesis, f"{exp.id}: {exp.plant} {exp.task} ({exp.dynamics}), the thesis's "
               f"solvers at the figure's budget ({budget} iterations)")
    if "beyond" in ax_of:
        cost_panel(ax_of["beyond"], exp, [r for r in rows if not r["thesis"]],
                   "beyond the thesis: long budgets, crocoddyl FDDP and ablations", budget=budget,
                   stat="median")  # the median: FDDP's infeasible first iterates (x0 held) reach 1e100
    if "wall" in ax_of:
        wall_time_panel(ax_of["wall"], wall_panel_data(cache, exp, plans), per_it)
    if "cog_plan" in ax_of:
        _planned_cog_panel(cache, exp, plans, ax_of["cog_plan"])
    if "cog" in ax_of:
        _cog_panel(cache, exp, executions, ax_of["cog"])
        _executed_panel(cache, exp, plans, executions, ax_of["executed"])

    handles = []
    for r in rows:
        d = len(r["diverged"])
        text = f"{r['label']}: {r['runs']} runs" + (f", {d} diverged" if d else "")
        handles.append(Line2D([], [], color=r["color"], lw=2, label=text))
    handles.append(Line2D([], [], color="k", lw=0.9, ls="--", label="dashed: the median over the runs"))
    if any(r["diverged"] for r in rows):
        handles.append(Line2D([], [], color="k", lw=0.8, marker="x", markersize=7,
                              label="thin: a diverged run up to its last iterate before the divergence (x)"))
    fig.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 3 if n > 1 else 2), fontsize=8,
               frameon=False)
    save_figure(fig, path, dpi=110)


def band(r: dict, stat: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(line, lower, upper)`` of a cost panel row: ``mean`` with mean +- one standard deviation (the lower edge
    not below the lowest run's cost: on the log scale a mean - std <= 0 has no place), or ``median`` with the
    interquartile range."""
    if stat == "median":
        return r["median"], r["q25"], r["q75"]
    return r["mean"], np.fmax(r["mean"] - r["std"], r["lowest"]), r["mean"] + r["std"]


def cost_panel(ax, exp: Experiment, rows: list[dict], title: str, budget: int | None = None,
               stat: str = "mean") -> None:
    """Cost per iteration: per variant the mean (line) and mean +- one standard deviation (band, ``band``) over its
    runs with the median dashed, or (``stat`` "median") the median and the interquartile range; the diverged runs
    thin to their last iterate; ``budget``: a dotted line at the thesis's solvers' budget on the figure."""
    drawn = []
    zero = False
    labelled = 0   # labels of variants that diverged in every run, stacked so that none hides another
    for r in rows:
        it, c = r["iterations"], r["color"]
        line, lo, hi = band(r, stat)
        ax.fill_between(it, lo, hi, color=c, alpha=0.16, lw=0)
        ax.plot(it, line, color=c, lw=1.8)
        if stat == "mean":
            ax.plot(it, r["median"], color=c, lw=0.9, ls="--")
        drawn += [line, lo, hi, r["median"]]
        ends = []
        for x, y in r["diverged"]:
            if y.size:
                ax.plot(x, y, color=c, lw=0.7, alpha=0.8)
                ax.plot(x[-1], y[-1], "x", color=c, markersize=7, mew=1.5)
                drawn.append(y)
                ends.append((x[-1], y[-1]))
                zero = zero or x[0] == 0
        if ends and len(r["diverged"]) == r["runs"]:  # no line: say whose crosses these are
            x, y = max(e[0] for e in ends), float(np.exp(np.mean(np.log([e[1] for e in ends]))))
            ax.annotate(f"{r['label']}: {len(ends)}/{r['runs']} diverged", (x, y), xytext=(8, -11 * labelled),
                        textcoords="offset points", va="center", fontsize=8, color=c,
                        bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.85})
            labelled += 1
    ax.set_yscale("log")
    lim, clipped = _clipped_limits(drawn, [_first_finite(r["median"]) for r in rows])
    if lim:
        ax.set_ylim(*lim)
    n_it = max((r["iterations"].size for r in rows), default=1)
    ax.set_xlim(left=-max(1.0, 0.03 * n_it) if zero else 0.5, right=n_it + 0.5)
    if budget is not None and budget < n_it:
        ax.axvline(budget, color="k", lw=0.8, ls=":")
        ax.annotate(f"the thesis's solvers' budget ({budget})", (budget, 1), xycoords=("data", "axes fraction"),
                    xytext=(3, -12), textcoords="offset points", fontsize=7)
    ax.set_xlabel("iteration" + (" (0: the initial guess rolled out)" if zero else ""))
    ax.set_ylabel("cost (rollout on the planning model)")
    what = ("mean and standard deviation" if stat == "mean" else "median and interquartile range (25-75 %)")
    ax.set_title(f"{title}\ncost per iteration: {what} over {_runs_phrase(rows)}"
                 + (" (median dashed)" if stat == "mean" else "") + (f"\n{clipped}" if clipped else ""), fontsize=9)
    ax.grid(True, which="both", alpha=0.3)


def planned_cog(cache: Cache, plans: list[dict], label: str) -> list[dict]:
    """Per plan of variant ``label`` the planned CoG's lateral coordinate (m, Drake's CoG of the planned joint
    positions) and its CoG via-points: ``{"times", "y", "via": [(t, target y)]}``."""
    from raico.pipeline.engine.artifacts import as_artifact
    from raico.plants.robots import shared_robot
    from raico.plants.taskmaps import CenterOfMass

    out = []
    for p in plans:
        if p["variant"].label != label:
            continue
        art = as_artifact(cache.require("plan", p["outcome"].key))
        X, desc = art.arrays("plan.npz", ("X",))["X"], art.document("problem.json")
        robot = shared_robot(desc.get("plant", "nao"))
        good = np.all(np.isfinite(X), axis=1)
        if not good.any():
            continue
        y = np.full(X.shape[0], np.nan)
        y[good] = CenterOfMass(robot, axes=(1,)).values_and_jacobians(X[good, :robot.n_q])[0][:, 0]
        via = [(term["times"][0] * desc["dt"], term["target"][1]) for term in desc["terms"]
               if term["name"].startswith("via_cog")]
        out.append({"times": np.arange(X.shape[0]) * desc["dt"], "y": y, "via": via})
    return out


def _planned_cog_panel(cache: Cache, exp: Experiment, plans: list[dict], ax, label: str = "R-AICO a=1") -> None:
    """The thesis's Fig. 3.4C: the planned CoG's lateral coordinate of ``label``'s plans (mean and standard
    deviation over the initial states, each plan thin) against its via-points (large dots)."""
    runs = planned_cog(cache, plans, label)
    color = solver_color(label)
    if not runs:
        ax.text(0.5, 0.5, "no plans", ha="center", va="center", transform=ax.transAxes)
        return
    t = runs[0]["times"]
    Y = np.array([r["y"] for r in runs if r["y"].shape == t.shape])
    for y in Y:
        ax.plot(t, y, color=color, lw=0.5, alpha=0.35)
    mean, sd = mean_std(Y)
    ax.fill_between(t, mean - sd, mean + sd, color=color, alpha=0.2, lw=0)
    ax.plot(t, mean, color=color, lw=1.8)
    for r in runs:
        for tv, yv in r["via"]:
            ax.plot(tv, yv, "o", color="k", markersize=8, mfc="none", mew=1.2)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("planned CoG lateral coordinate y (m, left +)")
    ax.set_title(f"planned CoG, {label} ({len(Y)} plans; Fig. 3.4C): mean and standard deviation,\neach plan thin; "
                 "circles: its CoG via-points", fontsize=9)
    ax.grid(True, alpha=0.3)


def wall_time_panel(ax, rows: list[dict], per_iteration: dict[str, float]) -> None:
    """Cost against wall time: per run the cost of the last iteration finished by time t, median and
    interquartile range over the runs on a common log-spaced time grid (where more than half the
    runs have finished an iteration). The cost axis spans the values that do not explode
    (FDDP's infeasible first iterates, x0 held, spike far above), said in the title."""
    import matplotlib.ticker

    lo_all, hi_first = [], []
    for r in rows:
        t, m, c = r["times"], r["median"], r["color"]
        ax.fill_between(t, r["q25"], r["q75"], color=c, alpha=0.18, lw=0)
        ax.plot(t, m, color=c, lw=1.6)
        if np.isfinite(m).any():
            lo_all.append(np.nanmin(r["q25"]))
            hi_first.append(m[np.isfinite(m)][0])
        for x, y in r["diverged"]:
            if y.size:
                ax.plot(x, y, color=c, lw=0.7, alpha=0.8)
                ax.plot(x[-1], y[-1], "x", color=c, markersize=7, mew=1.5)
                lo_all.append(np.nanmin(y))
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    clipped = ""
    if lo_all and hi_first:  # the values that do not explode, as the cost panels
        lim, clipped = _clipped_limits([np.asarray(lo_all), *[r[k] for r in rows for k in ("median", "q25", "q75")]],
                                       hi_first)
        if lim:
            ax.set_ylim(*lim)
    ax.set_xlabel("wall time (s, solver's own clock; shared 2-core machine)")
    ax.set_ylabel("cost (rollout on the planning model)")
    ts = [x for x in per_iteration.values() if x > 0]
    spread = f"\ntime per iteration (median) {1e3 * min(ts):.3g}-{1e3 * max(ts):.3g} ms" if ts else ""
    ax.set_title(f"cost against wall time: median and interquartile range\nof the cost reached by each time{spread}"
                 + (f"\n{clipped}" if clipped else ""), fontsize=9)
    ax.grid(True, which="both", alpha=0.3)


STATUS_STYLES = {"ok": "-", "limits": "-.", "tracking-lost": ":", "fell": "--", "diverged": (0, (1, 3)),
                 "collided": (0, (3, 1, 1, 1))}


def _executed_label(exp: Experiment) -> str:
    return exp.execute[0].label if exp.execute else "R-AICO a=1"


STABILIZER_COLOR = "#7b4173"  # the stabilizer's executions (plum) beside the joint PD's (the variant's colour)


def _stabilized(metrics: dict) -> bool:
    """Whether an execution ran the whole-body stabilizer (its metrics say ``controller`` ``wbc``)."""
    return metrics.get("controller", "pd") == "wbc"


def _group(e) -> tuple[str, str]:
    """(name, colour) of an execution's controller in the execution panels."""
    return ("stabilizer", STABILIZER_COLOR) if _stabilized(e.metrics) else ("joint PD", None)


def _cog_panel(cache: Cache, exp: Experiment, executions: list, ax) -> None:
    """The executed CoG's lateral coordinate of every executed run (free-standing Nao), in the
    executed variant's colour (the stabilizer's runs in plum), line style by the run's status,
    against that run's via-points (its plan's CoG targets: dots); a cross marks the moment a run failed."""
    from raico.pipeline.engine.artifacts import as_artifact

    label = _executed_label(exp)
    counts: dict[tuple[str, str, str], int] = {}
    for e in executions:
        art = as_artifact(cache.require("execute", e.key))
        d = art.arrays("rollout.npz")
        if "cog" not in d:
            continue
        group, gcolor = _group(e)
        color = gcolor or solver_color(label)
        plan = as_artifact(cache.require("plan", art.inputs[0].split("/", 1)[1]))
        desc = plan.document("problem.json")
        style = STATUS_STYLES.get(e.status, ":")
        counts[(group, color, e.status)] = counts.get((group, color, e.status), 0) + 1
        t, y = d["times"], d["cog"][:, 1]
        ax.plot(t, y, color=color, ls=style, lw=1.0, alpha=0.85)
        for term in desc["terms"]:
            if term["name"].startswith("via_cog"):
                ax.plot(term["times"][0] * desc["dt"], term["target"][1], "o", color=color, markersize=5,
                        markeredgecolor="k", markeredgewidth=0.5, alpha=0.8)
        t_fail = e.metrics.get("failure_time")
        if e.status != "ok" and t_fail is not None:
            k = min(int(round(t_fail / desc["dt"])), len(y) - 1)
            if np.isfinite(y[k]):
                ax.plot(t[k], y[k], "x", color="k", markersize=7, mew=1.2)
    if not counts:
        ax.text(0.5, 0.5, "no executions", ha="center", va="center", transform=ax.transAxes)
    else:
        from matplotlib.lines import Line2D

        ax.legend(handles=[Line2D([], [], color=c, ls=STATUS_STYLES.get(st, ":"), label=f"{g}: {st} ({k})")
                           for (g, c, st), k in counts.items()], fontsize=8, title="controller: status (runs)",
                  title_fontsize=8)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("executed CoG lateral coordinate y (m, left +)")
    ax.set_title(f"beyond the thesis: executed CoG, free-standing Nao, {label} ({sum(counts.values())} runs)\n"
                 "dots: each run's CoG via-points, x: its moment of failure", fontsize=9)
    ax.grid(True, alpha=0.3)


def _finite_median(values: list) -> float:
    """The median of the finite ``values`` (NaN if none)."""
    v = np.array(values, float)
    v = v[np.isfinite(v)]
    return float(np.median(v)) if v.size else math.nan


def write_balance_figure(cache: Cache, exp: Experiment, executions: list, path: Path) -> list[dict]:
    """``balance.png`` (beyond the thesis): per controller (joint PD, stabilizer) the executed
    CoG's and zero-moment point's signed margins against the contact polygon over time, one line per
    run (line style by status; below 0: outside, near 0: the feet about to tip), and the rows of its
    table: per controller the runs, how many stood, the medians of the worst CoG and ZMP margins and of
    the share of time the ZMP spent at the edge (``raico.stages.evaluate.metrics.zmp_metrics``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from raico.pipeline.engine.artifacts import as_artifact
    from raico.stages.evaluate.metrics import ZMP_EDGE

    groups: dict[str, list] = {}
    for e in executions:
        groups.setdefault(_group(e)[0], []).append(e)
    names = [g for g in ("joint PD", "stabilizer") if g in groups]
    fig, axes = plt.subplots(1, len(names), figsize=(5.6 * len(names), 4.2), squeeze=False, layout="constrained")
    rows = []
    for ax, name in zip(axes[0], names):
        runs = groups[name]
        for e in runs:
            d = as_artifact(cache.require("execute", e.key)).arrays("rollout.npz")
            style = STATUS_STYLES.get(e.status, ":")
            ax.plot(d["times"], d["cog_margin"], color="#d4a000", ls=style, lw=1.0, alpha=0.8)
            if "zmp_margin" in d:
                ax.plot(d["times"], d["zmp_margin"], color="#c83cc8", ls=style, lw=1.0, alpha=0.8)
        ax.axhline(0.0, color="k", lw=0.8)
        ax.axhspan(0.0, ZMP_EDGE, color="tab:red", alpha=0.08)
        lo, hi = ax.get_ylim()
        ax.set_ylim(max(lo, -0.1), hi)   # a fall leaves the panel (its margins reach tens of cm)
        stood = sum(e.status not in ("fell", "diverged") for e in runs)
        ax.set_title(f"{exp.id}, {name}: {stood}/{len(runs)} stood", fontsize=9)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("margin inside the contact polygon (m)")
        ax.grid(True, alpha=0.3)
        achieved = sum(executed_achieved(e.metrics) for e in runs)
        rows.append({"controller": name, "runs": len(runs), "stood": stood, "ok": sum(e.status == "ok" for e in runs),
                     "achieved": achieved,
                     **{k: _finite_median([e.metrics.get(k, math.nan) for e in runs])
                        for k in ("cog_min_margin", "zmp_min_margin", "zmp_edge_fraction")}})
    handles = [Line2D([], [], color="#d4a000", label="CoG (ground projection)"),
               Line2D([], [], color="#c83cc8", label="ZMP (from the ground's contact wrench)"),
               *[Line2D([], [], color="gray", ls=STATUS_STYLES.get(st, ":"), label=f"status {st}")
                 for st in sorted({e.status for e in executions})]]
    fig.legend(handles=handles, loc="outside lower center", ncol=len(handles), fontsize=8, frameon=False)
    fig.suptitle(f"red band: the ZMP within {ZMP_EDGE * 1000:g} mm of the polygon's edge (the feet tip)", fontsize=8)
    save_figure(fig, path, dpi=100)
    return rows


def balance_section(cache: Cache, exp: Experiment, executions: list, out_dir: Path) -> tuple[list[str], list[dict]]:
    """``balance.png`` and its markdown lines for an experiment with free-standing Nao executions."""
    if exp.plant != "nao" or not executions:
        return [], []
    rows = write_balance_figure(cache, exp, executions, out_dir / "balance.png")
    md = ["## Balance over time (beyond the thesis)", "",
          "Each execution's CoG and zero-moment point against the polygon of the sole corners in contact (signed "
          "margin, m, positive inside). The ZMP is where the ground's total contact wrench (Drake's contact "
          "results) has no horizontal moment, on flat ground its centre of pressure: it stays within the contact "
          "patches, so it reaches the polygon's edge when a foot tips (a little beyond it where a corner still "
          "touching is more than 1 mm up), and lies far outside once other bodies touch the ground (a fall). "
          "Margins below -0.1 m leave the panels.", "", "![balance](balance.png)", "",
          "| controller | runs | stood | worst CoG margin (m, median) | worst ZMP margin (m, median) | share of "
          "time with the ZMP at the edge (median) |", "|---|---|---|---|---|---|"]
    md += [f"| {r['controller']} | {r['runs']} | {r['stood']} | {_fmt(r['cog_min_margin'])} | "
           f"{_fmt(r['zmp_min_margin'])} | {_share(r['zmp_edge_fraction'])} |" for r in rows]
    return md + [""], rows


def _executed_panel(cache: Cache, exp: Experiment, plans: list[dict], executions: list, ax) -> None:
    """Per executed run its largest via-point error (the held right sole left out), planned (open
    circle) and executed (filled: status ok; cross: any other status), against the tolerance of the
    claim "executed_reaches"."""
    from raico.pipeline.engine.artifacts import as_artifact
    from raico.stages.evaluate.summary import largest_via_error
    from raico.thesis.claims import EXECUTED_VIA_TOL

    label = _executed_label(exp)
    color = solver_color(label)
    seed_of = {p["outcome"].key: (p["seed"], p["outcome"].metrics) for p in plans}
    pts: list = []
    achieved: dict = {}
    runs: dict = {}
    for i, e in enumerate(executions):
        key = as_artifact(cache.require("execute", e.key)).inputs[0].split("/", 1)[1]
        seed, pm = seed_of.get(key, (i, {}))
        group, gcolor = _group(e)
        shift = 0.25 if group == "stabilizer" else 0.0  # the stabilizer's run beside the joint PD's of that seed
        pts.append((seed + shift, largest_via_error(pm), largest_via_error(e.metrics), e.status, gcolor))
    if not pts:
        ax.text(0.5, 0.5, "no executions", ha="center", va="center", transform=ax.transAxes)
        return
    finite = [v for _, a, b, _, _ in pts for v in (a, b) if math.isfinite(v) and v > 0]
    top = max(finite + [EXECUTED_VIA_TOL]) * 3
    for seed, planned, executed, status, gcolor in pts:
        c = gcolor or color
        if math.isfinite(planned):
            ax.plot(seed, planned, "o", mfc="none", mec=c, markersize=7)
        ok = status == "ok"
        y = executed if math.isfinite(executed) else top
        ax.plot(seed, y, "o" if ok else "x", color=c if ok else "k", markersize=6 if ok else 7, mew=1.5)
        g = "stabilizer" if gcolor else "joint PD"
        runs[g] = runs.get(g, 0) + 1
        achieved[g] = achieved.get(g, 0) + bool(ok and executed <= EXECUTED_VIA_TOL)
    ax.axhline(EXECUTED_VIA_TOL, color="k", ls="--", lw=0.8)
    ax.set_yscale("log")
    lo = min(finite + [EXECUTED_VIA_TOL]) / 2
    ax.set_ylim(lo, top * (top / lo) ** 0.6)  # the upper part of the panel left free for the legend
    ax.set_xlabel("run (initial-state seed)")
    ax.set_xticks(sorted({int(p[0]) for p in pts}))
    ax.set_ylabel("largest via-point error (m)")
    from matplotlib.lines import Line2D

    stab = [Line2D([], [], ls="", marker="o", color=STABILIZER_COLOR, label="executed by the stabilizer, status ok "
                   "(right of its seed)")] if any(p[4] for p in pts) else []
    ax.legend(handles=[Line2D([], [], ls="", marker="o", mfc="none", mec=color, label="planned"),
                       Line2D([], [], ls="", marker="o", color=color, label="executed, status ok"), *stab,
                       Line2D([], [], ls="", marker="x", color="k", mew=1.5, label="executed, other status"),
                       Line2D([], [], color="k", ls="--", lw=0.8,
                              label=f"the claim's tolerance ({EXECUTED_VIA_TOL * 100:g} cm)")],
              fontsize=8, loc="best")
    ax.set_title(f"beyond the thesis: executed vs planned via-point error, {label}\nachieved (status ok and <= "
                 f"{EXECUTED_VIA_TOL * 100:g} cm): " + ", ".join(f"{g} {achieved[g]}/{n}" for g, n in runs.items()),
                 fontsize=9)
    ax.grid(True, which="both", alpha=0.3)


def moved_via_points(plans: list[dict]) -> list[dict]:
    """Per CoG via-point the support term moved before planning (``--balance``): the plans where it moved,
    the requested target's static margin (m, < 0 outside the support polygon) and how far it moved (m)."""
    by: dict[str, list[dict]] = {}
    for p in plans:
        for m in ((p["outcome"].metrics or {}).get("balance") or {}).get("moved") or []:
            by.setdefault(m["name"], []).append(m)
    rows = []
    for name, ms in by.items():
        margin = np.array([m["static_margin"] for m in ms], float)
        moved = np.array([np.linalg.norm(np.subtract(m["planned"], m["requested"])) for m in ms], float)
        rows.append({"via_point": name, "plans": len(ms), "static_margin_median": float(np.median(margin)),
                     "static_margin_min": float(margin.min()), "static_margin_max": float(margin.max()),
                     "moved_median": float(np.median(moved)), "moved_max": float(moved.max())})
    return rows


def moved_section(exp: Experiment, plans: list[dict]) -> tuple[list[str], list[dict]]:
    """The markdown lines on the via-points a balance option moved (none for the thesis's objective)."""
    if exp.balance == "none":
        return [], []
    rows = moved_via_points(plans)
    md = ["## Via-points moved by the support term (beyond the thesis)", "",
          f"`--balance {exp.balance}` (margin {exp.balance_margin:g} m): a CoG via-point whose target lies less than "
          "the margin inside the support polygon (or outside it) is reported before planning and planned at the "
          "nearest point with the margin; the executed via-point errors are against the planned point. "
          + ("None moved." if not rows else ""), ""]
    if rows:
        md += ["| via-point | plans where it moved | requested target's static margin (m): median (min-max) | "
               "moved by (m): median (max) |", "|---|---|---|---|"]
        md += [f"| {r['via_point']} | {r['plans']}/{len(plans)} | {_fmt(r['static_margin_median'])} "
               f"({_fmt(r['static_margin_min'])}-{_fmt(r['static_margin_max'])}) | {_fmt(r['moved_median'])} "
               f"({_fmt(r['moved_max'])}) |" for r in rows]
        md += [""]
    return md, rows


def _nearest_target_margin(m: dict) -> float:
    """An execution's CoG via-point target nearest the feet's edge: its margin (m; NaN without one)."""
    return min((m.get("cog_via_point_margins") or {"": math.nan}).values())


def _missed_row(key: str, m: dict, noise: str) -> dict:
    errs = {k: v for k, v in (m.get("via_point_errors") or {}).items() if not k.startswith("r_sole")}
    worst = max(errs, key=lambda k: errs[k], default=None)
    return {"key": key, "noise": noise, "status": m.get("status"), "reason": m.get("reason"), "via_point": worst,
            "error": errs.get(worst, float("nan")), "target_margin": _nearest_target_margin(m),
            "reference_cog_margin": m.get("reference_cog_min_margin", float("nan")),
            "reference_cog_time": m.get("reference_cog_min_margin_time"),
            "failure_time": m.get("failure_time"), "reference_cog_at_failure": m.get("reference_cog_margin_at_failure"),
            "beyond_limits": m.get("reference_beyond_limits") or {}}


def missed_rows(executions: list, noisy: list | None = None) -> list[dict]:
    """Per stabilizer execution that did not achieve the task (status ok and every via-point within
    ``EXECUTED_VIA_TOL``, the held right sole left out), and per noisy one (``noisy``: the noise sweep's entries,
    ``outcome`` and ``level``) that did not stand: its status, the worst via-point and its error (m), the nearest
    CoG via-point target's margin to the feet's polygon at the start (m), the least margin of the joint
    reference's CoG to that polygon (m) and when (s), and the joints the reference takes past their range (rad):
    what the reference asked that the robot could not give."""
    rows = [_missed_row(e.key, e.metrics, "none") for e in executions
            if _stabilized(e.metrics) and not executed_achieved(e.metrics)]
    for r in noisy or []:
        m = r["outcome"].metrics
        if _stabilized(m) and any(r["level"]) and m.get("status") in ("fell", "diverged"):
            x0, proc = r["level"]
            rows.append(_missed_row(r["outcome"].key, m, f"x0 {x0:g} rad, {proc:g} N m"))
    return rows


def missed_section(executions: list, noisy: list | None = None) -> tuple[list[str], list[dict]]:
    """The markdown lines on the stabilizer's runs that missed (``missed_rows``); none if every run achieved."""
    from raico.stages.execute.wbc import COG_MARGIN, LIMIT_MARGIN
    from raico.thesis.claims import EXECUTED_VIA_TOL

    rows = missed_rows(executions, noisy)
    if not rows:
        return [], []
    quiet = [r for r in rows if r["noise"] == "none"]
    stab = [e for e in executions if _stabilized(e.metrics)]
    good = [e.metrics for e in stab if executed_achieved(e.metrics)]

    def span(values) -> str:
        v = [x for x in values if x is not None and math.isfinite(x)]
        return "n/a" if not v else f"{_fmt(min(v))} to {_fmt(max(v))} m"

    target = [r["target_margin"] for r in rows]
    good_target = [_nearest_target_margin(m) for m in good]
    fell = len(rows) - len(quiet)
    md = ["## Where the stabilizer missed (beyond the thesis)", "",
          f"{len(quiet)} of {len(stab)} stabilizer runs without noise did not achieve the task (status ok and every "
          f"via-point within {EXECUTED_VIA_TOL * 100:g} cm); {fell} run{'' if fell == 1 else 's'} under noise fell. Against "
          "the feet's polygon at the start (margins positive inside): the joint reference's CoG (the plan, shifted by "
          f"the start projection) comes to {span(r['reference_cog_margin'] for r in rows)} of the edge in the runs "
          f"below, to {span(m.get('reference_cog_min_margin') for m in good)} in the {len(good)} that achieved; the "
          f"plan's CoG via-point target nearest the edge lies {span(target)} inside it below, {span(good_target)} in "
          f"those that achieved. The stabilizer holds its CoG reference {COG_MARGIN * 100:g} cm inside "
          "(`raico/stages/execute/wbc.py: COG_MARGIN`; tracked nearer the edge the robot tipped). The joint reference takes a joint "
          f"past its range in {sum(bool(r['beyond_limits']) for r in rows)} of the {len(rows)} runs below and in "
          f"{sum(bool(m.get('reference_beyond_limits')) for m in good)} of the {len(good)} that achieved (the "
          f"stabilizer stops it {LIMIT_MARGIN:g} rad inside its range).", "",
          "| execution | noise | status | worst via-point | its error (m) | the nearest CoG target's margin (m) | the reference "
          "CoG's least margin (m), at (s) (and where the run failed) | reference past a joint's range (rad) |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lim = ", ".join(f"{j} {v:.3f}" for j, v in sorted(r["beyond_limits"].items(), key=lambda kv: -kv[1])) or "none"
        status = r["status"] if r["status"] == "ok" else f"{r['status']} ({r['reason']})"
        at = "" if r["reference_cog_time"] is None else f", {r['reference_cog_time']:g}"
        if r.get("reference_cog_at_failure") is not None:
            at += f" (at the failure, {r['failure_time']:g} s: {_fmt(r['reference_cog_at_failure'])})"
        md.append(f"| {r['key']} | {r['noise']} | {status} | {r['via_point']} | {_fmt(r['error'])} | "
                  f"{_fmt(r['target_margin'])} | {_fmt(r['reference_cog_margin'])}{at} | {lim} |")
    return md + [""], rows


# ----------------------------------------------------------------------------- standing, across the Nao figures
STANDING_CONTROLLERS = {"joint PD": "pd", "stabilizer": "wbc"}


def standing_rows(docs: list[dict]) -> list[dict]:
    """Per Nao figure and controller (the figures' ``claims.json`` documents): the plan's balance option, runs,
    stood, status ok and achieved (ok and every via-point within ``EXECUTED_VIA_TOL``) without noise, and
    stood and ok under the noise sweep's noisy level, where it ran."""
    out = []
    for d in docs:
        exp = EXPERIMENTS.get(d["figure"])
        for b in d.get("balance") or []:
            noisy = [r for r in d.get("noise") or [] if r.get("controller", "pd") == STANDING_CONTROLLERS.get(
                b["controller"]) and (r["x0_noise"] or r["process_noise"])]
            out.append({"figure": d["figure"], "balance": exp.balance if exp else "none", "controller": b["controller"],
                        "runs": b["runs"], "stood": b["stood"], "ok": b.get("ok"), "achieved": b.get("achieved"),
                        "noise": [{"x0_noise": r["x0_noise"], "process_noise": r["process_noise"], "runs": r["runs"],
                                   "stood": r["stood"], "ok": r["ok"]} for r in noisy]})
    return out


def standing_section(docs: list[dict], root: Path) -> list[str]:
    """The report README's section on the free-standing Nao ``standing.png`` (the share of runs
    that stood and that achieved the task per figure and controller, and the share that stood under noise) and
    its table; none without a Nao figure."""
    rows = standing_rows(docs)
    if not rows:
        return []
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9.0, 3.8))
    x = np.arange(len(rows))
    bars = [("stood", [(r["stood"], r["runs"]) for r in rows], "tab:green"),
            ("achieved (ok, via-points <= 1 cm)", [(r["achieved"], r["runs"]) for r in rows], "tab:blue"),
            ("stood under noise", [(r["noise"][0]["stood"], r["noise"][0]["runs"]) if r["noise"] else (None, 0)
                                   for r in rows], "tab:orange")]
    for i, (label, counts, color) in enumerate(bars):
        xs = x + (i - 1) * 0.26
        values = [(a or 0) / n if n else 0.0 for a, n in counts]
        ax.bar(xs, values, 0.26, label=label, color=color)
        for xi, v, (a, n) in zip(xs, values, counts):   # the count on each bar: 0/10 is a result, "not run" is not
            ax.text(xi, v + 0.02, f"{a or 0}/{n}" if n else "not run", ha="center", va="bottom", fontsize=5.5,
                    rotation=90 if not n else 0)
    ax.set_xticks(x, [f"{r['figure']}\n{r['controller']}" + (f"\n--balance {r['balance']}" if r["balance"] != "none"
                                                              else "") for r in rows], fontsize=7)
    ax.set_ylim(0, 1.2)  # room above the bars for the legend
    ax.set_yticks(np.linspace(0, 1, 6))
    ax.set_ylabel("share of the runs")
    ax.axhline(0.9, color="gray", lw=0.8, ls=":")
    ax.legend(fontsize=7, loc="upper center", ncol=3)
    ax.set_title("The free-standing Nao: R-AICO a=1 plans executed in Drake (dotted: 9 of 10)", fontsize=9)
    fig.tight_layout()
    save_figure(fig, root / "standing.png", dpi=100)

    def noise_cell(r):
        return "; ".join(f"x0 {n['x0_noise']:g} rad, process {n['process_noise']:g} N m: stood {n['stood']}/{n['runs']}"
                         f", ok {n['ok']}/{n['runs']}" for n in r["noise"]) or "-"

    md = ["## Standing on the free-standing Nao (beyond the thesis)", "",
          "Every Nao figure's executed plans (R-AICO a=1) on the free-standing robot in Drake, with the thesis-style "
          "joint PD from the plan's start and with the whole-body stabilizer from the standing start; "
          "fig3.4-inside and fig3.4-support are the same targets without and with the planner's support term. "
          "Achieved: status ok and every executed via-point within 1 cm (the held right sole left out). Each "
          "figure's claims.md has the runs and the CoG and ZMP over time.", "", "![standing](standing.png)", "",
          "| figure | plan's balance term | controller | runs | stood | status ok | achieved | under noise |",
          "|---|---|---|---|---|---|---|---|"]
    md += [f"| {r['figure']} | {r['balance']} | {r['controller']} | {r['runs']} | {r['stood']} | {r['ok']} | "
           f"{r['achieved']} | {noise_cell(r)} |" for r in rows]
    return md + [""]


# ----------------------------------------------------------------------------- robustness under noise
NOISE_CONTROLLERS = {"pd": "joint PD", "wbc": "stabilizer"}


def noise_summary(noise: list[dict]) -> list[dict]:
    """Per controller and noise level of the sweep (``raico.thesis.figures.noise_runs``, run by ``experiment_flow``):
    runs, status counts, success rate (share with status ok), stood, and the spread of the largest executed via-point
    error."""
    from raico.stages.evaluate.summary import largest_via_error

    rows = []
    for controller, level in dict.fromkeys((r.get("controller", "pd"), r["level"]) for r in noise):
        rs = [r for r in noise if r.get("controller", "pd") == controller and r["level"] == level]
        st = [r["outcome"].status for r in rs]
        errs = np.array([largest_via_error(r["outcome"].metrics) for r in rs], float)
        fin = errs[np.isfinite(errs)]
        clamped = [r["outcome"].metrics.get("effort_clamped_fraction") for r in rs]
        clamped = [c for c in clamped if c is not None]
        rows.append({"controller": controller, "x0_noise": level[0], "process_noise": level[1], "runs": len(rs),
                     "ok": st.count("ok"), "stood": sum(x not in ("fell", "diverged") for x in st),
                     "success_rate": st.count("ok") / len(rs) if rs else math.nan,
                     "statuses": {k: st.count(k) for k in dict.fromkeys(st)},
                     "via_error_median": float(np.median(errs)) if errs.size else math.nan,
                     "via_error_min": float(fin.min()) if fin.size else math.nan,
                     "via_error_max": float(errs.max()) if errs.size else math.nan,
                     "clamped_median": float(np.median(clamped)) if clamped else math.nan,
                     "executions": [{"plan_seed": r["plan_seed"], "seed": r["seed"], "key": r["outcome"].key,
                                     "status": r["outcome"].status} for r in rs]})
    return rows


def write_noise_figure(exp: Experiment, rows: list[dict], path: Path) -> None:
    """Success rate (share of executions with status ok) and, on the Nao, the share that stood, against the noise
    level: one line each per controller."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.0, 3.8))
    levels = list(dict.fromkeys((r["x0_noise"], r["process_noise"]) for r in rows))
    x_of = {lv: i for i, lv in enumerate(levels)}
    colors = {"pd": "tab:blue", "wbc": "tab:green"}
    for controller in dict.fromkeys(r["controller"] for r in rows):
        rs = [r for r in rows if r["controller"] == controller]
        x = [x_of[(r["x0_noise"], r["process_noise"])] + (0.04 if controller == "wbc" else 0.0) for r in rs]
        name = NOISE_CONTROLLERS.get(controller, controller)
        ax.plot(x, [r["success_rate"] for r in rs], "o-", color=colors.get(controller), label=f"{name}: status ok")
        for xi, r in zip(x, rs):
            ax.annotate(f"{r['ok']}/{r['runs']}", (xi, r["success_rate"]), textcoords="offset points",
                        xytext=(6, -12 if controller == "wbc" else 6), fontsize=8, color=colors.get(controller))
        if exp.plant == "nao":
            ax.plot(x, [r["stood"] / r["runs"] for r in rs], "s--", color=colors.get(controller), alpha=0.5,
                    label=f"{name}: stood")
            for xi, r in zip(x, rs):
                ax.annotate(f"stood {r['stood']}/{r['runs']}", (xi, r["stood"] / r["runs"]), textcoords="offset points",
                            xytext=(-8, 8 if controller == "wbc" else 18), ha="right", fontsize=7,
                            color=colors.get(controller), alpha=0.8)
    ax.set_xticks(range(len(levels)), [f"x0 {a:g} rad\nprocess {b:g} N m" for a, b in levels], fontsize=8)
    ax.set_xlim(-0.4, len(levels) - 0.6)
    ax.set_ylim(-0.15, 1.15)
    ax.set_ylabel("share of the runs")
    ax.set_title(f"{exp.id}: executions under noise", fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    save_figure(fig, path, dpi=100)


def noise_section(exp: Experiment, noise: list[dict], out_dir: Path) -> tuple[list[str], list[dict]]:
    """``noise.png`` and the markdown lines of the noise-robustness section (none without a sweep)."""
    if not noise:
        return [], []
    rows = noise_summary(noise)
    write_noise_figure(exp, rows, out_dir / "noise.png")
    who = []
    if any(r["controller"] == "pd" for r in rows):
        who.append(f"joint PD: {NOISE_SWEEPS[exp.id].label}'s plans of the first {NOISE_RUNS} initial states, from the "
                   "plan's start")
    if any(r["controller"] == "wbc" for r in rows):
        who.append("stabilizer every executed plan, from the standing start")
    md = ["## Robustness under noise (beyond the thesis)", "",
          f"Each plan executed once per noise level ({'; '.join(who)}): initial joint-angle noise (rad) and torque "
          "noise per planning step and joint (N m; added to the controller's torque, the sum clamped at the effort "
          "limits); plan i with execution seed i. A run succeeds when its status is ok; it stood unless it fell or "
          "diverged. Its limits are the controller's: a motor that clamps only the noise (on the Nao a hand's 0.29 "
          "N m, a wrist's 0.41 N m) is not at a limit of the controller; the last column counts the samples with any "
          "motor clamped at its effort limit, the command plus the noise (each run's `effort_clamped_fraction`). "
          "The noisy runs are not recorded by `make reproduce` (their keys are in claims.json; `raico show "
          "KEY --open` writes and opens a recording from the cache).", "", "![noise](noise.png)", "",
          "| controller | x0 noise (rad) | process noise (N m) | runs | success rate | stood | statuses | largest "
          "executed via-point error: median (min-max) | samples with a motor clamped, command + noise (median) |",
          "|---|---|---|---|---|---|---|---|---|"]
    md += [f"| {NOISE_CONTROLLERS.get(r['controller'], r['controller'])} | {r['x0_noise']:g} | {r['process_noise']:g} | "
           f"{r['runs']} | {_share(r['success_rate'])} | {r['stood']} | "
           f"{', '.join(f'{k} {v}' for k, v in r['statuses'].items())} | {_fmt(r['via_error_median'])} "
           f"({_fmt(r['via_error_min'])}-{_fmt(r['via_error_max'])}) | {_share(r['clamped_median'])} |" for r in rows]
    return md + [""], rows


# ----------------------------------------------------------------------------- claims
def claims_table(exp: Experiment, plans: list[dict], executions: list, cache: Cache | None = None,
                 integrators: list[dict] | None = None, noise: list[dict] | None = None) -> list[dict]:
    """The experiment's claims (``raico.thesis.claims``) on its measured summaries (with ``cache``:
    the runs' cost curves too; with ``integrators``, the integrator comparison's runs, its rows join
    ``S``). The integrator claim is left out where the comparison did not run (--quick)."""
    from raico.thesis.claims import THESIS, Quote, evaluate_claims
    from raico.thesis.figures import TASK_LABELS

    integ = {r["label"]: r for r in integrator_table(exp, integrators or [], cache)}
    names = tuple(c for c in exp.claims if c != "integrators_agree" or integrators)
    noisy = [{**r["outcome"].metrics, "noise_level": list(r["level"])} for r in noise or [] if any(r["level"])]
    own = [v for v in exp.variants if v.task is None and not v.nudge]
    S, without = _summaries(plans, own, cache, integ)
    rows = evaluate_claims(names, S, [e.metrics for e in executions], exp.id, noisy, without)
    for v in (v for v in exp.variants if v.nudge and v.task is None):  # the start moved by a tiny amount
        twin = replace(v, nudge=0.0)
        moved = {**S, twin.label: _summaries(plans, [v], cache, {}, v.label.removeprefix(twin.label))[0][twin.label]}
        again = evaluate_claims(names, moved, [e.metrics for e in executions], exp.id, noisy)
        effect = nudge_effect(plans, twin, v)
        for r, a in zip(rows, again):
            named = re.search(rf"(?<![-\w]){re.escape(twin.label)}(?![\w=])", r["measured"])
            if not named and a["verdict"] == r["verdict"]:
                continue
            said = (f"with {twin.label}'s start moved {v.nudge:g} rad ({effect['said']}): "
                    + ("the same verdict" if a["verdict"] == r["verdict"] else f"the verdict flips to {a['verdict']}"))
            r["margin"] = "; ".join(x for x in (r.get("margin"), said) if x)
            if a["verdict"] != r["verdict"]:
                r["fragile"] = "; ".join(x for x in (r.get("fragile"), said) if x)
    for task, words in TASK_LABELS.items():  # the thesis's set-up beside raico's: its thesis rows, judged alike
        setup = [v for v in exp.variants if v.task == task]
        if not setup:
            continue
        tail = f", {words}"
        S, without = _summaries(plans, setup, cache, {}, tail)
        more = evaluate_claims(tuple(c for c in names if isinstance(THESIS[c], Quote)), S, [], exp.id, [], without)
        rows += [{**r, "claim": f"{r['claim']} (with the thesis's {SETUP_WORDS.get(task, words)})",
                  "setup": setup_in_place(r.get("setup", ""), task)} for r in more]
    return rows


# the set-up deviations (raico.thesis.claims.SETUP_NOTES) a thesis set-up removes, and what its rows say instead
SETUP_REPLACES = {"reach-zero": (("nao start",), "q0 about the zero posture (the thesis's start; the elbow rolls at "
                                                 "the end of their range, 0.03 rad short of 0)"),
                  "balance-thesis": (("cog weights", "right sole"), "eq. 3.7's cost: 1e4 on the CoG via-points with "
                                                                    "C = diag(10, 1e6, 10), no right-sole term")}


def setup_in_place(setup: str, task: str) -> str:
    """A row's set-up deviations with those the thesis's set-up ``task`` removes replaced by what it runs."""
    from raico.thesis.claims import SETUP_NOTES

    gone, instead = SETUP_REPLACES.get(task, ((), ""))
    parts = [p for p in setup.split("; ") if p not in {SETUP_NOTES[k] for k in gone}]
    return "; ".join([instead, *parts] if instead else parts)


CHAOTIC = 1e-3  # a run is chaotic when a 1e-9 rad change of its start moves its final cost by more than 0.1 %


def nudge_effect(plans: list[dict], twin, nudged) -> dict:
    """How far each seed's final cost and largest via-point error moved when the start moved by ``nudged.nudge``
    (rad) from ``twin``'s: ``{"label", "nudge", "seeds", "cost_change", "via_change", "chaotic", "said"}``, the
    changes relative (cost) and in m (via-point), ``chaotic`` the seeds whose cost moved by more than
    ``CHAOTIC``."""
    from raico.stages.evaluate.summary import largest_via_error

    def by_seed(v) -> dict[int, tuple[float, float]]:
        return {p["seed"]: (float(p["outcome"].metrics.get("final_cost") or math.nan),
                            largest_via_error(p["outcome"].metrics)) for p in plans if p["variant"] == v}

    a, b = by_seed(twin), by_seed(nudged)
    seeds = sorted(set(a) & set(b))
    cost = [abs(b[k][0] - a[k][0]) / abs(a[k][0]) if a[k][0] else math.nan for k in seeds]
    via = [abs(b[k][1] - a[k][1]) for k in seeds]
    chaotic = [k for k, c in zip(seeds, cost) if not c <= CHAOTIC]
    fin = [c for c in cost if math.isfinite(c)]
    said = (f"final costs moved by up to {_share_pct(max(fin)) if fin else 'n/a'}, via-point errors by up to "
            f"{_fmt(max(via)) if via else 'n/a'} m; chaotic (cost moved > {CHAOTIC:.1%}) in {len(chaotic)}/{len(seeds)}"
            " runs" + (f": seeds {', '.join(map(str, chaotic))}" if chaotic else ""))
    return {"label": twin.label, "nudge": nudged.nudge, "seeds": seeds, "cost_change": cost, "via_change": via,
            "chaotic": chaotic, "said": said}


def processor_section(docs: list[dict]) -> list[str]:
    """Markdown: the figures' perturbation tests of the start (``nudge_effect``): which runs are chaotic, so
    that their numbers differ from processor to processor (numpy's BLAS sums in another order on another
    processor: a change of the order of 1e-16 that a chaotic run amplifies)."""
    tests = [(d["figure"], e) for d in docs for e in d.get("processor") or []]
    if not tests:
        return []
    out = ["## Which numbers depend on the processor", "",
           "Each run below ran twice, the second time with every joint of its start moved by the stated amount. "
           "The compiled kernels are deterministic; numpy's BLAS is not across processors, so a run whose result "
           f"moves far more than its start (final cost by more than {CHAOTIC:.1%} after 1e-9 rad: chaotic) gives "
           "other numbers on another processor. The claims' rows on such a variant say whether the verdict "
           "survives the move.", "", "| figure | variant | start moved (rad) | runs | chaotic runs (seeds) | largest final-"
           "cost change | largest via-point change (m) |", "|---|---|---|---|---|---|---|"]
    for fid, e in tests:
        fin = [c for c in e["cost_change"] if math.isfinite(c)]
        out.append(f"| {fid} | {e['label']} | {e['nudge']:g} | {len(e['seeds'])} | {len(e['chaotic'])} "
                   f"({', '.join(map(str, e['chaotic'])) or 'none'}) | {_share_pct(max(fin)) if fin else 'n/a'} | "
                   f"{_fmt(max(e['via_change'])) if e['via_change'] else 'n/a'} |")
    return out + [""]


def not_holding_section(rows: list[dict]) -> list[str]:
    """Markdown: every thesis row that does not hold (or cannot be tested), with its reason and how fragile it is."""
    from raico.thesis.claims import BEYOND, CANNOT

    thesis = [r for r in rows if not str(r.get("thesis", "")).startswith(BEYOND)]
    out = [r for r in thesis if r["verdict"] in ("does not hold", CANNOT)]
    if not out:
        return []
    lines = ["### The thesis's rows that do not hold, and why", ""]
    for r in out:
        why = r.get("why") or (r["criterion"] if r["verdict"] == CANNOT else "")
        lines.append(f"- {r['figure']}, {r['claim']}: **{r['verdict']}**. {why.rstrip('.')}."
                     + (f" Fragile: {r['fragile']}." if r.get("fragile") else ""))
    return lines + [""]


def _share_pct(x: float) -> str:
    return f"{100 * x:.3g} %"


# how a row names the thesis's set-up it was judged in (raico.thesis.figures.TASK_LABELS)
SETUP_WORDS = {"reach-zero": "start: the zero posture", "balance-thesis": "cost: eq. 3.7's 1e4, no right-sole term"}


def _summaries(plans: list[dict], variants: list, cache: Cache | None, extra: dict,
               tail: str = "") -> tuple[dict, dict]:
    """The variants' summaries by label (``tail`` cut off the end of each: the thesis's set-up's variants under the
    labels the claims know), with ``extra`` rows; and seed -> those summaries with that seed left out (empty with
    fewer than ``LEAVE_ONE_OUT_MIN`` seeds)."""
    from raico.thesis.figures import LEAVE_ONE_OUT_MIN, variant_runs
    from raico.thesis.figures import plan_summary as summary

    runs = {v.label.removesuffix(tail): variant_runs(plans, v, cache) for v in variants}
    S = {**{k: summary(k, [r for _, r in rs]) for k, rs in runs.items()}, **extra}
    seeds = sorted({seed for rs in runs.values() for seed, _ in rs})
    without = {k: {**{lab: summary(lab, [r for seed, r in rs if seed != k]) for lab, rs in runs.items()}, **extra}
               for k in seeds} if len(seeds) >= LEAVE_ONE_OUT_MIN else {}
    return S, without


def integrator_table(exp: Experiment, integrators: list[dict], cache: Cache | None = None) -> list[dict]:
    """Per variant of the integrator comparison (appendix C) its plan summary and the medians of its plans'
    open-loop Drake integrations (``integration_summary``), plus the per-via-point medians of plan and
    integration (``via_plan``, ``via_drake``: term -> m)."""
    from raico.stages.evaluate.summary import integration_summary, median

    rows = []
    for v in exp.integrators:
        runs = [p for p in integrators if p["variant"] == v]
        if not runs:
            continue
        row = summarize(integrators, v, cache)
        row.update(integration_summary([p["integration"].metrics for p in runs]))
        for key, src in (("via_plan", lambda p: p["outcome"].metrics), ("via_drake", lambda p: p["integration"].metrics)):
            errs = [src(p).get("via_point_errors") or {} for p in runs]
            terms = list(dict.fromkeys(k for e in errs for k in e))
            row[key] = {t: median(np.array([math.inf if e.get(t) is None else e[t] for e in errs], float))
                        for t in terms}
        rows.append(row)
    return rows


INTEGRATOR_TEXT = (
    "Appendix C's three discretizations of the pseudo-dynamics qddot = u (A = [[1, tau], [0, 1]] per joint; B = [0; "
    "tau] Euler, [tau^2; tau] backward Euler, raico's and the thesis's default, [tau^2/2; tau] Heun), each planned by "
    "the same solver from the same initial states (backward Euler: the figure's own runs of those states). "
    "**Drake's integration**: the plan's controls (joint accelerations) held over each planning step, open loop, on "
    "Drake's continuous arm through computed torque (inverse dynamics at every derivative evaluation), integrated by "
    "runge_kutta3 at a fixed 1 ms step (`execute --open-loop`). Under a held acceleration Drake's trajectory is "
    "q + tau qdot + tau^2/2 u per step, which is Heun's model: its error is round-off; backward Euler's and Euler's "
    "positions drift by tau/2 times the velocity change so far (opposite signs). The executions of raico "
    "(`execute` without --open-loop) close the loop with the plan's feedback controller, which corrects such a drift.")


def markdown_integrators(rows: list[dict]) -> str:
    terms = list(dict.fromkeys(t for r in rows for t in r.get("via_plan", {})))
    out = ["| variant | runs | diverged | final cost | " + " | ".join(f"{t} planned (m)" for t in terms)
           + " | " + " | ".join(f"{t} Drake (m)" for t in terms) + " | RMS joint error vs Drake (rad), median (max) | "
           "largest joint error vs Drake (rad) | wall time (s) |", "|" + "---|" * (7 + 2 * len(terms))]
    out += [f"| {r['label']} | {r['runs']} | {r['diverged']} | {_fmt(r['final_cost_median'])} | "
            + " | ".join(_fmt(r["via_plan"].get(t)) for t in terms) + " | "
            + " | ".join(_fmt(r["via_drake"].get(t)) for t in terms)
            + f" | {_fmt(r['integration_rmse_median'])} ({_fmt(r['integration_rmse_max'])}) | "
            f"{_fmt(r['integration_max_error_median'])} | {_fmt(r['wall_time_median_s'])} |" for r in rows]
    return "\n".join(out) + "\n\n(medians over the initial states)"


def term_medians(cache: Cache, plans: list[dict], variant) -> dict[str, float]:
    """Per cost term of the variant's problem, the median over its runs with a finite final cost of
    the term's value on the final plan (the objective rebuilt from the run's ``problem.json``; terms
    that need a learned model left out). Their sum is the run's final cost."""
    from raico.pipeline.engine.artifacts import as_artifact
    from raico.planning.objective import objective_from_description
    from raico.stages.evaluate.summary import median

    values: dict[str, list[float]] = {}
    for p in plans:
        fc = p["outcome"].metrics.get("final_cost")
        if p["variant"] != variant or fc is None or not math.isfinite(fc):
            continue
        art = as_artifact(cache.require("plan", p["outcome"].key))
        P, desc = art.arrays("plan.npz", ("X", "U")), art.document("problem.json")
        obj = objective_from_description(desc)
        with np.errstate(all="ignore"):
            for t in obj.state_terms:
                values.setdefault(t.name, []).append(float(np.sum(t.value(P["X"]))))
            for t in obj.control_terms:
                values.setdefault(t.name, []).append(float(np.sum(t.value(P["U"]))))
            for t in obj.joint_terms:
                values.setdefault(t.name, []).append(float(np.sum(t.joint_value(P["X"][:-1], P["U"]))))
    return {k: median(np.array(v)) for k, v in values.items()}


def summary_table(exp: Experiment, plans: list[dict], cache: Cache | None = None) -> list[dict]:
    """The variants' summaries; with ``cache`` each also holds ``term_medians``."""
    rows = [summarize(plans, v) for v in exp.variants]
    if cache is not None:
        for row, v in zip(rows, exp.variants):
            row["term_medians"] = term_medians(cache, plans, v)
    return rows


SMOKE = "smoke test: not meaningful at 2 seeds and a few iterations"


def markdown_claims(rows: list[dict], smoke: bool = False) -> str:
    """The claims table in two parts: the thesis's own claims first (each with the sentence it tests, its section
    and the figure it is written about, the runs it reads, the set-up deviations that can drive its verdict and,
    where it does not hold, why), then the rows beyond the thesis (crocoddyl, adaptive R-AICO, long budgets,
    ablations, free-standing executions, PILCO, ...)."""
    from raico.thesis.claims import BEYOND, CANNOT

    def verdict(r: dict) -> str:
        if smoke:   # --quick: the verdict as computed, marked as not a finding
            return f"{r['verdict']} ({SMOKE})"
        why = r.get("why") or ""
        said = [f"why: {why}"] if r["verdict"] == "does not hold" and why else []
        said += [f"fragile: {r['fragile']}"] if r.get("fragile") else []
        return f"**{r['verdict']}**" + (f" ({'; '.join(said)})" if said else "")

    thesis_head = ["| figure | claim | the thesis says (section, about which figure) | criterion | measured | runs "
                   "(initial states or seeds) | set-up deviations that can drive the verdict | margin (each condition "
                   "against its limit) | verdict (if it does not hold: why; fragile: what would flip it) |",
                   "|---|---|---|---|---|---|---|---|---|"]
    beyond_head = ["| figure | claim | the thesis says | criterion | measured | runs | margin | verdict |",
                   "|---|---|---|---|---|---|---|---|"]
    beyond = [r for r in rows if str(r.get("thesis", "")).startswith(BEYOND)]
    thesis = [r for r in rows if r not in beyond]
    out: list[str] = []
    if thesis:
        held = sum(r["verdict"] == "holds" for r in thesis)
        untested = sum(r["verdict"] == CANNOT for r in thesis)
        out += [f"### The thesis's claims ({held} of {len(thesis)} hold"
                + (f", {untested} cannot be tested" if untested else "") + ")", "", *thesis_head]
        fragile = sum(bool(r.get("fragile")) for r in thesis)
        out += [f"| {r['figure']} | {r['claim']} | {r.get('thesis', '')} | {r['criterion']} | {r['measured']} | "
                f"{r.get('seeds', '')} | {r.get('setup', '')} | {r.get('margin') or '-'} | {verdict(r)} |"
                for r in thesis]
        if fragile and not smoke:
            out += ["", f"{fragile} of these {len(thesis)} verdicts are fragile: leaving out one seed flips them, or a "
                    "deciding margin is inside its quantity's spread over the runs (or within 5 % of its limit), or "
                    "a rerun without a seed failed, so whether it flips is not known (the row says which)."]
        out += [""]
    if beyond:
        held = sum(r["verdict"] == "holds" for r in beyond)
        out += [f"### Beyond the thesis ({held} of {len(beyond)} hold)", "", *beyond_head]
        out += [f"| {r['figure']} | {r['claim']} | {r.get('thesis', '')} | {r['criterion']} | {r['measured']} | "
                f"{r.get('seeds', '')} | {r.get('margin') or '-'} | {verdict(r)} |" for r in beyond]
        out += [""]
    return "\n".join(out).rstrip()


def _share(x: float) -> str:
    """A share in [0, 1] as a whole percentage ("n/a" when not finite)."""
    return "n/a" if x is None or not math.isfinite(x) else f"{100 * x:.0f} %"


def _fmt(x: float) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    return f"{x:.3g}"


def markdown_summary(rows: list[dict]) -> str:
    out = ["| variant | runs | diverged | stopped by the solver's own convergence test (status converged; no claim's rule) | first-iteration "
           "cost | final cost | final/initial | "
           "largest via-point error | wall time (s) |", "|---|---|---|---|---|---|---|---|---|"]
    out += [f"| {r['label']} | {r['runs']} | {r['diverged']} | {r['converged']} | {_fmt(r['first_cost_median'])} | "
            f"{_fmt(r['final_cost_median'])} | {_fmt(r['cost_ratio_median'])} | {_fmt(r['max_via_error_median'])} | "
            f"{_fmt(r['wall_time_median_s'])} |" for r in rows]
    return "\n".join(out) + "\n\n(medians over the runs)"


FIGURE_CAPTION = ("Cost per iteration, as the thesis draws it: the left panel holds the thesis's solvers at the "
                  "figure's budget, the solid line the mean, the band the mean +- one standard deviation over the runs "
                  "with a finite cost at that iteration (its lower edge not below the lowest run, where mean - std "
                  "has no place on the log scale), the dashed line the median. Runs that stopped early hold their "
                  "last cost, so a dashed line's last point is the table's median final cost. The next panel holds "
                  "the variants beyond the thesis (long budgets, crocoddyl FDDP, ablations): median and interquartile "
                  "range (25-75 %), robust to FDDP's infeasible first iterates. Against wall time: median and "
                  "interquartile range of the cost reached by each time, where more than half the runs have "
                  "finished an iteration. Thin lines ending in x: diverged runs up to their last iterate before the "
                  "divergence. One colour per solver variant in every figure.")


def _controller(e: dict) -> str:
    """An execution's controller and start, as the report names them."""
    ctrl = "stabilizer (whole-body QP)" if _stabilized(e) else "joint PD"
    return f"{ctrl}, {'standing start' if e.get('start') == 'standing' else 'plan start'}"


def write_motion_figure(cache: Cache, exp: Experiment, plans: list[dict], path: Path) -> bool:
    """``path``: the Nao's motion panels (``raico.thesis.panels.motion_figure``); False (nothing written) without any."""
    from raico.thesis.panels import motion_figure

    fig = motion_figure(cache, exp, plans)
    if fig is not None:
        save_figure(fig, path, dpi=100)
    return fig is not None


MOTION_CAPTION = ("The motion, drawn from the R-AICO a=1 plans as the thesis's panels show it: snapshots (Fig. 3.3A, "
                  "Fig. 3.4A; stick figures of Drake's kinematics, the first initial state's plan), and on the reach "
                  "the right hand's objectives (Fig. 3.3C) and the left hand and head (Fig. 3.3D).")


def write_experiment_report(cache: Cache, exp: Experiment, result: dict, out_dir: Path) -> dict:
    """``figure.png``, ``claims.md``/``claims.json`` and the run list under ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    write_figure(cache, exp, result["plans"], out_dir / "figure.png", result.get("executions"))
    motion = write_motion_figure(cache, exp, result["plans"], out_dir / "motion.png")
    integ = result.get("integrators") or []
    rows = claims_table(exp, result["plans"], result["executions"], cache, integ, result.get("noise"))
    summary = summary_table(exp, result["plans"], cache)
    integ_rows = integrator_table(exp, integ, cache)
    runs = [{"variant": p["variant"].label, "seed": p["seed"], "key": p["outcome"].key,
             "status": p["outcome"].status, "recording": str(Path(p["outcome"].path) / "recording.rrd"),
             "recorded": (Path(p["outcome"].path) / "recording.rrd").exists()}
            for p in result["plans"] + integ]
    integ_runs = [{"variant": p["variant"].label, "seed": p["seed"], "plan": p["outcome"].key,
                   "integration": p["integration"].key, "status": p["integration"].status} for p in integ]
    execs = [{"key": e.key, "recording": str(Path(e.path) / "recording.rrd"),
              "recorded": (Path(e.path) / "recording.rrd").exists(), **{
        k: v for k, v in e.metrics.items() if k != "via_point_errors"}} for e in result["executions"]]
    noise_md, noise_rows = noise_section(exp, result.get("noise") or [], out_dir)
    balance_md, balance_rows = balance_section(cache, exp, result["executions"], out_dir)
    moved_md, moved_rows = moved_section(exp, result["plans"])
    missed_md, missed = missed_section(result["executions"], result.get("noise"))
    balance_md = moved_md + balance_md + missed_md
    processor = [nudge_effect(result["plans"], replace(v, nudge=0.0), v) for v in exp.variants if v.nudge]
    doc = {"figure": exp.id, "description": exp.description, "claims": rows, "summary": summary,
           "runs": runs, "executions": execs, "noise": noise_rows, "integrators": integ_rows,
           "integrator_runs": integ_runs, "balance": balance_rows, "moved_via_points": moved_rows,
           "stabilizer_missed": missed, "processor": processor}
    write_file_atomic(out_dir / "claims.json", json.dumps(doc, indent=2, default=float))
    md = [f"# {exp.id}: {exp.description}", "", "![figure](figure.png)", "", FIGURE_CAPTION, ""]
    md += ["![motion](motion.png)", "", MOTION_CAPTION, ""] if motion else []
    md += ["## Claims", "",
          markdown_claims(rows), "", "## Runs", "", markdown_summary(summary), ""]
    if execs:
        nao = exp.plant == "nao"
        md += [f"## Executions in Drake (R-AICO a=1{', free-standing Nao' if nao else ''})", "",
               "| execution | controller, start | status | why | CoG inside the contact polygon | worst margin (m) | "
               "steps at an effort limit | RMSE planned vs executed (rad) | recording |",
               "|---|---|---|---|---|---|---|---|---|"]
        md += [f"| {e['key']} | {_controller(e)} | **{e.get('status')}** | {e.get('reason', '')} | "
               f"{_share(e.get('cog_inside_fraction'))} | {_fmt(e.get('cog_min_margin'))} | "
               f"{_share(e.get('torque_saturation'))} | {_fmt(e.get('rmse_planned_executed'))} | "
               + (f"`{e['recording']}`" if e["recorded"] else f"on demand: `raico show {e['key']} --open`") + " |"
               for e in execs]
        if nao:
            parts = []
            for ctrl in sorted({_controller(e) for e in execs}):
                group = [e for e in execs if _controller(e) == ctrl]
                stood = sum(e.get("status") not in ("fell", "diverged") for e in group)
                parts.append(f"{ctrl}: {stood}/{len(group)}")
            md += ["", f"Stood ({'; '.join(parts)}). The CoG is judged against the convex hull of the sole "
                   "corners in contact (Drake's contact forces, corners within 1 mm of the ground); statuses and "
                   "thresholds: README, section Execution. The stabilizer (beyond the thesis): "
                   "`raico/stages/execute/wbc.py`, from the standing start (`raico/plants/floating.py: stance_positions`)."]
        md += [""]
    md += balance_md
    md += noise_md
    md += processor_section([doc])
    if integ_rows:
        md += ["## Pseudo-dynamics integrators (appendix C)", "", INTEGRATOR_TEXT, "", markdown_integrators(integ_rows),
               "", "Drake's integrations (execute entries, not recorded; `raico execute --plan KEY --open-loop` "
               "records one from the cache): " + ", ".join(f"{r['variant']} seed {r['seed']} `{r['integration']}`"
                                                          for r in integ_runs), ""]
    md += ["", "## Recordings", ""] + [f"- {r['variant']} seed {r['seed']}: `{r['recording']}`" for r in runs
                                       if r["recorded"]]
    unrecorded = [r for r in runs if not r["recorded"]]
    if unrecorded:
        md += ["", f"Not recorded by `make reproduce` ({len(unrecorded)} runs: the thesis solvers' plans beyond the first "
               f"{RECORDED_SEEDS} initial states, the ablations, baselines, long-budget references and the integrator "
               "comparison; `raico show KEY --open` writes and opens a recording from the cache): " + ", ".join(f"{r['variant']} seed {r['seed']} `{r['key']}`" for r in unrecorded)]
    write_file_atomic(out_dir / "claims.md", "\n".join(md) + "\n")
    return doc


# ----------------------------------------------------------------------------- the same results in two figures
IDENTICAL_RTOL = 1e-3  # "the same" as the tables show them (3 significant digits)
RESULT_WORDS = "final cost, worst final cost, largest via-point error, divergences and convergences"


def _term(doc: dict, label: str, term: str) -> float | None:
    row = next((r for r in doc.get("summary", []) if r.get("label") == label), None)
    return None if row is None else (row.get("term_medians") or {}).get(term)


def _change(x: float | None, y: float | None, label: str) -> str:
    if x is None or y is None or not (math.isfinite(x) and math.isfinite(y)):
        return f"{_fmt(x)} -> {_fmt(y)} ({label})"
    return f"{x:.4g} -> {y:.4g} ({label}, {y - x:+.3g})"


def identical_results_remarks(docs: list[dict], rtol: float = IDENTICAL_RTOL) -> dict[str, list[str]]:
    """Markdown remarks on pairs of figures (claims.json documents of the planning experiments, in
    order) that give the same results for some variants (``raico.stages.evaluate.summary.identical_variants``
    on their summaries, relative ``rtol``): figure id of the pair's second figure -> its lines. Each
    remark names the variants, the largest relative difference, the terms by which the two problems
    differ and their measured medians on the final plans."""
    from raico.stages.evaluate.summary import identical_variants

    plan_docs = [d for d in docs if d.get("figure") in EXPERIMENTS and d.get("summary")]
    by_id = {d["figure"]: d for d in docs}
    out: dict[str, list[str]] = {}
    for i, a in enumerate(plan_docs):
        for b in plan_docs[i + 1:]:
            same = identical_variants(a["summary"], b["summary"], rtol)
            if not same:
                continue
            labels = [lab for lab, _ in same]
            fa, fb = a["figure"], b["figure"]
            text = (f"**{fa} and {fb} give the same results for {', '.join(labels)}**: {RESULT_WORDS} agree to a "
                    f"relative {max(d for _, d in same):.2g} (the tables show 3 significant digits).")
            ta = set(next(r for r in a["summary"] if r["label"] == labels[0]).get("term_medians") or {})
            tb = set(next(r for r in b["summary"] if r["label"] == labels[0]).get("term_medians") or {})
            extra = [(t, fb) for t in sorted(tb - ta)] + [(t, fa) for t in sorted(ta - tb)]
            if extra:
                text += (f" The problems differ by the term{'s' if len(extra) > 1 else ''} "
                         + ", ".join(f"{t} ({f} only)" for t, f in extra) + ".")
                parts = []
                for t, f in extra:
                    costs = [(lab, _term(by_id[f], lab, t)) for lab in labels]
                    parts.append(f"{t} costs " + ", ".join(f"{_fmt(v)} ({lab})" for lab, v in costs if v is not None))
                for t in sorted(ta & tb):
                    vals = [(lab, _term(a, lab, t), _term(b, lab, t)) for lab in labels]
                    parts.append(f"{t} " + ", ".join(_change(x, y, lab) for lab, x, y in vals))
                text += (f" Measured on the final plans (median over the runs, {fa} -> {fb} where both have the "
                         f"term): " + "; ".join(parts) + ".")
            text += " Why: not examined."   # the remark says what agrees; a reason needs a measurement
            out.setdefault(fb, []).append(text)
    return out


# ----------------------------------------------------------------------------- learning figures
def folder_name(fid: str) -> str:
    """An experiment id as a folder name (``fig4.1/4.2`` -> ``fig4.1-4.2``)."""
    return fid.replace("/", "-")


def _learn_panel(ax, S: dict, labels: list[str], key: str, ylabel: str, band: bool = False, tag: str = "",
                 style: str = "-") -> None:
    for i, lab in enumerate(labels):
        curve = np.array(S[lab].get(f"{key}_curve", []), float)
        if curve.size:
            x = np.arange(1, curve.size + 1)
            div = sum(S[lab].get("diverged_by_seed") or [])
            note = f"; {div} diverged executions, not drawn" if div else ""
            line, = ax.plot(x, curve, style, marker=".", color=f"C{i}", label=f"{lab}{tag} (n={S[lab]['runs']}{note})")
            lohi = np.array(S[lab].get(f"{key}_band", []), float)
            if band and lohi.shape == (curve.size, 2):
                ax.fill_between(x, lohi[:, 0], lohi[:, 1], color=line.get_color(), alpha=0.15, linewidth=0)
    ax.set_yscale("log")
    ax.set_xlabel("episode")
    ax.set_ylabel(ylabel)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)


def write_learn_figure(exp, S: dict, path: Path) -> None:
    """Thesis-style panels, median over seeds per episode: GP prediction error and planned-vs-
    executed RMSE per setting (fig4.2: one row per weight); fit time per evaluation (fig4.3)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if exp.plant == "pendulum":
        rows = [("w=0.01", "small weight w = 1e-2"), ("w=100", "large weight w = 1e2")]
        fig, axes = plt.subplots(2, 2, figsize=(11, 7.5), squeeze=False)
        for r, (tag, title) in enumerate(rows):
            labels = [lab for lab in S if tag in lab or lab == "sigma*=none"]
            _learn_panel(axes[r, 0], S, labels, "gp_error", "GP prediction error (rad/s^2, RMSE)")
            _learn_panel(axes[r, 1], S, labels, "rmse_planned_executed", "RMSE planned vs executed (rad)")
            axes[r, 0].set_title(f"({'AC'[r]}) GP error, {title}", fontsize=9)
            axes[r, 1].set_title(f"({'BD'[r]}) task RMSE, {title}", fontsize=9)
    else:
        fig, axes = plt.subplots(1, 3, figsize=(15, 4.6), squeeze=False)
        labels = list(S)
        _learn_panel(axes[0, 0], S, labels, "gp_error", "GP prediction error (rad/s^2, RMSE)", band=True,
                     tag=": next execution")
        _learn_panel(axes[0, 0], S, labels, "gp_error_heldout", "GP prediction error (rad/s^2, RMSE)", tag=": held-out",
                     style="--")
        axes[0, 0].set_title("(B) GP error: next execution (band: seeds), held-out (dashed)", fontsize=9)
        _learn_panel(axes[0, 1], S, labels, "fit_time_s", "time per evaluation (s)", band=True, tag=": fit")
        _learn_panel(axes[0, 1], S, labels, "plan_time_s", "time per evaluation (s)", tag=": plan", style="--")
        _learn_panel(axes[0, 1], S, labels, "execute_time_s", "time per evaluation (s)", tag=": execute", style=":")
        axes[0, 1].set_title("(C) time per evaluation: fit, plan, execute", fontsize=9)
        _learn_panel(axes[0, 2], S, labels, "task_error", "distance to the target (m)", band=True, tag=": executed")
        _learn_panel(axes[0, 2], S, labels, "planned_task_error", "distance to the target (m)", tag=": planned",
                     style="--")
        axes[0, 2].axhline(0.05, color="k", lw=0.8, ls=":", label="achieved below 5 cm")
        axes[0, 2].legend(fontsize=6)
        axes[0, 2].set_title("(D) distance to target: executed (band), planned (dashed)", fontsize=9)
        axes[0, 0].set_xlabel("evaluation")
        axes[0, 1].set_xlabel("evaluation")
        axes[0, 2].set_xlabel("evaluation")
    letters = ("; panels lettered as the thesis's Fig. 4.3, whose (A), snapshots of the movement, is the motion "
               "figure below" if exp.plant != "pendulum" else "")
    fig.suptitle(f"{exp.id}: {exp.plant} {exp.task}, learned GP dynamics (lines: median over seeds{letters})",
                 fontsize=10)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)


def write_learn_motion(cache: Cache, exp, learns: list[dict], label: str, path: Path) -> str | None:
    """The last episode of ``label``'s first seed: planned vs executed (pendulum angle; arm's
    end-effector x and z against the target). Returns the run's learn key."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from raico.pipeline.engine.artifacts import as_artifact
    from raico.plants.robots import shared_robot
    from raico.plants.taskmaps import EndEffectorPosition

    run = next((x for x in learns if x["setting"].label == label), None)
    if run is None:
        return None
    doc = as_artifact(cache.require("learn", run["outcome"].key)).document("episodes.json")
    last = doc["episodes"][-1]
    plan = as_artifact(cache.require("plan", last["plan"]))
    P, R = plan.arrays("plan.npz"), as_artifact(cache.require("execute", last["execute"])).arrays("rollout.npz")
    t = P["times"]
    fig, ax = plt.subplots(figsize=(6.5, 4))
    if exp.plant == "pendulum":
        ax.plot(t, P["X"][:, 0], label="planned (GP model)")
        ax.plot(R["times"], R["X"][:, 0], "--", label="executed (Drake)")
        ax.axhline(np.pi, color="k", lw=0.8, label="upright (pi)")
        ax.axhline(-np.pi, color="k", lw=0.8)
        ax.set_ylabel("pendulum angle q (rad, 0 hanging)")
    else:
        robot = shared_robot(exp.plant)
        ee = EndEffectorPosition(robot, "ee")
        target = np.array(plan.document("problem.json")["terms"][0]["target"])
        for lab, X, style in (("planned", P["X"], "-"), ("executed", R["X"], "--")):
            good = np.all(np.isfinite(X), axis=1)
            pts, _ = ee.values_and_jacobians(X[good, :robot.n_q])
            for i, axis in ((0, "x"), (2, "z")):
                ax.plot(t[good], pts[:, i], style, label=f"{lab} {axis}")
        for i in (0, 2):
            ax.plot(t[-1], target[i], "o", color="k")
        ax.set_ylabel("end-effector position (m)")
    ax.set_xlabel("time (s)")
    ax.set_title(f"{exp.id}: {label}, seed {run['seed']}, episode {last['episode']}", fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
    return run["outcome"].key


LEVEL = 2.0  # a curve "stays near its level" when its last three values' mean is within a factor 2 of its first three's


def heldout_sentence(label: str, s: dict) -> str | None:
    """What setting ``label``'s held-out GP error does over the episodes (``summarize_learn``'s
    ``gp_error_heldout_curve``, median over seeds), with the numbers; None without one."""
    c = np.array(s.get("gp_error_heldout_curve") or [], float)
    c = c[np.isfinite(c)]
    if c.size < 6:
        return None
    first, last = float(np.mean(c[:3])), float(np.mean(c[-3:]))
    ratio = last / first if first > 0 else math.nan
    if 1 / LEVEL <= ratio <= LEVEL:
        trend = ("stays near its level and does not fall towards zero (every episode within a factor "
                 f"{LEVEL:g} of the first three's mean)" if first / LEVEL <= c.min() and c.max() <= first * LEVEL
                 else "ends near its first level")
    else:
        trend = "falls" if ratio < 1 / LEVEL else "rises"
    nxt = s.get("gp_error_first3"), s.get("gp_error_last3")
    return (f"{label}: the GP error on the held-out babbling data {trend}: {_fmt(first)} rad/s^2 over the first three "
            f"episodes, {_fmt(last)} over the last three (x{_fmt(ratio)}; lowest {_fmt(float(c.min()))}, highest "
            f"{_fmt(float(c.max()))}; median over seeds), while the error on the next execution goes from "
            f"{_fmt(nxt[0])} to {_fmt(nxt[1])}.")


def endings_sentence(S: dict, tol: float = 0.1) -> str | None:
    """Where the swing-up's endings lie (``task_error_last_by_seed``: each setting and seed's last episode, rad from
    upright, those within ``tol``): how many lie within the claims' tie (1 mrad) of their median, with the executed
    torque's share of steps at its limit and the GP error on the next execution of those settings, and the others
    named. None with fewer than two endings."""
    from raico.thesis.claims import TIE

    pts = [(k, i, x) for k, s in S.items() for i, x in enumerate(s.get("task_error_last_by_seed") or []) if x <= tol]
    if len(pts) < 2:
        return None
    med = float(np.median([x for _, _, x in pts]))
    near = [p for p in pts if abs(p[2] - med) < TIE]
    far = [p for p in pts if abs(p[2] - med) >= TIE]
    together = {k for k, _, _ in near} - {k for k, _, _ in far}
    sat = [S[k]["torque_saturation_curve"][-1] for k in together if S[k].get("torque_saturation_curve")]
    gp = [S[k]["gp_error_curve"][-1] for k in together if S[k].get("gp_error_curve")]
    xs = [x for _, _, x in near]
    text = (f"{len(near)} of the {len(pts)} endings within {tol:g} rad of upright (setting and seed, last episode) lie "
            f"within {TIE * 1e3:g} mrad of {_fmt(med)} rad (from {_fmt(min(xs))} to {_fmt(max(xs))})")
    if sat and gp:
        text += (f"; in the settings that end there every time, the executed torque is at its limit in "
                 f"{_share(min(sat))}-{_share(max(sat))} of the last episode's steps and the GP error on the next "
                 f"execution is {_fmt(min(gp))}-{_fmt(max(gp))} rad/s^2: their plans converge to one optimum of the "
                 "task's cost on a model this accurate, where the uncertainty term, small along the data, no longer "
                 "separates the settings")
    if far:
        text += "; the others: " + ", ".join(f"{k} seed {i} at {_fmt(x)} rad" for k, i, x in far)
    return text + "."


def learn_findings(S: dict) -> list[str]:
    """Sentences on a learning figure's curves, from the numbers: the held-out GP error of each setting, where the
    settings that swing up end, and, for the hyperparameter schedules, the measured ratio of their fit times."""
    out = [x for lab, s in S.items() if (x := heldout_sentence(lab, s))]
    if any("sigma*" in k for k in S):
        out += [x for x in [endings_sentence({k: v for k, v in S.items() if not k.endswith(", x0 held")})] if x]
    div = {k: s["diverged_by_seed"] for k, s in S.items() if sum(s.get("diverged_by_seed") or [])}
    if div:
        out.append("Diverged executions (the simulation blew up; no data, left out of every curve and median), per "
                   "seed: " + "; ".join(f"{k}: {', '.join(map(str, d))} of {S[k].get('episodes', '?')} episodes"
                                        for k, d in div.items()) + ".")
    e, b = S.get("every"), S.get("batch-100")
    if e and b and b.get("fit_time_s_total"):
        out.append(f"Fit time over the whole loop (median over seeds): every {_fmt(e['fit_time_s_total'])} s, batch-100 "
                   f"{_fmt(b['fit_time_s_total'])} s: 'every' takes {_fmt(e['fit_time_s_total'] / b['fit_time_s_total'])}"
                   "x as long.")
    return out


def write_learn_report(cache: Cache, exp, result: dict, out_dir: Path) -> dict:
    """``figure.png``, ``motion.png``, ``claims.md``/``claims.json`` of a learning experiment."""
    from raico.thesis.claims import evaluate_claims
    from raico.thesis.figures import LEAVE_ONE_OUT_MIN, summarize_learns

    out_dir.mkdir(parents=True, exist_ok=True)
    learns = result["learns"]
    S = summarize_learns(learns)
    write_learn_figure(exp, S, out_dir / "figure.png")
    best = "sigma*=0, w=0.01" if exp.plant == "pendulum" else "every"
    motion_key = write_learn_motion(cache, exp, learns, best, out_dir / "motion.png")
    seeds = sorted({x["seed"] for x in learns})
    without = ({k: summarize_learns(learns, leave_out=k) for k in seeds} if len(seeds) >= LEAVE_ONE_OUT_MIN else {})
    rows = evaluate_claims(exp.claims, S, [], exp.id, without=without)
    runs = [{"setting": x["setting"].label, "seed": x["seed"], "key": x["outcome"].key,
             "recording": x["outcome"].recording or str(Path(x["outcome"].path) / "recording.rrd"),
             "first_success_episode": x["outcome"].metrics.get("first_success_episode")} for x in learns]
    summary = [{k: v for k, v in s.items() if not k.endswith("_curve")} for s in S.values()]
    doc = {"figure": exp.id, "description": exp.description, "claims": rows, "summary": summary, "runs": runs,
           "executions": [], "motion_run": motion_key, "findings": learn_findings(S)}
    write_file_atomic(out_dir / "claims.json", json.dumps(doc, indent=2, default=float))
    md = [f"# {exp.id}: {exp.description}", "", "![figure](figure.png)", "", "![motion](motion.png)", "",
          "## Claims", "", markdown_claims(rows), "", "## Settings (medians over seeds)", "",
          "| setting | seeds | GP error first 3 -> last 3 (rad/s^2) | RMSE first 3 -> last 3 (rad) | achieved in the "
          "last episode | executed s to first success | total fit time (s) | optimizations |",
          "|---|---|---|---|---|---|---|---|"]
    md += [f"| {s['label']} | {s['runs']} | {_fmt(s['gp_error_first3'])} -> {_fmt(s['gp_error_last3'])} | "
           f"{_fmt(s['rmse_planned_executed_first3'])} -> {_fmt(s['rmse_planned_executed_last3'])} | "
           f"{s['achieved_last']}/{s['runs']} | {', '.join(_fmt(x) for x in s['seconds_to_success'])} | "
           f"{_fmt(s['fit_time_s_total'])} | {s['optimizations']} |" for s in summary]
    findings = doc["findings"]
    if findings:
        md += ["", "## What the curves say", ""] + [f"- {line}" for line in findings]
    md += ["", "## Choices", ""] + [f"- {k}: {v}" for k, v in exp.notes]
    md += ["", "## Recordings", ""] + [f"- {r['setting']} seed {r['seed']}: `{r['recording']}`" for r in runs]
    write_file_atomic(out_dir / "claims.md", "\n".join(md) + "\n")
    return doc
