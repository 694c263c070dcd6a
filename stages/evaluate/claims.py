"""Claims of the thesis checked against measured summaries (SPEC §10), each by a stated criterion.

A claim function takes ``S`` (variant label -> summary of :func:`stages.evaluate.summary.summarize`)
and ``execs`` (metric dicts of the executions) and returns ``(claim, criterion, measured, holds)``.
The functions are pure, so each is unit-tested on synthetic summaries whose verdict is known.
"""

from __future__ import annotations

import math

import numpy as np


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
    inside = [e.get("cog_inside_fraction", math.nan) for e in execs]
    margin = [e.get("cog_min_margin", math.nan) for e in execs]
    sat = [e.get("torque_saturation", math.nan) for e in execs]
    rm = [e.get("rmse_planned_executed", math.nan) for e in execs]
    ok = all(f >= 1.0 for f in inside)
    return ("CoG stays over the support polygon of the feet (R-AICO a=1 executed in Drake)",
            "CoG ground projection inside the convex hull of both soles at every step of every run",
            f"inside fraction median {_fmt(float(np.median(inside)))}, worst margin {_fmt(float(np.min(margin)))} m, "
            f"steps with torque saturation median {_fmt(float(np.median(sat)))}, planned-vs-executed RMSE median "
            f"{_fmt(float(np.median(rm)))} rad", ok)


CLAIMS = {k[len("claim_"):]: v for k, v in globals().items() if k.startswith("claim_")}


def evaluate_claims(names: tuple[str, ...], S: dict, execs: list[dict], figure: str) -> list[dict]:
    """Rows ``{"figure", "claim", "criterion", "measured", "verdict"}`` for the named claims."""
    rows = []
    for c in names:
        claim, criterion, numbers, ok = CLAIMS[c](S, execs)
        rows.append({"figure": figure, "claim": claim, "criterion": criterion, "measured": numbers,
                     "verdict": "holds" if ok else "does not hold"})
    return rows
