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
    from pipeline.stage_io import load_npz
    from plants.robots import shared_robot
    from plants.taskmaps import CenterOfMass
    from stages.plan.stage import PlanConfig, build_problem

    robot = shared_robot("nao")
    cogmap = CenterOfMass(robot, axes=(1,))
    target = Variant("raico", 1.0)
    ys, times, vias = [], None, None
    for p in plans:
        if p["variant"] != target:
            continue
        entry = cache.require("plan", p["outcome"].key)
        d = load_npz(entry, "plan.npz")
        X = d["X"]
        if not np.all(np.isfinite(X)):
            continue
        y, _ = cogmap.values_and_jacobians(X[:, :robot.n_q])
        ys.append(y[:, 0])
        times = d["times"]
        if vias is None:
            cfg = PlanConfig.from_dict(entry.meta["config"])
            _, task, problem, _ = build_problem(cfg)
            vias = [(t.times[0] * task.dt, t.target[1]) for t in problem.state_terms if t.name.startswith("via_cog")]
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
def _by_label(exp: Experiment, plans: list[dict]) -> dict[str, dict]:
    return {v.label: summarize(plans, v) for v in exp.variants}


def _fmt(x: float) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    return f"{x:.3g}"


def _raico(S: dict) -> dict:
    return {k: v for k, v in S.items() if k.startswith("R-AICO")}


def _main(S: dict) -> dict:
    """Variants of the thesis figure (ablations left out)."""
    return {k: v for k, v in S.items() if "no sweep" not in k}


def claim_raico_converges(S, execs):
    R = _raico(S)
    best = min(s["final_cost_median"] for s in _main(S).values())
    ok = all(s["diverged"] == 0 and s["final_cost_median"] <= 2 * best for s in R.values())
    nums = "; ".join(f"{k}: final median {_fmt(s['final_cost_median'])} (final/initial {_fmt(s['cost_ratio_median'])}), "
                     f"diverged {s['diverged']}/{s['runs']}" for k, s in R.items())
    return ("R-AICO converges", "no R-AICO run diverges and each R-AICO variant's median final cost is within 2x "
            "of the lowest median final cost of any solver", f"{nums}; lowest {_fmt(best)}", ok)


def _best_raico(S) -> float:
    return min((s["final_cost_median"] for s in _raico(S).values()), default=math.nan)


def claim_aico_unstable(S, execs):
    a, best = S["AICO"], _best_raico(S)
    ok = a["diverged"] > 0 or a["final_cost_median"] > 2 * best
    return ("plain AICO is unstable, no low-cost solution", "AICO diverges in some run, or its median final "
            "cost exceeds 2x the best R-AICO's", f"AICO final median {_fmt(a['final_cost_median'])}, diverged "
            f"{a['diverged']}/{a['runs']}; best R-AICO {_fmt(best)}", ok)


def claim_aico_unstable_without_relinearization(S, execs):
    a, best = S["AICO (no sweep relinearization)"], _best_raico(S)
    ok = a["diverged"] > 0 or a["final_cost_median"] > 2 * best or a["final_cost_max"] > 2 * best
    return ("ablation: AICO taking full Gauss-Newton steps (theta = inf) is unstable",
            "it diverges in some run, or its median or worst final cost exceeds 2x the best R-AICO's median",
            f"AICO without relinearization: final median {_fmt(a['final_cost_median'])}, worst "
            f"{_fmt(a['final_cost_max'])}, diverged {a['diverged']}/{a['runs']}; best R-AICO {_fmt(best)}", ok)


def claim_aico_fails(S, execs):
    a, best = S["AICO"], _best_raico(S)
    ok = a["diverged"] >= a["runs"] / 2 or a["final_cost_median"] > 10 * best
    return ("plain AICO fails on the analytic model", "AICO diverges in at least half the runs, or its median "
            "final cost exceeds 10x the best R-AICO's", f"AICO final median {_fmt(a['final_cost_median'])}, "
            f"diverged {a['diverged']}/{a['runs']}; best R-AICO {_fmt(best)}", ok)


def claim_ilqg_stalls(S, execs):
    i, best = S["iLQG"], _best_raico(S)
    ok = i["final_cost_median"] > 2 * best
    return ("iLQG stalls on the analytic model", "iLQG's median final cost exceeds 2x the best R-AICO's",
            f"iLQG final median {_fmt(i['final_cost_median'])}; best R-AICO {_fmt(best)}", ok)


def claim_all_converge_aico_fastest(S, execs):
    S = _main(S)
    best = min(s["final_cost_median"] for s in S.values())
    allok = all(s["diverged"] == 0 and s["final_cost_median"] <= 2 * best for s in S.values())
    aico_first = S["AICO"]["first_cost_median"]
    fastest = all(aico_first <= s["first_cost_median"] for s in S.values())
    nums = "; ".join(f"{k}: first {_fmt(s['first_cost_median'])}, final {_fmt(s['final_cost_median'])}"
                     for k, s in S.items())
    return ("all solvers converge fast, plain AICO fastest", "every variant ends within 2x of the best median "
            "final cost without divergence, and AICO has the lowest first-iteration cost", nums, allok and fastest)


def claim_raico_reaches_aico_not(S, execs):
    r, a = S["R-AICO a=1"], S["AICO"]
    tol = 0.01
    ok = r["max_via_error_median"] <= tol and (a["max_via_error_median"] > tol or a["diverged"] > 0)
    return ("R-AICO reaches the via-points, AICO does not", f"median (over runs) of the largest via-point error "
            f"<= {tol} m for R-AICO a=1, > {tol} m (or diverged) for AICO",
            f"R-AICO a=1 {_fmt(r['max_via_error_median'])} m, AICO {_fmt(a['max_via_error_median'])} m "
            f"(diverged {a['diverged']}/{a['runs']})", ok)


def claim_cog_support(S, execs):
    if not execs:
        return ("CoG stays over the support polygon (executed in Drake)", "every executed step", "no executions", False)
    inside = [e.metrics.get("cog_inside_fraction", math.nan) for e in execs]
    margin = [e.metrics.get("cog_min_margin", math.nan) for e in execs]
    sat = [e.metrics.get("torque_saturation", math.nan) for e in execs]
    rm = [e.metrics.get("rmse_planned_executed", math.nan) for e in execs]
    ok = all(f >= 1.0 for f in inside)
    return ("CoG stays over the support polygon of the feet (R-AICO a=1 executed in Drake)",
            "CoG ground projection inside the convex hull of both soles at every step of every run",
            f"inside fraction median {_fmt(float(np.median(inside)))}, worst margin {_fmt(float(np.min(margin)))} m, "
            f"steps with torque saturation median {_fmt(float(np.median(sat)))}, planned-vs-executed RMSE median "
            f"{_fmt(float(np.median(rm)))} rad", ok)


CLAIMS = {k[len("claim_"):]: v for k, v in globals().items() if k.startswith("claim_")}


def claims_table(exp: Experiment, plans: list[dict], executions: list) -> list[dict]:
    S = _by_label(exp, plans)
    rows = []
    for c in exp.claims:
        claim, criterion, numbers, ok = CLAIMS[c](S, executions)
        rows.append({"figure": exp.id, "claim": claim, "criterion": criterion, "measured": numbers,
                     "verdict": "holds" if ok else "does not hold"})
    return rows


def summary_table(exp: Experiment, plans: list[dict]) -> list[dict]:
    return [summarize(plans, v) for v in exp.variants]


def markdown_claims(rows: list[dict]) -> str:
    out = ["| figure | thesis claim | criterion | measured | verdict |", "|---|---|---|---|---|"]
    out += [f"| {r['figure']} | {r['claim']} | {r['criterion']} | {r['measured']} | **{r['verdict']}** |" for r in rows]
    return "\n".join(out)


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
