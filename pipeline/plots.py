"""``raico plot``: an experiment's runs table as figures (PNG, matplotlib's Agg backend).

Three kinds, each over the seeds of every group of runs (a group: the runs that share the grouping
options, by default every swept option but the x axis's, so a group is a variant or, for ``line``, a
line through the variants that differ only in x):

- ``line``: a metric against a swept option: the median over the seeds at each x and the
  interquartile range as a band. A group that has one x value only because it does not use the option
  (iLQG has no alpha) or was run at one value is drawn as a dashed horizontal line at its median, its
  band across the plot: a baseline to compare the lines with.
- ``curve``: the cost per iteration (``plan.npz`` ``costs`` of each run's plan), median and
  interquartile band per group on a log axis; a run that stopped early holds its last cost, a diverged
  run drops out from its divergence on.
- ``box``: a box per group (median, quartiles, whiskers at 1.5 IQR) with every run as a dot beside it.

Legends name the groups by the options that differ between them, leaving out those a group's runs
do not use (an option whose value leaves the run's normalized config, so its cache key, unchanged);
never by keys. Each legend entry says how many runs it shows (``n=8/10``: two runs had no finite value).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.errors import BadInput

KINDS = ("line", "curve", "box")


@dataclass
class Plot:
    """A written figure and what it draws per legend entry (group label -> ``x``, ``median``, ``q25``,
    ``q75``, ``n``: the numbers behind the lines, bands and boxes)."""

    path: Path
    series: dict[str, dict[str, Any]] = field(default_factory=dict)
COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
          "#17becf")
BAND_ALPHA = 0.2


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


def _value(v: Any) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def unused_options(cache, row, options: Sequence[str], others: dict[str, set]) -> set[str]:
    """:func:`pipeline.expfile.unused_in` for the run of a runs-table ``row`` (its first stage's ``meta.json``);
    none without a cache or an entry."""
    from pipeline.expfile import _meta, unused_in

    cols = [c for c in row.index if str(c).endswith(".key")]
    if cache is None or not cols or not isinstance(row[cols[0]], str):
        return set()
    stage = cols[0][:-4]
    return unused_in(stage, _meta(cache, stage, row[cols[0]]).get("config") or {}, options, others)


def labels(cache, grouped: list[tuple[dict[str, Any], Any]], drop_unused: bool = True) -> list[str]:
    """A legend entry per group: the options whose values differ between the groups (``option=value``),
    without those the group's runs do not use (:func:`unused_options`); ``all runs`` for a single group."""
    if len(grouped) == 1 and not grouped[0][0]:
        return ["all runs"]
    keys = list(grouped[0][0])
    values = {k: {opts.get(k) for opts, _ in grouped} for k in keys}
    differ = [k for k in keys if len({_value(v) for v in values[k]}) > 1] or keys
    out = []
    for opts, rows in grouped:
        skip = unused_options(cache, rows.iloc[0], differ, values) if drop_unused else set()
        parts = [f"{k}={_value(opts[k])}" for k in differ if k not in skip]
        out.append(", ".join(parts) or ", ".join(f"{k}={_value(opts[k])}" for k in differ))
    if len(set(out)) < len(out):   # dropping unused options made two the same: name every differing option
        out = [", ".join(f"{k}={_value(opts[k])}" for k in differ) for opts, _ in grouped]
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


def _legend(ax, entries: int) -> None:
    """The legend below the axes (it never hides a line or a band), in two columns when it is long."""
    if entries:
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2 if entries > 3 else 1,
                  frameon=False)


def _save(fig, out: Path, series: dict[str, dict[str, Any]]) -> Plot:
    import matplotlib.pyplot as plt

    from pipeline.cache import atomic_path

    out.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)
    return Plot(out, series)


def line_plot(df, swept: list[str], x: str, metric: str, out: Path, name: str, cache=None,
              by: Sequence[str] | None = None, yscale: str = "auto") -> Plot:
    """``metric`` against option ``x``: median and interquartile band over the seeds per group."""
    by = grouping(df, swept, by, x)
    grouped = groups(df, by)
    names = labels(cache, grouped)
    xs_all = df[x].map(_plain)
    numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in xs_all if v is not None)
    # the axis spans the x values of the groups that vary x (a baseline's single value, e.g. iLQG's alpha 0, is
    # not a point on it)
    varied = [rows for _, rows in grouped if rows[x].map(_plain).nunique() > 1]
    on_axis = [v for rows in varied for v in rows[x].map(_plain)] if varied else list(xs_all)
    order = sorted({v for v in on_axis if v is not None}, key=(float if numeric else str))
    pos = (lambda v: float(v)) if numeric else (lambda v: float(order.index(v)))
    fig, ax = _figure(f"{name}: {metric} against {x}",
                      f"median over the seeds, band: interquartile range ({df['seed'].nunique()} seeds)")
    every = _numbers(df[metric])
    lines, flat, series = [], [], {}
    for (_, rows), label, color in zip(grouped, names, _cycle(len(grouped))):
        pts = []
        for xv, g in rows.groupby(rows[x].map(_plain), sort=False, dropna=False):
            v = _numbers(g[metric])
            v = v[np.isfinite(v)]
            pts.append((xv, v, len(g)))
        if len(pts) == 1 and varied:   # one x value: a baseline across the plot
            uses = x not in unused_options(cache, rows.iloc[0], [x], {x: set(order)})
            flat.append((label, color, pts[0][1], pts[0][2],
                         f"at {x}={_value(pts[0][0])} only" if uses else f"does not use {x}"))
            continue
        pts = sorted((p for p in pts if p[0] is not None), key=lambda p: pos(p[0]))
        X = np.array([pos(p[0]) for p in pts])
        med = np.array([np.median(p[1]) if p[1].size else np.nan for p in pts])
        lo = np.array([np.percentile(p[1], 25) if p[1].size else np.nan for p in pts])
        hi = np.array([np.percentile(p[1], 75) if p[1].size else np.nan for p in pts])
        ns, totals = [p[1].size for p in pts], [p[2] for p in pts]
        n_text = (f"n={ns[0]}" if len(set(ns)) == 1 and ns == totals else
                  f"n={min(ns)}-{max(ns)} of {max(totals)}" if min(ns) != max(ns) else f"n={ns[0]}/{max(totals)}")
        ax.plot(X, med, "-o", color=color, lw=1.8, ms=4, label=f"{label} ({n_text} per point)")
        series[label] = {"x": [p[0] for p in pts], "median": med.tolist(), "q25": lo.tolist(), "q75": hi.tolist(),
                         "n": ns}
        ax.fill_between(X, lo, hi, color=color, alpha=BAND_ALPHA, lw=0)
        lines.append(label)
    for label, color, v, total, why in flat:
        if not v.size:
            continue
        ax.axhline(np.median(v), color=color, ls="--", lw=1.5, label=f"{label} ({_n_text(v.size, total)}; {why})")
        q25, q75 = np.percentile(v, [25, 75])
        series[label] = {"x": None, "median": [float(np.median(v))], "q25": [float(q25)], "q75": [float(q75)],
                         "n": [v.size]}
        ax.axhspan(q25, q75, color=color, alpha=BAND_ALPHA * 0.6, lw=0)
    if numeric:
        xv = np.array(order, float)
        if xv.size > 1 and xv.min() > 0 and xv.max() / xv.min() >= 10:
            ax.set_xscale("log")
        ax.set_xticks(xv)
        ax.set_xticklabels([_value(v) for v in order])
        ax.minorticks_off() if ax.get_xscale() == "log" else None
    else:
        ax.set_xticks(range(len(order)))
        ax.set_xticklabels([str(v) for v in order])
    if _log_scale(every, yscale):
        ax.set_yscale("log")
    ax.set_xlabel(x)
    ax.set_ylabel(metric)
    _legend(ax, len(lines) + len(flat))
    return _save(fig, out, series)


def cost_curves(cache, keys: Sequence[Any]) -> np.ndarray:
    """``(runs, iterations)`` costs of the plans ``keys`` (``plan.npz`` ``costs``; a cost that is not finite,
    such as crocoddyl's for an infeasible iterate or a diverged run's, stays so); a run that stopped early
    holds its last cost if it is finite; a missing entry is a row of NaN."""
    curves = []
    for k in keys:
        c = np.zeros(0)
        if isinstance(k, str):
            try:
                with np.load(cache.root / "plan" / k / "plan.npz", allow_pickle=False) as f:
                    c = np.asarray(f["costs"], float)
            except (OSError, KeyError, ValueError):
                pass
        curves.append(c)
    n = max((len(c) for c in curves), default=0)
    out = np.full((len(curves), n), np.nan)
    for i, c in enumerate(curves):
        out[i, :len(c)] = c
        if len(c) and len(c) < n and np.isfinite(c[-1]):
            out[i, len(c):] = c[-1]
    return out


def curve_plot(df, swept: list[str], out: Path, name: str, cache, by: Sequence[str] | None = None,
               yscale: str = "log") -> Plot:
    """The cost per iteration, median and interquartile band over the seeds per group."""
    if "plan.key" not in df.columns:
        raise BadInput(f"{name}: no plan runs in the table (--kind curve plots the plans' cost per iteration)")
    grouped = groups(df, grouping(df, swept, by))
    names = labels(cache, grouped)
    fig, ax = _figure(f"{name}: cost per iteration", f"median over the runs with a finite cost at the iteration, "
                      f"band: interquartile range ({df['seed'].nunique()} seeds)")
    every, series = [], {}
    shown = 0
    for (_, rows), label, color in zip(grouped, names, _cycle(len(grouped))):
        C = cost_curves(cache, list(rows["plan.key"]))
        if not C.size:
            continue
        alive = np.isfinite(C)
        it = np.arange(1, C.shape[1] + 1)
        med, lo, hi = (np.full(C.shape[1], np.nan) for _ in range(3))
        for j in range(C.shape[1]):
            col = C[alive[:, j], j]
            if col.size:
                med[j] = np.median(col)
                lo[j], hi[j] = np.percentile(col, [25, 75])
        ended = int(np.isfinite(C[:, -1]).sum())
        text = f"n={len(rows)}" + ("" if ended == len(rows) else f"; {len(rows) - ended} without a finite last cost")
        ax.plot(it, med, color=color, lw=1.8, label=f"{label} ({text})")
        series[label] = {"x": it.tolist(), "median": med.tolist(), "q25": lo.tolist(), "q75": hi.tolist(),
                         "n": [len(rows)]}
        ax.fill_between(it, lo, hi, color=color, alpha=BAND_ALPHA, lw=0)
        every.append(C[alive])
        shown += 1
    values = np.concatenate(every) if every else np.zeros(0)
    if _log_scale(values, "log" if yscale == "auto" and values.size and values.min() > 0 else yscale):
        ax.set_yscale("log")
    ax.set_xlabel("iteration")
    ax.set_ylabel("cost")
    _legend(ax, shown)
    return _save(fig, out, series)


def box_plot(df, swept: list[str], metric: str, out: Path, name: str, cache=None, by: Sequence[str] | None = None,
             yscale: str = "auto") -> Plot:
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
    if _log_scale(every, yscale):
        ax.set_xscale("log")
    ax.set_xlabel(metric)
    return _save(fig, out, series)


def _cycle(n: int) -> list[str]:
    return [COLORS[i % len(COLORS)] for i in range(n)]
