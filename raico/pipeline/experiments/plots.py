"""``raico plot``: an experiment's runs table as figures (PNG, matplotlib's Agg backend).

Four kinds, each over the seeds of every group of runs (a group: the runs that share the grouping
options, by default every swept option but the x axis's); what each draws is documented in
docs/experiment-files.md:

- ``line``: a metric against a swept option: the median over the seeds at each x and the
  interquartile range as a band. A group that has one x value only because it does not use the option
  (iLQG has no alpha) is drawn as a dashed horizontal line at its median, its band across the plot: a
  baseline to compare the lines with; a group that uses it at one value is a point there.
  On a categorical option (solver, schedule) the groups are points with the interquartile range as
  error bars. Every group has its own colour, marker and line style; a group without a finite value is
  in the legend with ``n=0``.
- ``curve``: the cost per iteration (``plan.npz`` ``costs`` of each run's plan), median and
  interquartile band per group on a log axis; a run that stopped early holds its last cost, a diverged
  run drops out from its divergence on.
- ``wall``: the cost against wall time (each run's cost of the last iteration finished by each time,
  ``plan.npz`` ``elapsed``), median and interquartile band per group on log axes.
- ``box``: a box per group (median, quartiles, whiskers at 1.5 IQR) with every run as a dot beside it.

The cost axes (``curve``, ``wall``) span the finite values that do not explode (:func:`clip_range`:
FDDP's infeasible early iterates reach 1e35 and more, which would flatten every other curve); what is
left out is said in the figure and by ``raico plot``. ``--ylim LO,HI`` sets the value axis of any kind.
Axes name their unit (:func:`axis_label`).

Legends name the groups by the options that differ between them, leaving out those a group's runs
do not use; a group whose runs use none of them by its variants' names (``AICO, iLQG``); never by
keys. Each legend entry says how many runs it shows (``n=8/10``: two runs had no finite value).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from raico.pipeline.errors import BadInput, check_folder

KINDS = ("line", "curve", "wall", "box")
EXPLODE_DECADES = 3.0  # a value this many decades above the bulk's upper quartile (or more) is exploding


@dataclass
class Plot:
    """A written figure and what it draws per legend entry (group label -> ``x``, ``median``, ``q25``,
    ``q75``, ``n``: the numbers behind the lines, bands and boxes)."""

    path: Path
    series: dict[str, dict[str, Any]] = field(default_factory=dict)
    clipped: str = ""  # what the value axis leaves out ("" if nothing), as the figure says it
    limits: tuple[float, float] | None = None  # the value axis's range where it was set (--ylim, or clipped)
    line: str = ""  # what raico plot says of it (plot_experiment)


@dataclass
class Clip:
    """The value axis's range (``lo``, ``hi``; None: the data's own) and what it leaves out: ``above`` /
    ``below`` values beyond it (the largest above: ``top``), ``nonfinite`` values (inf, NaN) that no
    axis shows."""

    lo: float | None
    hi: float | None
    above: int = 0
    below: int = 0
    top: float | None = None
    nonfinite: int = 0
    reason: str = "exploding"
    what: str = "value"   # what is counted: a run's value, or a drawn point of a curve

    def text(self) -> str:
        """One phrase for the figure and the command's line ("" if nothing is left out)."""
        parts = []
        if self.above:
            parts.append(f"{self.above} {self.what}{'s' if self.above > 1 else ''} above {self.hi:.3g} "
                         f"(up to {self.top:.3g}; {self.reason})")
        if self.below:
            parts.append(f"{self.below} below {self.lo:.3g} ({self.reason})")
        if self.nonfinite:
            parts.append(f"{self.nonfinite} not finite")
        return ("clipped: " + "; ".join(parts)) if parts else ""


def clip_range(values: np.ndarray, log: bool, ylim: tuple[float, float] | None = None,
               first: np.ndarray | None = None) -> Clip:
    """The value axis for ``values`` (any shape): ``ylim`` if given, else the finite values that do not
    explode. Exploding: more than :data:`EXPLODE_DECADES` decades (or three interquartile ranges, if
    wider) above the upper quartile of the values' magnitudes (log10), and more than ten times the
    lowest of ``first`` (each run's first finite cost: where the runs start is not exploding, however far
    above their ends; an early iterate that explodes is the first cost of its run, so the lowest). On a
    log axis values <= 0 count as not finite."""
    v = np.ravel(np.asarray(values, float))
    ok = np.isfinite(v) & ((v > 0) if log else True)
    nonfinite, v = int((~ok).sum()), v[ok]
    if ylim is not None:
        lo, hi = ylim
        return Clip(lo, hi, int((v > hi).sum()), int((v < lo).sum()), float(v.max()) if (v > hi).any() else None,
                    nonfinite, "beyond --ylim")
    if not v.size:
        return Clip(None, None, nonfinite=nonfinite)
    mag = np.log10(np.maximum(np.abs(v), np.finfo(float).tiny))
    q25, q75 = np.percentile(mag, [25, 75])
    fence = q75 + max(3.0 * (q75 - q25), EXPLODE_DECADES)
    f = np.asarray(first if first is not None else [], float)
    f = f[np.isfinite(f) & (f != 0)]
    if f.size:
        fence = max(fence, float(np.log10(np.min(np.abs(f)))) + 1.0)
    out = mag > fence
    kept = v[~out]
    lo, hi = float(kept.min()), float(kept.max())
    if log:
        lo, hi = 10 ** (np.log10(lo) - 0.1), 10 ** (np.log10(hi) + 0.1)
    else:
        pad = 0.05 * (hi - lo) or 0.05 * max(abs(hi), 1e-300)
        lo, hi = lo - pad, hi + pad
    top = float(v[out].max()) if out.any() else None
    return Clip(lo, hi, int((out & (v > 0)).sum()), int((out & (v < 0)).sum()), top, nonfinite)


def parse_ylim(text: str | None) -> tuple[float, float] | None:
    """``--ylim LO,HI`` as two finite numbers with LO < HI (:class:`BadInput` otherwise)."""
    if text is None:
        return None
    try:
        lo, hi = (float(x) for x in text.split(","))
    except ValueError:
        raise BadInput(f"--ylim {text}: give two numbers LO,HI, e.g. --ylim 1e2,1e5") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise BadInput(f"--ylim {text}: LO < HI, both finite")
    return lo, hi


# units of the runs table's metric columns, by the metric's name (its last part) or suffix
UNITS = {"final_cost": "", "initial_cost": "", "first_iteration_cost": "", "first": "", "last": "", "min": "",
         "cost": "",
         "cost_ratio": "final over initial", "iterations": "count", "iterations_to_1pct": "iterations",
         "episodes": "count", "rmse_planned_executed": "rad", "task_error": "m", "gp_error": "rad/s^2",
         "samples": "count", "failure_time": "s"}
SUFFIX_UNITS = (("_s", "s"), ("_m", "m"), ("_rad", "rad"), ("_ms", "ms"), ("_pct", "%"), ("_nm", "N m"))
OPTION_UNITS = {"dt": "s", "q0_std": "rad", "T": "steps", "iterations": "count", "duration": "s"}


def axis_label(column: str) -> str:
    """A runs-table column with its unit: ``plan.final_cost (cost, no unit)``, ``plan.wall_time_s (s)``,
    ``plan.via_point_errors.via_x1@500 (the term's unit: m or rad)``; a column of unknown unit as it is."""
    name = str(column)
    last = name.split(".")[-1]
    if ".via_point_errors." in f".{name}" or last.startswith("via_"):
        return f"{name} (the term's unit: m for positions, rad for angles)"
    if "." not in name:   # an option on the x axis
        return f"{name} ({OPTION_UNITS[name]})" if name in OPTION_UNITS else name
    if last in UNITS:   # "": a cost (a weighted sum of squares, no unit)
        return f"{name} ({UNITS[last] or 'cost, no unit'})"
    for suffix, unit in SUFFIX_UNITS:
        if last.endswith(suffix):
            return f"{name} ({unit})"
    return name
COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
          "#17becf")
BAND_ALPHA = 0.2
MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")
LINESTYLES = ("-", "--", "-.", ":")


# ----------------------------------------------------------------------------- groups and their names
def grouping(df, swept: list[str], by: Sequence[str] | None, x: str | None = None) -> list[str]:
    """The options that make the groups: ``by`` (checked against the table), else every swept option
    that varies in ``df`` but ``x``."""
    if by:
        missing = [b for b in by if b not in df.columns]
        if missing:
            raise BadInput(f"--group {missing[0]}: no such column; options: {', '.join(swept) or 'none'}")
        return [b for b in by if b != x]
    return [s for s in swept if s != x and s in df.columns and df[s].astype(str).nunique() > 1]


def groups(df, by: list[str]) -> list[tuple[dict[str, Any], Any]]:
    """``[(options, rows)]`` of ``df`` grouped by ``by``, in the table's order (one group if ``by`` is empty)."""
    if not by:
        return [({}, df)]
    out = []
    for values, g in df.groupby(by, sort=False, dropna=False):
        values = values if isinstance(values, tuple) else (values,)
        out.append((dict(zip(by, (_plain(v) for v in values))), g))
    return out


def _plain(v: Any) -> Any:
    if hasattr(v, "item"):
        v = v.item()
    return None if isinstance(v, float) and math.isnan(v) else v


def option_text(v: Any) -> str:
    """An option's value as a label shows it (floats in ``%g``)."""
    return f"{v:g}" if isinstance(v, float) else str(v)


def unused_options(cache, row, options: Sequence[str], others: dict[str, set]) -> set[str]:
    """:func:`raico.pipeline.experiments.expfile.unused_in` for the run of a runs-table ``row`` (its first stage's ``meta.json``);
    none without a cache or an entry."""
    from raico.pipeline.experiments.expfile import entry_meta, unused_in

    cols = [c for c in row.index if str(c).endswith(".key")]
    if cache is None or not cols or not isinstance(row[cols[0]], str):
        return set()
    stage = cols[0][:-4]
    return unused_in(stage, entry_meta(cache, stage, row[cols[0]]).get("config") or {}, options, others)


def _variant_names(rows) -> str:
    """The variants (their labels: a ``[[point]]``'s own, a grid variant's ``option=value``) of a group's runs."""
    if "variant" not in rows.columns:
        return ""
    return ", ".join(str(v) for v in dict.fromkeys(rows["variant"].map(_plain)) if v is not None)


def labels(cache, grouped: list[tuple[dict[str, Any], Any]], drop_unused: bool = True) -> list[str]:
    """A legend entry per group: the options whose values differ between the groups (``option=value``),
    without those the group's runs do not use (:func:`unused_options`); a group whose runs use none of them
    (AICO, iLQG and FDDP where the groups differ in R-AICO's schedule) by its variants' names, as the
    experiment file calls them; ``all runs`` for a single group."""
    if len(grouped) == 1 and not grouped[0][0]:
        return ["all runs"]
    keys = list(grouped[0][0])
    values = {k: {opts.get(k) for opts, _ in grouped} for k in keys}
    differ = [k for k in keys if len({option_text(v) for v in values[k]}) > 1] or keys
    out = []
    for opts, rows in grouped:
        skip = unused_options(cache, rows.iloc[0], differ, values) if drop_unused else set()
        parts = [f"{k}={option_text(opts[k])}" for k in differ if k not in skip]
        out.append(", ".join(parts) or _variant_names(rows) or ", ".join(f"{k}={option_text(opts[k])}" for k in differ))
    if len(set(out)) < len(out):   # dropping unused options made two the same: name every differing option
        out = [", ".join(f"{k}={option_text(opts[k])}" for k in differ) for opts, _ in grouped]
    return out


# ----------------------------------------------------------------------------- the figures
def _numbers(series) -> np.ndarray:
    import pandas as pd

    return pd.to_numeric(series, errors="coerce").to_numpy(float)


def _log_scale(values: np.ndarray, mode: str) -> bool:
    v = values[np.isfinite(values)]
    if mode == "log":
        if v.size and v.min() <= 0:
            raise BadInput("--yscale log: the values include zero or negative ones")
        return True
    if mode == "linear" or not v.size:
        return False
    return bool(v.min() > 0 and v.max() / v.min() >= 100)


def _n_text(n: int, total: int) -> str:
    return f"n={n}" if n == total else f"n={n}/{total}"


def _figure(title: str, subtitle: str):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 6), dpi=100)
    ax.set_title(f"{title}\n{subtitle}", fontsize=10)
    ax.grid(True, which="major", alpha=0.3)
    return fig, ax


LEGEND_COLUMN = 60   # characters: longer entries take the whole width (two columns would leave the figure)


def _legend(ax, entries: int) -> None:
    """The legend below the axes (it never hides a line or a band), in two columns when it is long and its
    entries are short enough to fit side by side."""
    if entries:
        longest = max((len(t) for t in ax.get_legend_handles_labels()[1]), default=0)
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.12),
                  ncol=2 if entries > 3 and longest <= LEGEND_COLUMN else 1, frameon=False)


def _save(fig, out: Path, series: dict[str, dict[str, Any]], clip: Clip | None = None) -> Plot:
    import matplotlib.pyplot as plt

    from raico.pipeline.engine.atomic import atomic_path

    text = clip.text() if clip is not None else ""
    if text:   # said in the figure, below its title
        ax = fig.axes[0]
        ax.set_title(f"{ax.get_title()}\n{text}", fontsize=10)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)
    return Plot(out, series, text, None if clip is None or clip.lo is None else (clip.lo, clip.hi))


def _dodge(i: int, n: int, width: float = 0.3) -> float:
    """The offset of the ``i``-th of ``n`` groups drawn side by side at a category (category units)."""
    return 0.0 if n <= 1 else (i - (n - 1) / 2) * width / (n - 1)


def _apply_ylim(ax, values: np.ndarray, log: bool, ylim: tuple[float, float] | None,
                explode: bool = False, first: np.ndarray | None = None, axis: str = "y") -> Clip | None:
    """Set the value axis to ``ylim``, or (``explode``) to :func:`clip_range`'s; the clip, or None when
    the axis is left to matplotlib."""
    if ylim is None and not explode:
        return None
    if ylim is not None and log and ylim[0] <= 0:
        raise BadInput(f"--ylim {ylim[0]:g},{ylim[1]:g}: a log axis needs LO > 0 (or --yscale linear)")
    clip = clip_range(values, log, ylim, first)
    if clip.lo is not None:
        (ax.set_ylim if axis == "y" else ax.set_xlim)(clip.lo, clip.hi)
    return clip


def _style(i: int) -> dict[str, Any]:
    """Group ``i``'s colour, marker and line style: no two of the first ten groups share all three, and the
    markers shrink from group to group, so a marker drawn over another leaves the one below in sight."""
    return {"color": COLORS[i % len(COLORS)], "marker": MARKERS[i % len(MARKERS)],
            "ls": LINESTYLES[i % len(LINESTYLES)], "ms": max(9.0 - 1.2 * (i % 5), 4.0)}


def _style_key(style: dict[str, Any]) -> tuple[str, str, str]:
    return style["color"], style["marker"], style["ls"]


def line_plot(df, swept: list[str], x: str, metric: str, out: Path, name: str, cache=None,
              by: Sequence[str] | None = None, yscale: str = "auto", ylim: tuple[float, float] | None = None) -> Plot:
    """``metric`` against option ``x``: median and interquartile band over the seeds per group; on a
    categorical ``x`` a point per category with the interquartile range as an error bar (no line: the
    categories have no order between them), the groups side by side. A group that does not use ``x``
    (iLQG has no alpha) is a horizontal baseline across the plot; one that uses it at a single value is a
    point there. Each group has its own colour, marker and line style (:func:`_style`); a group without a
    finite value is a legend entry that says so."""
    by = grouping(df, swept, by, x)
    grouped = groups(df, by)
    names = labels(cache, grouped)
    xs_all = df[x].map(_plain)
    numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in xs_all if v is not None)
    single = [rows[x].map(_plain).nunique(dropna=False) == 1 for _, rows in grouped]
    varied = not all(single)
    # a baseline: a group at one x value because it does not use x (its normalized config ignores it)
    everyone = {v for v in xs_all if v is not None}
    baseline = [varied and one and x in unused_options(cache, rows.iloc[0], [x], {x: everyone})
                for (_, rows), one in zip(grouped, single)]
    # the axis spans the x values of the groups that use x (a baseline's value, e.g. iLQG's alpha 0, is no point on it)
    on_axis = [v for (_, rows), flat in zip(grouped, baseline) if not flat for v in rows[x].map(_plain)] or list(xs_all)
    order = sorted({v for v in on_axis if v is not None}, key=(float if numeric else str))
    pos = (lambda v: float(v)) if numeric else (lambda v: float(order.index(v)))
    fig, ax = _figure(f"{name}: {metric} against {x}",
                      f"median over the seeds, {'band' if numeric else 'error bar'}: interquartile range "
                      f"({df['seed'].nunique()} seeds)")
    every = _numbers(df[metric])
    entries, flat, series = 0, [], {}
    dodged = [label for label, flat_ in zip(names, baseline) if not flat_]   # drawn at their x values, side by side
    for i, ((_, rows), label, is_flat) in enumerate(zip(grouped, names, baseline)):
        style = _style(i)
        pts = []
        for xv, g in rows.groupby(rows[x].map(_plain), sort=False, dropna=False):
            v = _numbers(g[metric])
            v = v[np.isfinite(v)]
            pts.append((xv, v, len(g)))
        if is_flat:   # across the plot
            flat.append((label, style, pts[0][1], pts[0][2], f"does not use {x}"))
            continue
        pts = sorted((p for p in pts if p[0] is not None), key=lambda p: pos(p[0]))
        X = np.array([pos(p[0]) for p in pts])
        med = np.array([np.median(p[1]) if p[1].size else np.nan for p in pts])
        lo = np.array([np.percentile(p[1], 25) if p[1].size else np.nan for p in pts])
        hi = np.array([np.percentile(p[1], 75) if p[1].size else np.nan for p in pts])
        ns, totals = [p[1].size for p in pts], [p[2] for p in pts]
        n_text = (f"n={ns[0]}" if len(set(ns)) == 1 and ns == totals else
                  f"n={min(ns)}-{max(ns)} of {max(totals)}" if min(ns) != max(ns) else f"n={ns[0]}/{max(totals)}")
        joined = numeric and len(X) > 1
        series[label] = {"x": [p[0] for p in pts], "median": med.tolist(), "q25": lo.tolist(), "q75": hi.tolist(),
                         "n": ns, "drawn": "line" if joined else "points", "style": _style_key(style)}
        at = f", at {x}={option_text(pts[0][0])} only" if numeric and len(X) == 1 and varied else ""
        text = f"{label} ({n_text} per point{at})" if max(ns) else f"{label} (n=0/{max(totals)}: no finite value)"
        if joined:
            ax.plot(X, med, color=style["color"], ls=style["ls"], marker=style["marker"], ms=style["ms"] * 0.7,
                    lw=1.8, label=text)
            ax.fill_between(X, lo, hi, color=style["color"], alpha=BAND_ALPHA, lw=0)
        else:   # categories, or one value: points and error bars, side by side, never joined
            if not numeric:
                X = X + _dodge(dodged.index(label), len(dodged))
            ax.errorbar(X, med, yerr=np.vstack([med - lo, hi - med]), fmt=style["marker"], color=style["color"],
                        ms=style["ms"], capsize=4, lw=1.5, label=text)
        entries += 1
    for k, (label, style, v, total, why) in enumerate(flat):
        entries += 1
        if not v.size:   # nothing to draw: the legend says so rather than leaving the group out
            ax.plot([], [], color=style["color"], ls=style["ls"], marker=style["marker"],
                    label=f"{label} (n=0/{total}: no finite value; {why})")
            series[label] = {"x": None, "median": [], "q25": [], "q75": [], "n": [0], "style": _style_key(style)}
            continue
        # across the axes (x in axes units), its markers placed apart from every other baseline's
        marks = 1 + (2 * k) % 8
        ax.plot(np.linspace(0.0, 1.0, 41), np.full(41, np.median(v)), transform=ax.get_yaxis_transform(),
                color=style["color"], ls=style["ls"] if style["ls"] != "-" else "--", lw=1.5, marker=style["marker"],
                ms=style["ms"] * 0.7, markevery=(marks, 8), label=f"{label} ({_n_text(v.size, total)}; {why})")
        q25, q75 = np.percentile(v, [25, 75])
        series[label] = {"x": None, "median": [float(np.median(v))], "q25": [float(q25)], "q75": [float(q75)],
                         "n": [v.size], "style": _style_key(style), "marks_from": marks}
        ax.axhspan(q25, q75, color=style["color"], alpha=BAND_ALPHA * 0.6, lw=0)
    if numeric:
        xv = np.array(order, float)
        if xv.size > 1 and xv.min() > 0 and xv.max() / xv.min() >= 10:
            ax.set_xscale("log")
        ax.set_xticks(xv)
        ax.set_xticklabels([option_text(v) for v in order])
        ax.minorticks_off() if ax.get_xscale() == "log" else None
    else:
        ax.set_xticks(range(len(order)))
        ax.set_xticklabels([str(v) for v in order])
        ax.set_xlim(-0.5, len(order) - 0.5)
    log = _log_scale(every, yscale)
    if log:
        ax.set_yscale("log")
    clip = _apply_ylim(ax, every, log, ylim)
    ax.set_xlabel(axis_label(x) + ("" if numeric else " (categories)"))
    ax.set_ylabel(axis_label(metric))
    _legend(ax, entries)
    return _save(fig, out, series, clip)


def cost_curves(cache, keys: Sequence[Any], name: str = "costs") -> np.ndarray:
    """``(runs, iterations)`` costs of the plans ``keys`` (``plan.npz`` ``costs``; a cost that is not finite,
    such as crocoddyl's for an infeasible iterate or a diverged run's, stays so); a run that stopped early
    holds its last cost if it is finite; a run without a plan (not a key: its plan failed) is a row of NaN,
    and so is one whose ``plan.npz`` cannot be read or lacks ``name``, said in one line on stderr.
    ``name="elapsed"``: each iteration's end (s since the run started) instead, NaN after a run's last."""
    from raico.pipeline.engine.artifacts import LOAD_ERRORS, clean_error

    curves, unread = [], []
    for k in keys:
        c = np.zeros(0)
        if isinstance(k, str):
            try:
                with np.load(cache.root / "plan" / k / "plan.npz", allow_pickle=False) as f:
                    c = np.asarray(f[name], float)
            except (OSError, *LOAD_ERRORS) as e:
                unread.append(f"plan/{k}: {clean_error(e)}")
        curves.append(c)
    if unread:
        print(f"raico: warning: {len(unread)} of {len(curves)} plans have no readable '{name}' in plan.npz "
              f"({'; '.join(unread[:3])}{'; ...' if len(unread) > 3 else ''}): their curves are left out (NaN)",
              file=sys.stderr, flush=True)
    n = max((len(c) for c in curves), default=0)
    out = np.full((len(curves), n), np.nan)
    for i, c in enumerate(curves):
        out[i, :len(c)] = c
        if name == "costs" and len(c) and len(c) < n and np.isfinite(c[-1]):
            out[i, len(c):] = c[-1]
    return out


def first_costs(C: np.ndarray) -> np.ndarray:
    """Each run's first finite cost (NaN for a run without one), ``(runs,)``."""
    ok = np.isfinite(C)
    idx = np.argmax(ok, axis=1)
    return np.where(ok.any(axis=1), C[np.arange(C.shape[0]), idx], np.nan) if C.size else np.zeros(0)


def _column_band(A: np.ndarray, min_count: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per column of ``A (runs, points)``: the median, 25th and 75th percentile of its finite values; NaN
    where fewer than ``min_count`` (at least one) runs have one."""
    med, lo, hi = (np.full(A.shape[1], np.nan) for _ in range(3))
    for j in range(A.shape[1]):
        col = A[np.isfinite(A[:, j]), j]
        if col.size >= max(min_count, 1):
            med[j] = np.median(col)
            lo[j], hi[j] = np.percentile(col, [25, 75])
    return med, lo, hi


def _cost_axis(ax, every: list[np.ndarray], starts: list[np.ndarray], yscale: str,
               ylim: tuple[float, float] | None):
    """The cost axis of a curve or wall plot: log where asked (``auto``: where every finite cost is positive),
    clipped to the values that do not explode (``every``: the runs' stored costs; ``starts``: their first
    costs) or to ``ylim``; what was clipped."""
    values = np.concatenate(every) if every else np.zeros(0)
    finite = values[np.isfinite(values)]
    log = _log_scale(finite, "log" if yscale == "auto" and finite.size and finite.min() > 0 else yscale)
    if log:
        ax.set_yscale("log")
    ax.set_ylabel("cost (no unit; rollout on the planning model)")
    return _apply_ylim(ax, values, log, ylim, explode=True, first=np.concatenate(starts) if starts else None)


def curve_plot(df, swept: list[str], out: Path, name: str, cache, by: Sequence[str] | None = None,
               yscale: str = "log", ylim: tuple[float, float] | None = None) -> Plot:
    """The cost per iteration, median and interquartile band over the seeds per group; the cost axis
    spans the finite values that do not explode (:func:`clip_range`), or ``ylim``."""
    if "plan.key" not in df.columns:
        raise BadInput(f"{name}: no plan runs in the table (--kind curve plots the plans' cost per iteration)")
    grouped = groups(df, grouping(df, swept, by))
    names = labels(cache, grouped)
    fig, ax = _figure(f"{name}: cost per iteration", f"median over the runs with a finite cost at the iteration, "
                      f"band: interquartile range ({df['seed'].nunique()} seeds)")
    every, series, starts = [], {}, []
    shown = 0
    for (_, rows), label, color in zip(grouped, names, _cycle(len(grouped))):
        C = cost_curves(cache, list(rows["plan.key"]))
        if not C.size:
            continue
        starts.append(first_costs(C))
        it = np.arange(1, C.shape[1] + 1)
        med, lo, hi = _column_band(C)
        ended = int(np.isfinite(C[:, -1]).sum())
        text = f"n={len(rows)}" + ("" if ended == len(rows) else f"; {len(rows) - ended} without a finite last cost")
        ax.plot(it, med, color=color, lw=1.8, label=f"{label} ({text})")
        series[label] = {"x": it.tolist(), "median": med.tolist(), "q25": lo.tolist(), "q75": hi.tolist(),
                         "n": [len(rows)]}
        ax.fill_between(it, lo, hi, color=color, alpha=BAND_ALPHA, lw=0)
        every.append(C[~np.isnan(C)])   # the stored costs (inf included), not the NaN after a run's end
        shown += 1
    clip = _cost_axis(ax, every, starts, yscale, ylim)
    ax.set_xlabel("iteration (count)")
    _legend(ax, shown)
    return _save(fig, out, series, clip)


def cost_at_times(C: np.ndarray, E: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """``(runs, times)``: per run the cost of its last iteration finished by each time of ``grid``
    (``E``: each iteration's end, s since the run started); NaN before its first."""
    at = np.full((C.shape[0], grid.size), np.nan)
    for i in range(C.shape[0]):
        e = np.where(np.isfinite(E[i]), E[i], np.inf)
        k = np.searchsorted(e, grid, side="right") - 1
        ok = k >= 0
        at[i, ok] = C[i, k[ok]]
    return at


def wall_plot(df, swept: list[str], out: Path, name: str, cache, by: Sequence[str] | None = None,
              yscale: str = "log", ylim: tuple[float, float] | None = None, points: int = 200) -> Plot:
    """The cost against wall time: per run the cost of its last iteration finished by each time of a
    log-spaced grid (s, the solver's own clock), median and interquartile band over the runs of each group
    where at least half of them have one; the cost axis clipped as :func:`curve_plot`'s."""
    if "plan.key" not in df.columns:
        raise BadInput(f"{name}: no plan runs in the table (--kind wall plots the plans' cost against wall time)")
    grouped = groups(df, grouping(df, swept, by))
    names = labels(cache, grouped)
    curves = [(cost_curves(cache, list(rows["plan.key"])), cost_curves(cache, list(rows["plan.key"]), "elapsed"))
              for _, rows in grouped]
    ends = np.concatenate([E[np.isfinite(E) & (E > 0)] for _, E in curves if E.size] or [np.zeros(0)])
    if not ends.size:
        raise BadInput(f"{name}: the plans have no iteration times (plan.npz elapsed)")
    grid = np.geomspace(ends.min(), ends.max(), points)
    fig, ax = _figure(f"{name}: cost against wall time", "median over the runs of the cost of the last iteration "
                      f"finished by each time, band: interquartile range ({df['seed'].nunique()} seeds)")
    every, series, starts, shown = [], {}, [], 0
    for (_, rows), (C, E), label, color in zip(grouped, curves, names, _cycle(len(grouped))):
        if not C.size or E.shape != C.shape:
            continue
        at = cost_at_times(C, E, grid)
        med, lo, hi = _column_band(at, min_count=(C.shape[0] + 1) // 2)   # where half the runs have one
        ax.plot(grid, med, color=color, lw=1.8, label=f"{label} (n={len(rows)})")
        ax.fill_between(grid, lo, hi, color=color, alpha=BAND_ALPHA, lw=0)
        series[label] = {"x": grid.tolist(), "median": med.tolist(), "q25": lo.tolist(), "q75": hi.tolist(),
                         "n": [len(rows)]}
        every.append(C[~np.isnan(C)])
        starts.append(first_costs(C))
        shown += 1
    ax.set_xscale("log")
    clip = _cost_axis(ax, every, starts, yscale, ylim)
    ax.set_xlabel("wall time (s, the solver's own clock)")
    _legend(ax, shown)
    return _save(fig, out, series, clip)


def box_plot(df, swept: list[str], metric: str, out: Path, name: str, cache=None, by: Sequence[str] | None = None,
             yscale: str = "auto", ylim: tuple[float, float] | None = None) -> Plot:
    """A box per group of ``metric`` over its runs, every run a dot beside it."""
    grouped = groups(df, grouping(df, swept, by))
    names = labels(cache, grouped)
    fig, ax = _figure(f"{name}: {metric} per group",
                      "box: median and quartiles, whiskers to the farthest run within 1.5 IQR; dots: every run")
    data, ticks, series = [], [], {}
    for (_, rows), label in zip(grouped, names):
        v = _numbers(rows[metric])
        ok = v[np.isfinite(v)]
        data.append(ok)
        series[label] = {"x": None, "median": [float(np.median(ok))] if ok.size else [], "n": [ok.size],
                         "values": ok.tolist()}
        ticks.append(f"{label} ({_n_text(ok.size, len(v))})".replace(", ", ",\n") if len(label) > 30
                     else f"{label} ({_n_text(ok.size, len(v))})")
    rng = np.random.default_rng(0)
    colors = _cycle(len(data))
    rows = list(range(len(data)))[::-1]   # the first group on top
    for i, v, color in zip(rows, data, colors):
        if v.size:
            ax.boxplot([v], positions=[i], widths=0.45, showfliers=False, patch_artist=True, orientation="horizontal",
                       boxprops={"facecolor": color, "alpha": 0.35}, medianprops={"color": "black", "lw": 1.5})
            ax.plot(v, i - 0.36 + rng.uniform(-0.05, 0.05, v.size), "o", color=color, ms=4, alpha=0.8)
    ax.set_yticks(rows)
    ax.set_yticklabels(ticks, fontsize=8)
    ax.set_ylim(-0.8, len(data) - 0.4)
    every = np.concatenate(data) if data else np.zeros(0)
    log = _log_scale(every, yscale)
    if log:
        ax.set_xscale("log")
    clip = _apply_ylim(ax, every, log, ylim, axis="x")   # the boxes lie: the value axis is x
    ax.set_xlabel(axis_label(metric))
    return _save(fig, out, series, clip)


def _cycle(n: int) -> list[str]:
    return [COLORS[i % len(COLORS)] for i in range(n)]


def plot_experiment(cache, experiment: str, kind: str = "line", x: str | None = None,
                    metric: str = "plan.final_cost", group: Sequence[str] | None = None, where: str | None = None,
                    yscale: str = "auto", ylim: str | tuple[float, float] | None = None,
                    out: str | Path | None = None) -> Plot:
    """``raico plot``: the figure of experiment ``experiment``'s runs table (its name or file) at ``out``
    (default ``artifacts/exp/NAME/KIND-METRIC[-X].png``), with the line the command prints
    (:attr:`Plot.line`); :class:`BadInput` with the command's message on bad input."""
    from raico.pipeline.experiments import expfile

    if kind not in KINDS:
        raise BadInput(f"--kind {kind}: choose one of {', '.join(KINDS)}")
    if yscale not in ("auto", "linear", "log"):
        raise BadInput(f"--yscale {yscale}: choose auto, linear or log")
    out = Path(out) if out is not None else None
    if out is not None and out.suffix.lower() != ".png":
        raise BadInput(f"--out {out}: a .png file")
    limits = parse_ylim(ylim) if isinstance(ylim, str) or ylim is None else parse_ylim(",".join(map(str, ylim)))
    df, swept = expfile.read_table(cache, experiment)
    name = str(df["experiment"].iloc[0]) if "experiment" in df.columns and len(df) else experiment
    if kind == "line":
        if x is None:
            raise BadInput(f"--kind line needs --x OPTION: one of the swept options {', '.join(swept) or '(none)'}")
        if x not in df.columns:
            raise BadInput(f"--x {x}: no such option in the table; swept options: {', '.join(swept) or 'none'}")
    elif x is not None:
        raise BadInput(f"--x goes with --kind line (--kind {kind} has no x option)")
    if kind in ("line", "box") and metric not in expfile.metric_columns(df):
        raise BadInput(f"--metric {metric}: {'not a number' if metric in df.columns else 'no such column'}; "
                       f"metrics: {', '.join(expfile.metric_columns(df))}")
    df = expfile.query(df, where)
    if not len(df):
        raise BadInput(f"--where '{where}' keeps no run")
    what = {"line": metric, "curve": "cost", "wall": "cost", "box": metric}[kind]
    out = out or expfile.table_dir(cache, name) / f"{kind}-{what}{'-' + x if x else ''}.png"
    check_folder(out.parent, "output folder")
    if kind == "line":
        drawn = line_plot(df, swept, x, metric, out, name, cache, group, yscale, limits)
    elif kind == "curve":
        drawn = curve_plot(df, swept, out, name, cache, group, yscale, limits)
    elif kind == "wall":
        drawn = wall_plot(df, swept, out, name, cache, group, yscale, limits)
    else:
        drawn = box_plot(df, swept, metric, out, name, cache, group, yscale, limits)
    against = f" against {x}" if x else " against wall time" if kind == "wall" else ""
    drawn.line = (f"plot {name}: {kind} of {what}{against}, {len(df)} runs in {len(drawn.series)} "
                  f"group{'' if len(drawn.series) == 1 else 's'} -> {drawn.path}"
                  + (f" ({drawn.clipped})" if drawn.clipped else ""))
    return drawn
