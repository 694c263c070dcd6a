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




# ----------------------------------------------------------------------------- learning (thesis §4)
def _falls(s: dict, key: str, factor: float) -> bool:
    return math.isfinite(s[f"{key}_first3"]) and s[f"{key}_last3"] <= factor * s[f"{key}_first3"]


def _small_weight(L: dict) -> dict:
    return {k: v for k, v in L.items() if "w=0.01" in k}


def claim_gp_error_falls(L, execs):
    S = _small_weight(L)
    ok = bool(S) and all(_falls(s, "gp_error", 0.1) for s in S.values())
    nums = "; ".join(f"{k}: {_fmt(s['gp_error_first3'])} -> {_fmt(s['gp_error_last3'])} rad/s^2" for k, s in S.items())
    return ("the GP's prediction error falls towards zero for a small C_sigma (w = 1e-2)",
            "for every sigma* with w = 1e-2: the median over seeds of the mean GP error on the executed motion in the "
            "last three episodes is at most 10% of that in the first three", nums or "no runs", ok)


def claim_rmse_falls(L, execs):
    S = _small_weight(L)
    ok = bool(S) and all(_falls(s, "rmse_planned_executed", 0.1) for s in S.values())
    nums = "; ".join(f"{k}: {_fmt(s['rmse_planned_executed_first3'])} -> {_fmt(s['rmse_planned_executed_last3'])} rad"
                     for k, s in S.items())
    return ("the planned-vs-executed RMSE falls towards zero for a small C_sigma (w = 1e-2)",
            "as above, for the RMSE between the planned and the executed joint trajectory", nums or "no runs", ok)


def claim_large_weight_explores(L, execs):
    pairs = []
    for sigma in ("0.2", "1"):
        big, small = L.get(f"sigma*={sigma}, w=100"), L.get(f"sigma*={sigma}, w=0.01")
        if big and small:
            pairs.append((sigma, big, small))
    ok = bool(pairs) and all(b["gp_error_last3"] > 2 * s["gp_error_last3"]
                             or b["rmse_planned_executed_last3"] > 2 * s["rmse_planned_executed_last3"]
                             for _, b, s in pairs)
    nums = "; ".join(f"sigma*={g}: GP error {_fmt(b['gp_error_last3'])} (w=100) vs {_fmt(s['gp_error_last3'])} "
                     f"(w=0.01), RMSE {_fmt(b['rmse_planned_executed_last3'])} vs "
                     f"{_fmt(s['rmse_planned_executed_last3'])}" for g, b, s in pairs)
    return ("a large weight (w = 1e2) with sigma* in {0.2, 1} explores too much",
            "for sigma* = 0.2 and 1, the last-three-episode GP error or RMSE with w = 100 exceeds twice that with "
            "w = 0.01", nums or "no runs", ok)


def claim_swing_up_achieved(L, execs):
    s = L.get("sigma*=0, w=0.01")
    if not s:
        return ("the swing-up is achieved on the Drake pendulum", "", "no runs", False)
    secs = [x for x in s["seconds_to_success"] if math.isfinite(x)]
    ok = s["achieved_last"] == s["runs"]
    return ("the swing-up is achieved on the Drake pendulum (sigma* = 0, w = 1e-2)",
            "in the last episode of every seed the executed pendulum ends within 0.1 rad of upright",
            f"achieved in the last episode: {s['achieved_last']}/{s['runs']} seeds; first success after "
            f"{', '.join(_fmt(x) for x in s['seconds_to_success'])} s of executed motion (babbling included)"
            + (f"; median {_fmt(float(np.median(secs)))} s" if secs else ""), ok)


PILCO_SECONDS = 17.5  # Deisenroth & Rasmussen, ICML 2011: real cart-pole swing-up after 17.5 s of interaction
PILCO_SOURCE = ("PILCO (Deisenroth and Rasmussen, ICML 2011) learned the cart-pole swing-up, its closest task, "
                "from scratch with 17.5 s of interaction with the real system")


def claim_pilco_efficiency(L, execs):
    s = L.get("sigma*=0, w=0.01")
    secs = s["seconds_to_success"] if s else []
    fin = [x for x in secs if math.isfinite(x)]
    med = float(np.median(secs)) if secs else math.inf
    ok = bool(secs) and med <= PILCO_SECONDS
    return ("data efficiency against PILCO: seconds of executed motion until the first swing-up",
            f"median over seeds of raico's executed seconds (babbling included) until the first episode that "
            f"ends within 0.1 rad of upright <= {PILCO_SECONDS} s ({PILCO_SOURCE})",
            f"raico: {', '.join(_fmt(x) for x in secs)} s over {len(secs)} seeds ({len(fin)} succeeded), "
            f"median {_fmt(med)} s; PILCO {PILCO_SECONDS} s", ok)


def claim_batch_cheaper(L, execs):
    e, b = L.get("every"), L.get("batch-100")
    if not (e and b):
        return ("batch-100 hyperparameter updates are much cheaper at similar error", "", "no runs", False)
    cheaper = b["fit_time_s_total"] <= 0.5 * e["fit_time_s_total"]
    similar = b["gp_error_last3"] <= 2 * e["gp_error_last3"]
    return ("batch-100 hyperparameter updates cost much less time than every-evaluation updates at similar "
            "prediction error", "total fit time of batch-100 at most half of every's, and its GP error over the "
            "last three evaluations at most twice every's",
            f"fit time {_fmt(b['fit_time_s_total'])} s (batch-100, {b['optimizations']} optimizations) vs "
            f"{_fmt(e['fit_time_s_total'])} s (every, {e['optimizations']}); GP error {_fmt(b['gp_error_last3'])} vs "
            f"{_fmt(e['gp_error_last3'])} rad/s^2", cheaper and similar)


def claim_reach_achieved(L, execs):
    got = {k: (s["achieved_last"], s["runs"], s["task_error_last3"]) for k, s in L.items()}
    ok = bool(got) and all(a == n for a, n, _ in got.values())
    return ("the learned-model planner reaches the target on the Drake robot",
            "the last evaluation's execution reaches the target to 5 cm, for every schedule and seed",
            "; ".join(f"{k}: {a}/{n}, task error over the last three {_fmt(e)} m" for k, (a, n, e) in got.items()), ok)


CLAIMS = {k[len("claim_"):]: v for k, v in globals().items() if k.startswith("claim_")}


def evaluate_claims(names: tuple[str, ...], S: dict, execs: list[dict], figure: str) -> list[dict]:
    """Rows ``{"figure", "claim", "criterion", "measured", "verdict"}`` for the named claims."""
    rows = []
    for c in names:
        claim, criterion, numbers, ok = CLAIMS[c](S, execs)
        rows.append({"figure": figure, "claim": claim, "criterion": criterion, "measured": numbers,
                     "verdict": "holds" if ok else "does not hold"})
    return rows
