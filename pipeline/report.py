"""Figures in the thesis's style and claims tables (SPEC §8 evaluate, §10), measured and honest.

Every claim is checked by a stated criterion on the measured numbers; the verdict is
``holds`` or ``does not hold`` and the numbers that decided it go into the table.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from pipeline.cache import Cache
from pipeline.experiments import Experiment, Variant, cost_curves, summarize


def write_figure(cache: Cache, exp: Experiment, plans: list[dict], path: Path) -> None:
    """Mean and std of the cost per iteration (log scale), one line per solver variant;
    for the balancing figures also the CoG's lateral coordinate against its via-points."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cog = exp.plant == "nao" and exp.task.startswith("balance")
    fig, axes = plt.subplots(1, 2 if cog else 1, figsize=(11 if cog else 6, 4.2), squeeze=False)
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
        _cog_panel(cache, exp, plans, axes[0, 1])
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _cog_panel(cache: Cache, exp: Experiment, plans: list[dict], ax) -> None:
    from pipeline.runner import as_artifact
    from plants.robots import shared_robot
    from plants.taskmaps import CenterOfMass

    robot = shared_robot("nao")
    cogmap = CenterOfMass(robot, axes=(1,))
    target = Variant("raico", 1.0)
    ys, times, vias = [], None, None
    for p in plans:
        if p["variant"] != target:
            continue
        art = as_artifact(cache.require("plan", p["outcome"].key))
        d = art.arrays("plan.npz")
        X = d["X"]
        if not np.all(np.isfinite(X)):
            continue
        y, _ = cogmap.values_and_jacobians(X[:, :robot.n_q])
        ys.append(y[:, 0])
        times = d["times"]
        if vias is None:  # the planned objective, as the plan artifact stored it
            desc = art.document("problem.json")
            vias = [(t["times"][0] * desc["dt"], t["target"][1]) for t in desc["terms"]
                    if t["name"].startswith("via_cog")]
    if ys:
        Y = np.array(ys)
        m, s = Y.mean(0), Y.std(0)
        ax.plot(times, m, label="R-AICO a=1, mean of runs")
        ax.fill_between(times, m - s, m + s, alpha=0.25)
        for t, yv in vias or []:
            ax.plot(t, yv, "o", color="k", markersize=8)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("CoG lateral coordinate y (m, left +)")
    ax.set_title("CoG against its via-points (dots)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)


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
    write_figure(cache, exp, result["plans"], out_dir / "figure.png")
    rows = claims_table(exp, result["plans"], result["executions"])
    summary = summary_table(exp, result["plans"])
    runs = [{"variant": p["variant"].label, "seed": p["seed"], "key": p["outcome"].key,
             "status": p["outcome"].status, "recording": str(Path(p["outcome"].path) / "recording.rrd")}
            for p in result["plans"]]
    execs = [{"key": e.key, "recording": str(Path(e.path) / "recording.rrd"), **{
        k: v for k, v in e.metrics.items() if k != "via_point_errors"}} for e in result["executions"]]
    doc = {"figure": exp.id, "description": exp.description, "claims": rows, "summary": summary,
           "runs": runs, "executions": execs}
    (out_dir / "claims.json").write_text(json.dumps(doc, indent=2, default=float))
    md = [f"# {exp.id}: {exp.description}", "", "![figure](figure.png)", "", "## Claims", "",
          markdown_claims(rows), "", "## Runs", "", markdown_summary(summary), ""]
    if execs:
        md += ["## Executions in Drake (R-AICO a=1)", "", "| plan run | CoG inside | worst margin (m) | torque "
               "saturation | RMSE planned vs executed (rad) | recording |", "|---|---|---|---|---|---|"]
        md += [f"| {e['key']} | {_fmt(e.get('cog_inside_fraction'))} | {_fmt(e.get('cog_min_margin'))} | "
               f"{_fmt(e.get('torque_saturation'))} | {_fmt(e.get('rmse_planned_executed'))} | `{e['recording']}` |"
               for e in execs]
    md += ["", "## Recordings", ""] + [f"- {r['variant']} seed {r['seed']}: `{r['recording']}`" for r in runs]
    (out_dir / "claims.md").write_text("\n".join(md) + "\n")
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
    fig.savefig(path, dpi=100)
    plt.close(fig)


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
    fig.savefig(path, dpi=100)
    plt.close(fig)
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
    (out_dir / "claims.json").write_text(json.dumps(doc, indent=2, default=float))
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
    (out_dir / "claims.md").write_text("\n".join(md) + "\n")
    return doc
