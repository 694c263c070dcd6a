"""Per-variant summaries of an experiment's runs (medians over initial states), from run metrics.

Pure functions of the plan stage's metrics (``final_cost``, ``cost_ratio``,
``via_point_errors``, ...) and statuses, so they are unit-tested on synthetic runs.
"""

from __future__ import annotations

import math

import numpy as np


def median(a: np.ndarray) -> float:
    """Median of the finite entries of ``a`` (NaN if none)."""
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else math.nan


def largest_via_error(metrics: dict) -> float:
    """The largest via-point error of a run (m or rad), the held right sole left out."""
    errs = {k: v for k, v in (metrics.get("via_point_errors") or {}).items() if not k.startswith("r_sole")}
    if not errs:
        return math.nan
    return max(math.inf if v is None else v for v in errs.values())


EXECUTED_VIA_TOL = 0.01  # m, as the planning claim's tolerance


def executed_achieved(metrics: dict) -> bool:
    """An execution achieved the task: status ``ok`` and its largest executed via-point error (the held right sole
    left out) within ``EXECUTED_VIA_TOL``."""
    return metrics.get("status") == "ok" and largest_via_error(metrics) <= EXECUTED_VIA_TOL


def median_curve(curves: list[np.ndarray]) -> list[float]:
    """Elementwise median over runs of per-iteration cost curves; a run that stopped early (converged)
    keeps its last cost for the later iterations."""
    curves = [c for c in curves if c.size]
    if not curves:
        return []
    n = max(c.size for c in curves)
    padded = np.array([np.concatenate([c, np.full(n - c.size, c[-1])]) for c in curves])
    return [median(padded[:, j]) for j in range(n)]


def relative_change(curve: np.ndarray, k: int) -> float:
    """``|c[-1] - c[-1-k]| / |c[-1]|``: how much a cost curve still moved over its last ``k``
    iterations (NaN if it is shorter or not finite there)."""
    c = np.asarray(curve, float)
    if c.size <= k or not (np.isfinite(c[-1]) and np.isfinite(c[-1 - k])) or c[-1] == 0:
        return math.nan
    return float(abs(c[-1] - c[-1 - k]) / abs(c[-1]))


def summarize(label: str, runs: list[dict]) -> dict:
    """Summary of one variant's runs; each run is ``{"status", "metrics"}``."""
    ms = [r["metrics"] for r in runs]
    st = [str(r["status"]) for r in runs]

    def col(key: str, default: float = math.nan) -> np.ndarray:
        return np.array([default if m.get(key) is None else m.get(key) for m in ms], float)

    ratio, final, first = col("cost_ratio"), col("final_cost"), col("first_iteration_cost")
    curves = [np.array([math.nan if c is None else c for c in m.get("cost_history") or []], float)
              for m, status in zip(ms, st) if status != "diverged"]
    return {"label": label, "runs": len(ms), "diverged": st.count("diverged"),
            "cost_curve_median": median_curve(curves), "flat_last5_median": median(np.array(
                [relative_change(c, 5) for c in curves], float)),
            "converged": st.count("converged"), "final_cost_median": median(final),
            "first_cost_median": median(first), "cost_ratio_median": median(ratio),
            "cost_ratio_max": float(np.nanmax(ratio)) if np.isfinite(ratio).any() else math.nan,
            "final_cost_max": float(np.nanmax(final)) if np.isfinite(final).any() else math.inf,
            "max_via_error_median": median(np.array([largest_via_error(m) for m in ms], float)),
            # per run, in the order given (the initial states' seeds): for comparisons paired by seed
            "final_costs": [math.inf if s == "diverged" else float(x) for x, s in zip(final, st)],
            "via_errors": [math.inf if s == "diverged" else largest_via_error(m) for m, s in zip(ms, st)],
            **{f"{k}_median": median(col(k)) for k in ("head_joint_excursion", "left_arm_joint_excursion",
                                                       "left_hand_excursion") if any(k in m for m in ms)},
            "wall_time_median_s": median(col("wall_time_s"))}


def integration_summary(metrics: list[dict]) -> dict:
    """Medians over a variant's open-loop Drake integrations (``execute --open-loop``; their metrics): RMS and
    largest joint-position error against the plan (rad), largest via-point error of Drake's trajectory (m)."""
    def col(key: str) -> np.ndarray:
        return np.array([math.nan if m.get(key) is None else m[key] for m in metrics], float)

    rmse = col("rmse_planned_executed")
    return {"integration_runs": len(metrics), "integration_rmse_median": median(rmse),
            "integration_rmse_max": float(np.max(rmse)) if rmse.size else math.nan,
            "integration_max_error_median": median(col("max_tracking_error")),
            "integration_via_error_median": median(np.array([largest_via_error(m) for m in metrics], float))}


def _curves(runs: list[dict], key: str) -> np.ndarray:
    """``(runs, episodes)`` of a per-episode list in each run's learn metrics (NaN-padded; None -> NaN)."""
    rows = [[math.nan if v is None else float(v) for v in (m.get(key) or [])] for m in runs]
    n = max((len(r) for r in rows), default=0)
    out = np.full((len(rows), n), math.nan)
    for i, r in enumerate(rows):
        out[i, :len(r)] = r
    return out


def seconds_to_success(m: dict) -> float:
    """Executed seconds (babbling included) until the end of the first episode whose execution
    achieved the task; inf if none did."""
    first = m.get("first_success_episode")
    if first is None:
        return math.inf
    return float(m.get("babble_seconds", 0.0)) + float(sum((m.get("executed_seconds") or [])[:first]))


def summarize_learn(label: str, runs: list[dict]) -> dict:
    """Summary of one learning setting over its seeds; ``runs`` are the learn outcomes' metrics.

    ``*_first3`` / ``*_last3``: the median over seeds of the mean over the first / last three
    episodes (fewer if the run is shorter)."""
    out: dict = {"label": label, "runs": len(runs)}
    for key in ("gp_error", "gp_error_heldout", "rmse_planned_executed", "task_error", "planned_task_error",
                "fit_time_s", "plan_time_s", "execute_time_s", "torque_saturation"):
        C = _curves(runs, key)
        k = min(3, C.shape[1]) if C.size else 0
        with np.errstate(all="ignore"):
            out[f"{key}_curve"] = [median(C[:, j]) for j in range(C.shape[1])]
            out[f"{key}_band"] = [[float(np.nanmin(C[:, j])), float(np.nanmax(C[:, j]))]
                                  if np.isfinite(C[:, j]).any() else [math.nan, math.nan] for j in range(C.shape[1])]
            out[f"{key}_first3"] = median(np.nanmean(C[:, :k], axis=1)) if k else math.nan
            out[f"{key}_last3"] = median(np.nanmean(C[:, -k:], axis=1)) if k else math.nan
            out[f"{key}_total"] = median(np.nansum(C, axis=1)) if C.size else math.nan
    last = _curves(runs, "task_error")
    # per seed (in the order given) the last episode's executed task error: for comparisons paired by seed
    out["task_error_last_by_seed"] = [float(r[np.isfinite(r)][-1]) if np.isfinite(r).any() else math.nan for r in last]
    ach = _curves(runs, "achieved")
    out["achieved_last"] = int(np.nansum(ach[:, -1])) if ach.size else 0
    out["seconds_to_success"] = [seconds_to_success(m) for m in runs]
    out["first_success_episode"] = [m.get("first_success_episode") for m in runs]
    out["optimizations"] = [int(np.nansum(r)) for r in _curves(runs, "optimized")]
    out["episodes_feeding_data"] = [m.get("episodes_feeding_data") for m in runs]
    out["episodes_truncated"] = [m.get("episodes_truncated") for m in runs]
    out["tracking_lost"] = int(sum(sum(1 for st in (m.get("execution_status") or []) if st == "tracking-lost")
                                   for m in runs))
    return out


# ----------------------------------------------------------------------------- the same results in two figures
# What a variant's runs achieved (its path there, the first-iteration cost and the wall time, left out: the first
# depends on the problem's terms at the start, the second is a measurement that never repeats).
RESULT_KEYS = ("runs", "diverged", "converged", "final_cost_median", "final_cost_max", "max_via_error_median")


def relative_difference(a: float | None, b: float | None) -> float:
    """``|a - b| / max(|a|, |b|)``: 0 when both are equal (also both NaN or None, or the same infinity),
    ``inf`` when only one is finite or they are opposite infinities."""
    a = math.nan if a is None else float(a)
    b = math.nan if b is None else float(b)
    if a == b or (math.isnan(a) and math.isnan(b)):
        return 0.0
    if not (math.isfinite(a) and math.isfinite(b)):
        return math.inf
    return abs(a - b) / max(abs(a), abs(b))


def identical_variants(A, B, rtol: float = 1e-12, keys: tuple[str, ...] = RESULT_KEYS) -> list[tuple[str, float]]:
    """The variants of two figures whose summaries (:func:`summarize` rows, as a list or as a dict
    label -> row) agree on every one of ``keys`` to the relative ``rtol``: ``(label, largest relative
    difference)`` each, in ``A``'s order; labels found in only one figure, or rows lacking one of
    ``keys``, are skipped."""
    rows_a = A if isinstance(A, dict) else {r["label"]: r for r in A}
    rows_b = B if isinstance(B, dict) else {r["label"]: r for r in B}
    out = []
    for label, a in rows_a.items():
        b = rows_b.get(label)
        if b is None or any(k not in a or k not in b for k in keys):
            continue
        diff = max((relative_difference(a.get(k), b.get(k)) for k in keys), default=0.0)
        if diff <= rtol:
            out.append((label, diff))
    return out
