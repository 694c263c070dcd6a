"""Task achieved: each via-point judged in its own unit against its tolerance.

A via-point's task map says which tolerance kinds judge it (the map table's ``tolerance`` column,
:mod:`raico.planning.term_kinds`: a position in m, an orientation in rad, ...; a frame placement both); its
error is the largest Euclidean error over its steps, against the term's own ``tol`` or the kind's default
(:data:`TASK_TOLERANCES`). The plan, execute and evaluate stages report the verdict (``metrics["task"]``).
"""

from __future__ import annotations

import math

import numpy as np

from raico.planning.costs import ViaPoint
from raico.planning.term_kinds import kind_of_map

TASK_TOLERANCES = {"position": (0.01, "m"), "orientation": (0.05, "rad"), "com": (0.01, "m"),
                   "posture": (0.05, "rad")}   # kind -> (default tolerance, unit)


def task_kinds(term) -> list[tuple[str, np.ndarray]]:
    """A via-point's tolerance kinds and the task-map rows each covers: ``[(kind, rows)]``, its task map's
    row of the map table (``raico.planning.term_kinds``, column ``tolerance``); ``[]`` for a map of no kind."""
    row = kind_of_map(term.taskmap)
    rows = np.arange(term.taskmap.dim)
    return [] if row is None else [(kind, rows[part]) for kind, part in row.tolerance]


def task_errors(problem, X: np.ndarray) -> dict[str, dict]:
    """Per via-point (a frame placement: ``NAME`` its position, ``NAME/orientation`` its orientation):
    ``{"kind", "unit", "error", "tol"}``: the largest Euclidean error over its steps (the dimensions
    that count, as :func:`via_point_errors`; ``inf`` where a state is not finite) in the kind's unit,
    and its tolerance: the term's own ``tol`` (a number, or for a placement ``[m, rad]``), else the
    kind's default (:data:`TASK_TOLERANCES`). Terms that also cost step 0 are left out."""
    n_q = X.shape[1] // 2
    out: dict[str, dict] = {}
    for term in problem.state_terms:
        if not isinstance(term, ViaPoint) or term.is_active_at(0) or term.weight == 0:
            continue
        kinds = task_kinds(term)
        if not kinds:
            continue
        w = np.diag(term.C)
        idx = np.flatnonzero(term.active(np.arange(problem.T + 1)))
        good = np.all(np.isfinite(X[idx]), axis=1)
        diff = np.full((idx.size, term.taskmap.dim), np.inf)
        if good.any():
            phi, _ = term.taskmap.values_and_jacobians(X[idx[good], :n_q])
            diff[good] = term.target - phi
        own = getattr(term, "tol", None)
        own = [own] if own is not None and np.ndim(own) == 0 else own
        for k, (kind, rows) in enumerate(kinds):
            keep = rows[w[rows] >= 0.01 * w.max()]
            if not keep.size:
                continue
            tol, unit = TASK_TOLERANCES[kind]
            if own is not None and k < len(own):
                tol = float(own[k])
            err = float(np.max(np.linalg.norm(diff[:, keep], axis=1))) if idx.size else 0.0
            name = term.name if k == 0 else f"{term.name}/{kind}"
            out[name] = {"kind": kind, "unit": unit, "error": err, "tol": tol}
    return out


def task_verdict(errors: dict[str, dict]) -> dict | None:
    """Whether every term of :func:`task_errors` is within its tolerance, and the worst term (the largest
    error over tolerance): ``{"achieved", "worst", "kind", "unit", "error", "tol"}``; None without terms."""
    if not errors:
        return None
    name, e = max(errors.items(), key=lambda kv: kv[1]["error"] / kv[1]["tol"] if kv[1]["tol"] > 0
                  else (math.inf if kv[1]["error"] > 0 else 0.0))
    achieved = all(v["error"] <= v["tol"] for v in errors.values())
    return {"achieved": bool(achieved), "worst": name, **e}


def task_line(verdict: dict) -> str:
    """``task achieved: worst term 'reach' 0.00632 m <= 0.01 m (position)`` (or ``missed``, ``>``)."""
    ok = verdict["error"] <= verdict["tol"]
    return (f"task {'achieved' if verdict['achieved'] else 'missed'}: worst term '{verdict['worst']}' "
            f"{verdict['error']:.3g} {verdict['unit']} {'<=' if ok else '>'} {verdict['tol']:g} {verdict['unit']} "
            f"({verdict['kind']})")
