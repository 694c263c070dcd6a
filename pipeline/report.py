"""Figures in the thesis's style and claims tables (SPEC §8 evaluate, §10), measured and honest.

Every claim is checked by a stated criterion on the measured numbers; the verdict is
``holds`` or ``does not hold`` and the numbers that decided it go into the table.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from pipeline.cache import Cache, atomic_path, write_file_atomic
from pipeline.experiments import BASELINE_LABELS, Experiment, cost_curves, summarize


def save_figure(fig, path: Path, dpi: int = 100) -> None:
    """Write ``fig`` to ``path`` atomically and release it."""
    import matplotlib.pyplot as plt

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi)
    plt.close(fig)

def write_figure(cache: Cache, exp: Experiment, plans: list[dict], path: Path, executions: list | None = None) -> None:
    """Mean and std of the cost per iteration (log scale), one line per solver variant;
    for the balancing figures also the executed CoG's lateral coordinate against its via-points."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cog = exp.plant == "nao" and exp.task.startswith("balance")
    wall = any(v.solver in BASELINE_LABELS for v in exp.variants)  # the crocoddyl baseline: cost vs wall time
    n = 1 + cog + wall
    fig, axes = plt.subplots(1, n, figsize=(6 if n == 1 else 5.5 * n, 4.2), squeeze=False)
    ax = axes[0, 0]
    for v in exp.variants:
        C = cost_curves(cache, plans, v)
        if C.size == 0:
            continue
        it = np.arange(1, C.shape[1] + 1)
        with np.errstate(all="ignore"):
            logc = np.log10(np.where(C > 0, C, np.nan))
            m, s = np.nanmean(logc, 0), np.nanstd(logc, 0)
        n_div = sum(p["outcome"].status == "diverged" for p in plans if p["variant"] == v)
        note = f", diverged {n_div}/{C.shape[0]}" if n_div else ""
        line, = ax.plot(it, 10 ** m, label=f"{v.label} (n={C.shape[0]}{note})")
        ax.fill_between(it, 10 ** (m - s), 10 ** (m + s), color=line.get_color(), alpha=0.2)
    ax.set_yscale("log")
    ax.set_xlabel("iteration")
    ax.set_ylabel("cost (rollout on the planning model)")
    ax.set_title(f"{exp.id}: {exp.plant} {exp.task} ({exp.dynamics})")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    if cog:
        _cog_panel(cache, exp, executions or [], axes[0, 1])
    if wall:
        _wall_time_panel(cache, exp, plans, axes[0, n - 1])
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def _wall_time_panel(cache: Cache, exp: Experiment, plans: list[dict], ax) -> None:
    """Cost against wall time: per run the cost of the last iteration finished by time t (a step
    function of the run's ``elapsed``), median over runs on a common log-spaced time grid. The
    cost axis spans the medians' lowest value to ten times the highest first-iteration median."""
    import matplotlib.ticker

    curves = [(v, cost_curves(cache, plans, v), cost_curves(cache, plans, v, "elapsed")) for v in exp.variants]
    ends = [E[np.isfinite(E)] for _, _, E in curves if E.size]
    ends = np.concatenate(ends) if ends else np.zeros(0)
    ends = ends[ends > 0]
    if ends.size == 0:
        return
    grid = np.geomspace(ends.min(), ends.max(), 300)
    lo, hi = np.inf, -np.inf  # log10 range shown: the medians' lowest value, their highest first value
    for v, C, E in curves:
        if C.size == 0 or E.shape != C.shape:
            continue
        at = np.full((C.shape[0], grid.size), np.nan)
        for i in range(C.shape[0]):
            e = np.where(np.isfinite(E[i]), E[i], np.inf)
            k = np.searchsorted(e, grid, side="right") - 1   # last iteration finished by each time
            ok = k >= 0
            at[i, ok] = C[i, k[ok]]
        with np.errstate(all="ignore"):
            logc = np.log10(np.where(at > 0, at, np.nan))
        logc[~np.isfinite(logc)] = np.nan
        good = np.sum(np.isfinite(logc), 0) * 2 > C.shape[0]  # more than half the runs have a cost
        m = np.full(grid.size, np.nan)
        if good.any():
            m[good] = np.nanmedian(logc[:, good], 0)
        ax.plot(grid, 10 ** m, label=f"{v.label} (median of {C.shape[0]})")
        if np.isfinite(m).any():
            first = m[np.isfinite(m)][0]
            lo, hi = min(lo, np.nanmin(m)), max(hi, first)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    if np.isfinite(lo) and np.isfinite(hi):  # FDDP's infeasible first iterates (x0 held) may spike far above
        ax.set_ylim(10 ** (lo - 0.3), 10 ** (hi + 1.0))
    ax.set_xlabel("wall time (s, solver's own clock; shared 2-core machine)")
    ax.set_ylabel("cost (rollout on the planning model)")
    ax.set_title("cost against wall time")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)


STATUS_COLORS = {"ok": "tab:green", "limits": "tab:orange", "tracking-lost": "tab:purple", "fell": "tab:red",
                 "diverged": "k"}


def _cog_panel(cache: Cache, exp: Experiment, executions: list, ax) -> None:
    """The executed CoG's lateral coordinate of every executed run (free-standing Nao), coloured by
    the run's status, against that run's via-points (its plan's targets: dots in the same colour);
    a cross marks the moment a run failed."""
    from pipeline.runner import as_artifact

    counts: dict[str, int] = {}
    for e in executions:
        art = as_artifact(cache.require("execute", e.key))
        d = art.arrays("rollout.npz")
        if "cog" not in d:
            continue
        plan = as_artifact(cache.require("plan", art.inputs[0].split("/", 1)[1]))
        desc = plan.document("problem.json")
        color = STATUS_COLORS.get(e.status, "tab:gray")
        label = None if e.status in counts else e.status
        counts[e.status] = counts.get(e.status, 0) + 1
        t, y = d["times"], d["cog"][:, 1]
        ax.plot(t, y, color=color, lw=0.9, alpha=0.8, label=label)
        for term in desc["terms"]:
            if term["name"].startswith("via_cog"):
                ax.plot(term["times"][0] * desc["dt"], term["target"][1], "o", color=color, markersize=6,
                        markeredgecolor="k", markeredgewidth=0.5)
        t_fail = e.metrics.get("failure_time")
        if e.status != "ok" and t_fail is not None and np.isfinite(y[int(round(t_fail / desc["dt"]))]):
            k = int(round(t_fail / desc["dt"]))
            ax.plot(t[k], y[k], "x", color=color, markersize=8)
    if not counts:
        ax.text(0.5, 0.5, "no executions", ha="center", va="center", transform=ax.transAxes)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("executed CoG lateral coordinate y (m, left +)")
    n = sum(counts.values())
    ax.set_title(f"executed CoG, free-standing Nao, R-AICO a=1 ({n} runs)\ndots: each run's via-points, x: its "
                 "moment of failure", fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, title="status", title_fontsize=8)


# ----------------------------------------------------------------------------- robustness under noise
def noise_summary(noise: list[dict]) -> list[dict]:
    """Per noise level of the sweep (``pipeline.experiments.run_noise_sweep``): runs, status counts,
    success rate (share with status ok) and the spread of the largest executed via-point error."""
    from stages.evaluate.summary import largest_via_error

    rows = []
    for level in dict.fromkeys(r["level"] for r in noise):
        rs = [r for r in noise if r["level"] == level]
        st = [r["outcome"].status for r in rs]
        errs = np.array([largest_via_error(r["outcome"].metrics) for r in rs], float)
        fin = errs[np.isfinite(errs)]
        rows.append({"x0_noise": level[0], "process_noise": level[1], "runs": len(rs), "ok": st.count("ok"),
                     "stood": sum(x not in ("fell", "diverged") for x in st),
                     "success_rate": st.count("ok") / len(rs) if rs else math.nan,
                     "statuses": {k: st.count(k) for k in dict.fromkeys(st)},
                     "via_error_median": float(np.median(errs)) if errs.size else math.nan,
                     "via_error_min": float(fin.min()) if fin.size else math.nan,
                     "via_error_max": float(errs.max()) if errs.size else math.nan,
                     "executions": [{"plan_seed": r["plan_seed"], "seed": r["seed"], "key": r["outcome"].key,
                                     "status": r["outcome"].status} for r in rs]})
    return rows


def write_noise_figure(exp: Experiment, rows: list[dict], path: Path) -> None:
    """Success rate (share of executions with status ok) against the noise level."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pipeline.experiments import NOISE_SWEEPS

    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    x = np.arange(len(rows))
    ax.plot(x, [r["success_rate"] for r in rows], "o-", label=f"{NOISE_SWEEPS[exp.id].label} plans")
    for i, r in enumerate(rows):
        ax.annotate(f"{r['ok']}/{r['runs']}", (x[i], r["success_rate"]), textcoords="offset points", xytext=(6, 6),
                    fontsize=8)
    if exp.plant == "nao":
        ax.plot(x, [r["stood"] / r["runs"] for r in rows], "s--", color="tab:gray", label="share that stood")
    ax.set_xticks(x, [f"x0 {r['x0_noise']:g} rad\nprocess {r['process_noise']:g} N m" for r in rows], fontsize=8)
    ax.set_ylim(-0.05, 1.1)
    ax.set_ylabel("success rate (status ok)")
    ax.set_title(f"{exp.id}: executions under noise", fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)


def noise_section(exp: Experiment, noise: list[dict], out_dir: Path) -> tuple[list[str], list[dict]]:
    """``noise.png`` and the markdown lines of the noise-robustness section (none without a sweep)."""
    if not noise:
        return [], []
    from pipeline.experiments import NOISE_SWEEPS

    rows = noise_summary(noise)
    write_noise_figure(exp, rows, out_dir / "noise.png")
    md = ["## Robustness under noise (beyond the thesis)", "",
          f"{NOISE_SWEEPS[exp.id].label}'s plans of the first initial states, each executed once per noise level "
          "(initial joint-angle noise, rad; torque noise per planning step and joint, N m; plan i with execution seed "
          "i); a run succeeds when its status is ok.", "", "![noise](noise.png)", "",
          "| x0 noise (rad) | process noise (N m) | runs | success rate | stood | statuses | largest executed "
          "via-point error: median (min-max) |", "|---|---|---|---|---|---|---|"]
    md += [f"| {r['x0_noise']:g} | {r['process_noise']:g} | {r['runs']} | {_fmt(r['success_rate'])} | {r['stood']} | "
           f"{', '.join(f'{k} {v}' for k, v in r['statuses'].items())} | {_fmt(r['via_error_median'])} "
           f"({_fmt(r['via_error_min'])}-{_fmt(r['via_error_max'])}) |" for r in rows]
    return md + [""], rows


# ----------------------------------------------------------------------------- claims
def claims_table(exp: Experiment, plans: list[dict], executions: list) -> list[dict]:
    """The experiment's claims (``stages.evaluate.claims``) on its measured summaries."""
    from stages.evaluate.claims import evaluate_claims

    S = {v.label: summarize(plans, v) for v in exp.variants}
    return evaluate_claims(exp.claims, S, [e.metrics for e in executions], exp.id)


def summary_table(exp: Experiment, plans: list[dict]) -> list[dict]:
    return [summarize(plans, v) for v in exp.variants]


def markdown_claims(rows: list[dict]) -> str:
    out = ["| figure | thesis claim | criterion | measured | verdict |", "|---|---|---|---|---|"]
    out += [f"| {r['figure']} | {r['claim']} | {r['criterion']} | {r['measured']} | **{r['verdict']}** |" for r in rows]
    return "\n".join(out)


def _fmt(x: float) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    return f"{x:.3g}"


def markdown_summary(rows: list[dict]) -> str:
    out = ["| variant | runs | diverged | converged (tol) | first-iteration cost | final cost | final/initial | "
           "largest via-point error | wall time (s) |", "|---|---|---|---|---|---|---|---|---|"]
    out += [f"| {r['label']} | {r['runs']} | {r['diverged']} | {r['converged']} | {_fmt(r['first_cost_median'])} | "
            f"{_fmt(r['final_cost_median'])} | {_fmt(r['cost_ratio_median'])} | {_fmt(r['max_via_error_median'])} | "
            f"{_fmt(r['wall_time_median_s'])} |" for r in rows]
    return "\n".join(out) + "\n\n(medians over the runs)"


def write_experiment_report(cache: Cache, exp: Experiment, result: dict, out_dir: Path) -> dict:
    """``figure.png``, ``claims.md``/``claims.json`` and the run list under ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    write_figure(cache, exp, result["plans"], out_dir / "figure.png", result.get("executions"))
    rows = claims_table(exp, result["plans"], result["executions"])
    summary = summary_table(exp, result["plans"])
    runs = [{"variant": p["variant"].label, "seed": p["seed"], "key": p["outcome"].key,
             "status": p["outcome"].status, "recording": str(Path(p["outcome"].path) / "recording.rrd")}
            for p in result["plans"]]
    execs = [{"key": e.key, "recording": str(Path(e.path) / "recording.rrd"), **{
        k: v for k, v in e.metrics.items() if k != "via_point_errors"}} for e in result["executions"]]
    noise_md, noise_rows = noise_section(exp, result.get("noise") or [], out_dir)
    doc = {"figure": exp.id, "description": exp.description, "claims": rows, "summary": summary,
           "runs": runs, "executions": execs, "noise": noise_rows}
    write_file_atomic(out_dir / "claims.json", json.dumps(doc, indent=2, default=float))
    md = [f"# {exp.id}: {exp.description}", "", "![figure](figure.png)", "", "## Claims", "",
          markdown_claims(rows), "", "## Runs", "", markdown_summary(summary), ""]
    if execs:
        nao = exp.plant == "nao"
        md += [f"## Executions in Drake (R-AICO a=1{', free-standing Nao' if nao else ''})", "",
               "| execution | status | why | CoG inside the contact polygon | worst margin (m) | steps at an "
               "effort limit | RMSE planned vs executed (rad) | recording |", "|---|---|---|---|---|---|---|---|"]
        md += [f"| {e['key']} | **{e.get('status')}** | {e.get('reason', '')} | {_fmt(e.get('cog_inside_fraction'))} | "
               f"{_fmt(e.get('cog_min_margin'))} | {_fmt(e.get('torque_saturation'))} | "
               f"{_fmt(e.get('rmse_planned_executed'))} | `{e['recording']}` |" for e in execs]
        if nao:
            stood = sum(e.get("status") not in ("fell", "diverged") for e in execs)
            md += ["", f"Stood: {stood}/{len(execs)} runs. The CoG is judged against the convex hull of the sole "
                   "corners in contact (Drake's contact forces, corners within 1 mm of the ground); statuses and "
                   "thresholds: README, section Execution."]
        md += [""]
    md += noise_md
    md += ["", "## Recordings", ""] + [f"- {r['variant']} seed {r['seed']}: `{r['recording']}`" for r in runs]
    write_file_atomic(out_dir / "claims.md", "\n".join(md) + "\n")
    return doc


# ----------------------------------------------------------------------------- learning figures
def folder_name(fid: str) -> str:
    """An experiment id as a folder name (``fig4.1/4.2`` -> ``fig4.1-4.2``)."""
    return fid.replace("/", "-")


def _learn_panel(ax, S: dict, labels: list[str], key: str, ylabel: str) -> None:
    for lab in labels:
        curve = np.array(S[lab][f"{key}_curve"], float)
        if curve.size:
            ax.plot(np.arange(1, curve.size + 1), curve, marker=".", label=f"{lab} (n={S[lab]['runs']})")
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
        fig, axes = plt.subplots(1, 3, figsize=(14, 4.2), squeeze=False)
        labels = list(S)
        _learn_panel(axes[0, 0], S, labels, "gp_error", "GP prediction error (rad/s^2, RMSE)")
        axes[0, 0].set_title("(B) GP prediction error per evaluation", fontsize=9)
        _learn_panel(axes[0, 1], S, labels, "fit_time_s", "fit time (s)")
        axes[0, 1].set_title("(C) fit time per evaluation", fontsize=9)
        _learn_panel(axes[0, 2], S, labels, "task_error", "largest via-point error, executed (m)")
        axes[0, 2].set_title("(D) task error of the executed motion", fontsize=9)
        axes[0, 0].set_xlabel("evaluation")
        axes[0, 1].set_xlabel("evaluation")
        axes[0, 2].set_xlabel("evaluation")
    fig.suptitle(f"{exp.id}: {exp.plant} {exp.task}, learned GP dynamics (lines: median over seeds)", fontsize=10)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)


def write_learn_motion(cache: Cache, exp, learns: list[dict], label: str, path: Path) -> str | None:
    """The last episode of ``label``'s first seed: planned vs executed (pendulum angle; arm's
    end-effector x and z against the target). Returns the run's learn key."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pipeline.runner import as_artifact
    from plants.robots import shared_robot
    from plants.taskmaps import EndEffectorPosition

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


def write_learn_report(cache: Cache, exp, result: dict, out_dir: Path) -> dict:
    """``figure.png``, ``motion.png``, ``claims.md``/``claims.json`` of a learning experiment."""
    from pipeline.experiments import summarize_learns
    from stages.evaluate.claims import evaluate_claims

    out_dir.mkdir(parents=True, exist_ok=True)
    learns = result["learns"]
    S = summarize_learns(learns)
    write_learn_figure(exp, S, out_dir / "figure.png")
    best = "sigma*=0, w=0.01" if exp.plant == "pendulum" else "every"
    motion_key = write_learn_motion(cache, exp, learns, best, out_dir / "motion.png")
    rows = evaluate_claims(exp.claims, S, [], exp.id)
    runs = [{"setting": x["setting"].label, "seed": x["seed"], "key": x["outcome"].key,
             "recording": x["outcome"].recording or str(Path(x["outcome"].path) / "recording.rrd"),
             "first_success_episode": x["outcome"].metrics.get("first_success_episode")} for x in learns]
    summary = [{k: v for k, v in s.items() if not k.endswith("_curve")} for s in S.values()]
    doc = {"figure": exp.id, "description": exp.description, "claims": rows, "summary": summary, "runs": runs,
           "executions": [], "motion_run": motion_key}
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
    md += ["", "## Choices", ""] + [f"- {k}: {v}" for k, v in exp.notes]
    md += ["", "## Recordings", ""] + [f"- {r['setting']} seed {r['seed']}: `{r['recording']}`" for r in runs]
    write_file_atomic(out_dir / "claims.md", "\n".join(md) + "\n")
    return doc
