"""Evaluation metrics of one run, shared by the plan, execute and evaluate stages (SPEC §8).

Via-point errors of a trajectory against its objective; execution metrics of a rollout.
"""

from __future__ import annotations

import numpy as np

from stages.plan.costs import ViaPoint


def via_point_errors(problem, X: np.ndarray) -> dict[str, float]:
    """``{"<term>@<t>": error}``: Euclidean task error over the dimensions that count.

    Dimensions count whose precision is at least 1% of the largest (balance: the lateral
    axis only). Terms held at every step (the Nao's right sole) report their largest error.
    """
    n_q = X.shape[1] // 2
    out: dict[str, float] = {}
    for term in problem.state_terms:
        if not isinstance(term, ViaPoint):
            continue
        w = np.diag(term.C)
        keep = w >= 0.01 * w.max()
        idx = np.flatnonzero(term.active(np.arange(problem.T + 1)))
        if not np.all(np.isfinite(X[idx])):
            errs = np.full(idx.size, np.inf)
        else:
            phi, _ = term.taskmap.values_and_jacobians(X[idx, :n_q])
            errs = np.linalg.norm((term.target - phi)[:, keep], axis=1)
        if idx.size > 3:
            out[f"{term.name}@max"] = float(errs.max())
        else:
            out.update({f"{term.name}@{t}": float(e) for t, e in zip(idx, errs)})
    return out


def execution_metrics(problem, X: np.ndarray, X_plan: np.ndarray, tau: np.ndarray, cog: np.ndarray | None,
                      margin: np.ndarray | None, robot) -> dict:
    """Metrics of one execution: status, via-point errors of the executed ``X (T+1, n_x)``,
    planned-vs-executed RMSE (rad), largest torque (N m); for the Nao the CoG against the
    support polygon (``margin (T+1,)`` m, > 0 inside) and the right sole's drift (m)."""
    n = X.shape[1] // 2
    finite = bool(np.all(np.isfinite(X)))
    with np.errstate(invalid="ignore"):
        rmse = float(np.sqrt(np.nanmean((X[:, :n] - X_plan[:, :n]) ** 2))) if finite else float("inf")
    m = {"status": "ok" if finite else "failed",
         "via_point_errors": via_point_errors(problem, X) if finite else {},
         "rmse_planned_executed": rmse,
         "max_abs_torque": float(np.nanmax(np.abs(tau))) if tau.size else 0.0}
    if cog is not None:
        inside = margin > 0
        sole0 = robot.plant.GetFrameByName("r_sole")
        ctx = robot.plant.CreateDefaultContext()
        drift = []
        for k in (0, len(X) - 1):
            robot.plant.SetPositions(ctx, robot.to_plant_q(X[k, :n]))
            drift.append(sole0.CalcPoseInWorld(ctx).translation())
        m.update(cog_inside_fraction=float(np.mean(inside)), cog_min_margin=float(np.nanmin(margin)),
                 r_sole_drift=float(np.linalg.norm(drift[1] - drift[0])))
    return m
