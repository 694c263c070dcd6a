"""Balance-aware Nao objectives: the ``--balance`` task option.

The planning model is welded at the left sole (world frame = left sole frame, ground z = 0), so
the support polygon is fixed in that frame for the whole movement:

- ``support`` (double support): the convex hull of both soles' corners (the robot's sole outline in
  each sole frame; the right sole at its start pose, which the task's ``r_sole`` term holds at
  every step 1..T);
- ``single`` (balance on the left foot): the left sole alone; the right sole's ``r_sole`` term
  is dropped (its contact released), its four corners kept above the ground (or above their start
  heights where the perturbed start posture has them below it) until step ``T // 3 - 1`` and
  lifted at least ``LIFT`` from step ``T // 3`` on (a one-sided via-point held to the end).

At every step 1..T the CoG's ground projection (quasi-static) is kept at least ``MARGIN``
inside every polygon edge by ``raico.planning.costs.TaskInequality`` (squared hinge, weight
``W_SUPPORT``), and every joint ``JOINT_MARGIN`` inside its range (weight ``W_RANGE``): the free
robot cannot go beyond a joint's limit to shift its CoG. Before planning, every CoG via-point whose target's ground projection lies
outside the polygon shrunk by the margin is reported (its static margin from the model, m) and
moved to the nearest point of the shrunk polygon; :class:`BalanceReport` says which, and the
moved terms keep their ``requested_target`` in the description.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from raico.planning import objective as ob
from raico.plants.polygons import convex_hull, halfplanes, nearest_feasible, signed_margin
from raico.plants.robots import Robot

BALANCE_MODES = ("none", "support", "single")
MARGIN = 0.025  # m, CoG ground projection inside every support-polygon edge by at least this (the default: with
# 1.5 cm the stabilizer's runs of seed 0's plans tipped over a sole's edge, in double and in single support; with
# 2.5 cm the ten of each stood: raico/thesis/figures.py, fig3.4-support and fig3.4-single)
NO_BALANCE_MARGIN = 0.015  # m, what a plan without a balance term stores (its cache key; the margin means nothing)
W_SUPPORT = 1e6  # per m^2 of margin violation (the balance task's lateral CoG weight)
LIFT = 0.02  # m, the right sole's lowest corner above the ground in single support ...
LIFT_BOUND = 0.025  # m, ... planned with 5 mm to spare (the bound is a soft penalty)
W_LIFT = 1e6  # per m^2 below a height bound
JOINT_MARGIN = 0.03  # rad, every joint planned this far inside its range ...
W_RANGE = 1e5  # ... per rad^2 beyond it (the stabilizer keeps 0.02 rad: raico/stages/execute/wbc.py LIMIT_MARGIN)


# ------------------------------------------------------------------ polygon geometry (world xy, m)
def sole_corners(robot: Robot, q: np.ndarray, frame: str) -> np.ndarray:
    """World positions ``(4, 3)`` (m) of the corners of sole ``frame`` at planning positions ``q (n_q,)``."""
    X = robot.plant.GetFrameByName(frame).CalcPoseInWorld(robot.set_state(q))
    local = np.c_[robot.support_polygon, np.zeros(len(robot.support_polygon))]
    return local @ X.rotation().matrix().T + X.translation()


def support_polygon(robot: Robot, q0: np.ndarray, mode: str) -> np.ndarray:
    """The support polygon ``(k, 2)`` (m, world xy = left sole frame, counter-clockwise) of a
    balance mode at the start posture ``q0``: both soles' hull (``support``) or the left sole
    (``single``)."""
    if mode not in BALANCE_MODES[1:]:
        raise ValueError(f"unknown balance '{mode}': choose one of {', '.join(BALANCE_MODES)}")
    soles = robot.feet if mode == "support" else robot.feet[:1]  # the stance sole first
    return convex_hull(np.vstack([sole_corners(robot, q0, s)[:, :2] for s in soles]))


# ------------------------------------------------------------------ the objective
@dataclass
class MovedViaPoint:
    """A CoG via-point moved before planning: its static margin (m, < 0 outside) and targets (m)."""

    name: str
    step: int
    static_margin: float
    requested: list[float]
    planned: list[float]


@dataclass
class BalanceReport:
    """What ``apply_balance`` did: the polygon ``(k, 2)`` (m), the margin and the moved via-points."""

    mode: str
    polygon: np.ndarray
    margin: float
    moved: list[MovedViaPoint] = field(default_factory=list)

    def line(self) -> str | None:
        """One line on the moved via-points (``None`` if none moved)."""
        if not self.moved:
            return None
        where = "both soles" if self.mode == "support" else "the left sole"
        parts = []
        for m in self.moved:
            what = (f"statically infeasible: its CoG lies {-m.static_margin:.4f} m outside the support polygon"
                    if m.static_margin < 0 else
                    f"within the margin: its CoG lies {m.static_margin:.4f} m inside the support polygon")
            parts.append(f"{m.name} (step {m.step}) is {what}, planned at ({m.planned[0]:.4f}, {m.planned[1]:.4f}) m "
                         f"instead of ({m.requested[0]:.4f}, {m.requested[1]:.4f})")
        return (f"balance {self.mode} ({where}, margin {self.margin} m): " + "; ".join(parts)
                + " (the nearest points with the margin)")

    def to_dict(self) -> dict:
        """JSON-able: mode, margin (m), polygon ``(k, 2)`` (m), moved via-points and the ``note`` line."""
        return {"mode": self.mode, "margin": self.margin, "polygon": self.polygon.tolist(),
                "moved": [vars(m) for m in self.moved], "note": self.line()}


def _is_cog_xy(d: dict) -> bool:
    return d.get("term") == "via" and d["map"]["map"] == "cog" and {0, 1} <= set(d["map"]["axes"])


def _steps(times) -> list[int]:
    return list(range(times["from"], times["to"] + 1)) if isinstance(times, dict) else list(times)


def apply_balance(robot: Robot, q0: np.ndarray, T: int, terms: list, mode: str,
                  margin: float = MARGIN) -> tuple[list, BalanceReport | None]:
    """The task's term descriptions with the balance objective of ``mode`` (module docstring) and
    its report; ``mode == "none"`` returns ``terms`` unchanged and no report."""
    if mode == "none":
        return terms, None
    poly = support_polygon(robot, q0, mode)
    report = BalanceReport(mode, poly, margin)
    out = []
    for d in terms:
        if mode == "single" and d.get("name") == "r_sole":
            continue  # the right sole's contact released
        if _is_cog_xy(d):
            axes = list(d["map"]["axes"])
            target = np.array(d["target"], float)
            xy = target[[axes.index(0), axes.index(1)]]
            m = signed_margin(poly, xy)
            if m < margin:
                new_xy = nearest_feasible(poly, margin, xy)
                new = target.copy()
                new[[axes.index(0), axes.index(1)]] = new_xy
                d = {**d, "target": new.tolist(), "requested_target": target.tolist()}
                report.moved += [MovedViaPoint(d["name"], t, m, xy.tolist(), new_xy.tolist())
                                 for t in _steps(d["times"])]
        out.append(d)
    A, b = halfplanes(poly)
    out.append(ob.inequality("support", ob.cog(axes=(0, 1), name="cog_xy"), A, b - margin, range(1, T + 1),
                             W_SUPPORT, polygon=poly.tolist(), margin=margin, mode=mode))
    # the joints inside their ranges: with both soles held, a CoG shift can ask more ankle roll than the joint has
    # (measured: fig3.4-inside's plans ask RAnkleRoll up to 0.44 rad, its limit is 0.398); the free robot cannot
    n = robot.n_q
    out.append(ob.inequality("joint_range", ob.joints(), np.vstack([np.eye(n), -np.eye(n)]),
                             np.r_[robot.upper - JOINT_MARGIN, -(robot.lower + JOINT_MARGIN)], range(1, T + 1),
                             W_RANGE, margin=JOINT_MARGIN))
    if mode == "single":
        swing = robot.feet[1]
        sole = ob.frame_points(swing, "r_sole_heights", axes=(2,),
                               points=np.c_[robot.support_polygon, np.zeros(len(robot.support_polygon))])
        lift_from = max(T // 3, 1)
        if lift_from > 1:  # not below the ground, nor below a start corner that is (a perturbed start)
            lower = np.minimum(sole_corners(robot, q0, swing)[:, 2], 0.0)
            out.append(ob.inequality("r_sole_clear", sole, -np.eye(4), -lower, range(1, lift_from),
                                     W_LIFT, lower=lower.tolist()))
        out.append(ob.inequality("r_sole_lift", sole, -np.eye(4), -LIFT_BOUND * np.ones(4), range(lift_from, T + 1),
                                 W_LIFT, lower=LIFT_BOUND))
    return out, report


def cog_margins(robot: Robot, X: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Static margin (m) of the CoG's ground projection against ``poly (k, 2)`` at every row of
    ``X (K, n_x)`` (NaN where a row is not finite)."""
    from raico.plants.taskmaps import CenterOfMass

    n_q = X.shape[1] // 2
    C, _ = CenterOfMass(robot, axes=(0, 1)).values_and_jacobians(np.asarray(X, float)[:, :n_q])
    return np.array([signed_margin(poly, c) if np.all(np.isfinite(c)) else np.nan for c in C])
