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


def summarize(label: str, runs: list[dict]) -> dict:
    """Summary of one variant's runs; each run is ``{"status", "metrics"}``."""
    ms = [r["metrics"] for r in runs]
    st = [str(r["status"]) for r in runs]

    def col(key: str, default: float = math.nan) -> np.ndarray:
        return np.array([default if m.get(key) is None else m.get(key) for m in ms], float)

    ratio, final, first = col("cost_ratio"), col("final_cost"), col("first_iteration_cost")
    return {"label": label, "runs": len(ms), "diverged": st.count("diverged"),
            "converged": st.count("converged"), "final_cost_median": median(final),
            "first_cost_median": median(first), "cost_ratio_median": median(ratio),
            "cost_ratio_max": float(np.nanmax(ratio)) if np.isfinite(ratio).any() else math.nan,
            "final_cost_max": float(np.nanmax(final)) if np.isfinite(final).any() else math.inf,
            "max_via_error_median": median(np.array([largest_via_error(m) for m in ms], float)),
            "wall_time_median_s": median(col("wall_time_s"))}
