"""Evaluation metrics of one run, shared by the plan, execute and evaluate stages.

Via-point errors of a trajectory against its objective; execution metrics of a rollout:
its status, tracking, limits and, for the free-standing Nao, the CoG against the support
polygon of the sole corners that are in contact.

Execution status, first that applies:

- ``diverged``: a non-finite state, or the simulator failed (the execute stage also marks the
  execution of a diverged plan so, and does not execute a plan that is not finite);
- ``fell`` (Nao): at some sample the torso is more than ``FALL_TORSO_DROP`` below its
  planned height, or its z axis is more than ``FALL_TORSO_TILT`` from the planned torso's
  z axis, or a sole lifts: its lowest corner rises more than ``FOOT_LIFT`` above the planned
  lowest corner's height (clipped at the ground; both soles stay on the ground in every Nao
  task; a foot rocking on an edge keeps that edge down and is judged by the torso). Planned values:
  the fixed-base model along the plan (left sole at the world origin, as on the free robot
  at the start). A plan whose initial posture cannot stand on flat ground (its soles not
  level: ``raico.plants.floating``) has fallen at t = 0;
- ``tracking-lost``: the largest joint error ``|q - q_plan|`` exceeds ``TRACKING_LOST`` (rad; on a
  prismatic joint ``TRACKING_LOST_M``, m) at some sample; under receding-horizon control ``q_plan`` is
  the controller's own prediction of the sample, which may leave the plan on purpose;
- ``limits``: in more than ``LIMITS_SHARE`` of the samples some joint is held at a position
  limit (within ``LIMIT_TOL`` of it, or past it, while the plan wants it more than ``LIMIT_TOL``
  elsewhere) or some actuator is at its effort limit because the controller asks for it (not a motor
  that only clamps the process noise; not the pendulum, whose +-10 N m is its task's control limit);
- ``ok``: none of these.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from raico.planning.achieved import task_errors, task_verdict  # noqa: F401  (the metrics of a run: re-exported)
from raico.planning.costs import via_point_errors  # noqa: F401  (re-exported)
from raico.plants.polygons import signed_margin  # noqa: F401  (re-exported)

FALL_TORSO_DROP = 0.10  # m, torso origin below its planned height
FALL_TORSO_TILT = 0.5  # rad, angle between the executed and the planned torso z axes
FOOT_LIFT = 0.01  # m, a sole's lowest corner above its planned height
TRACKING_LOST = 0.5  # rad, largest planned-vs-executed joint error
TRACKING_LOST_M = 0.1  # m, the same on a prismatic joint (a lift: 0.5 m would be its whole range)
LIMITS_SHARE = 0.2  # share of the samples with a joint at a position limit or an actuator at its effort limit
LIMIT_TOL = 0.01  # rad, a joint within this of a position limit is at it
CONTACT_TOL = 1e-3  # m, a sole corner this close to the ground (or below) is in contact ...
CONTACT_FORCE = 1e-3  # N, ... when Drake reports at least this normal force on its sole
STATUSES = ("ok", "limits", "tracking-lost", "fell", "diverged", "collided")
THRESHOLDS = {"fall_torso_drop_m": FALL_TORSO_DROP, "fall_torso_tilt_rad": FALL_TORSO_TILT,
              "foot_lift_m": FOOT_LIFT, "tracking_lost_rad": TRACKING_LOST, "limits_share": LIMITS_SHARE,
              "limit_tol_rad": LIMIT_TOL, "contact_tol_m": CONTACT_TOL}
STANDING = ("fall_torso_drop_m", "fall_torso_tilt_rad", "foot_lift_m", "contact_tol_m")  # the free-standing Nao's only


# ----------------------------------------------------------------------------- "task achieved", one judgement
def executed_task(task: dict | None, status: str) -> dict | None:
    """Execute's judgement of an execution (the ``execute`` line, ``learn`` and ``evaluate`` all use it): the
    task verdict of its trajectory (``metrics["task"]``, :func:`raico.planning.achieved.task_verdict`: every via-point
    term within its tolerance, in its unit) achieved only where the execution's ``status`` is ``ok`` too;
    the verdict's fields plus ``terms_within`` (the terms' own verdict) and ``status``. None without terms."""
    if not isinstance(task, dict):
        return None
    within = bool(task["achieved"])
    return {**task, "achieved": within and status == "ok", "terms_within": within, "status": status}


def task_note(verdict: dict) -> str:
    """One verdict as a line: ``task missed: worst term 'reach' 0.0157 m > 0.01 m (position)``, with
    ``, status tracking-lost`` where the terms were within their tolerances but the execution's status was
    not ok (:func:`executed_task`)."""
    from raico.planning.achieved import task_line

    tail = (f", status {verdict['status']}" if verdict.get("terms_within") and not verdict["achieved"]
            and verdict.get("status") not in (None, "ok") else "")
    return task_line(verdict) + tail


def prismatic_joints(robot) -> np.ndarray:
    """``(n_q,)`` bool: which of ``robot``'s planning joints are prismatic (their unit m, N)."""
    return np.array([robot.plant.GetJointByName(name).type_name() == "prismatic" for name in robot.joint_names],
                    bool)


def used_thresholds(standing: bool) -> dict[str, float]:
    """The thresholds an execution's status is judged by: a fixed-base robot's leave out the falls and feet."""
    return {k: v for k, v in THRESHOLDS.items() if standing or k not in STANDING}


# ----------------------------------------------------------------------------- support polygon
def contact_polygon(corners: np.ndarray, force: np.ndarray) -> np.ndarray:
    """The support polygon ``(k, 2)`` (m, world xy, convex hull, k <= 8) of the sole corners in
    contact: corners ``(2, 4, 3)`` at most ``CONTACT_TOL`` above the ground whose sole carries
    at least ``CONTACT_FORCE`` (``force (2,)`` N, Drake's contact results; NaN: no results yet,
    at t = 0, where the height decides). Fewer than three points in contact give a segment, a
    point or nothing."""
    touching = [corners[s, c, :2] for s in range(corners.shape[0]) for c in range(corners.shape[1])
                if not force[s] < CONTACT_FORCE and corners[s, c, 2] <= CONTACT_TOL]
    if len(touching) < 3:
        return np.array(touching).reshape(-1, 2)
    pts = np.array(touching)
    from scipy.spatial import ConvexHull, QhullError

    try:
        return pts[ConvexHull(pts).vertices]
    except QhullError:  # collinear corners: the extreme two
        d = pts - pts.mean(0)
        axis = np.linalg.svd(d)[2][0]
        s = d @ axis
        return pts[[int(np.argmin(s)), int(np.argmax(s))]]


def padded_polygons(polys: list) -> np.ndarray:
    """Polygons of different vertex counts as one ``(K, kmax, 2)`` array, NaN-padded (m)."""
    kmax = max((len(p) for p in polys), default=0)
    out = np.full((len(polys), max(kmax, 1), 2), np.nan)
    for k, p in enumerate(polys):
        out[k, :len(p)] = p
    return out


def support_polygons(corners: np.ndarray, force: np.ndarray, cog: np.ndarray) -> tuple[list, np.ndarray]:
    """Per sample: the contact polygon and the CoG's signed margin against it (NaN when not finite)."""
    polys, margin = [], np.full(len(corners), np.nan)
    for k in range(len(corners)):
        if not (np.all(np.isfinite(corners[k])) and np.all(np.isfinite(cog[k]))):
            polys.append(np.zeros((0, 2)))
            continue
        poly = contact_polygon(corners[k], force[k])
        polys.append(poly)
        margin[k] = signed_margin(poly, cog[k, :2])
    return polys, margin


def point_margins(polys: list, points: np.ndarray) -> np.ndarray:
    """Signed margin ``(K,)`` (m, positive inside) of each ground point ``points (K, 2)`` against that
    sample's contact polygon (``support_polygons``); NaN where the point is not finite or there is no polygon."""
    out = np.full(len(points), np.nan)
    for k, (poly, p) in enumerate(zip(polys, points)):
        if len(poly) and np.all(np.isfinite(p)):
            out[k] = signed_margin(poly, p)
    return out


# ----------------------------------------------------------------------------- status
def first_true(flags: np.ndarray) -> int | None:
    hits = np.flatnonzero(np.asarray(flags, bool))
    return int(hits[0]) if hits.size else None


def fall_flags(torso_height: np.ndarray, torso_height_plan: np.ndarray, torso_z: np.ndarray,
               torso_z_plan: np.ndarray, corner_height: np.ndarray, corner_height_plan: np.ndarray) -> dict:
    """Per-sample fall conditions ``(K,)`` bool: torso dropped, torso tilted, a foot lifted
    (heights m, torso z axes ``(K, 3)``, sole corner heights ``(K, 2, 4)``). A foot lifts when
    its lowest corner rises more than ``FOOT_LIFT`` above the plan's lowest corner of that sole;
    a planned height below the ground counts as on the ground (0)."""
    lowest_plan = np.maximum(corner_height_plan.min(axis=2), 0.0)
    with np.errstate(invalid="ignore"):
        cos = np.clip(np.sum(torso_z * torso_z_plan, axis=1), -1.0, 1.0)
        return {"torso_dropped": torso_height < torso_height_plan - FALL_TORSO_DROP,
                "torso_tilted": np.arccos(cos) > FALL_TORSO_TILT,
                "foot_lifted": np.any(corner_height.min(axis=2) - lowest_plan > FOOT_LIFT, axis=1)}


def position_limit_joints(Q: np.ndarray, Q_plan: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """``(K, n)``: joint held at a position limit: within ``LIMIT_TOL`` of it (or past it) while
    the plan wants it more than ``LIMIT_TOL`` elsewhere (inside or beyond the limit)."""
    with np.errstate(invalid="ignore"):
        at = (Q >= upper - LIMIT_TOL) | (Q <= lower + LIMIT_TOL)
        return at & (np.abs(Q_plan - Q) > LIMIT_TOL)


def position_limit_flags(Q: np.ndarray, Q_plan: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """``(K,)``: some joint held at a position limit (``position_limit_joints``)."""
    return np.any(position_limit_joints(Q, Q_plan, lower, upper), axis=1)


def execution_status(finite: np.ndarray, fell: np.ndarray | None, tracking_error: np.ndarray,
                     at_limit: np.ndarray, dt: float) -> tuple[str, float | None, str]:
    """``(status, failure time s or None, reason)`` from per-sample flags ``(K,)`` (see the module
    docstring); ``at_limit`` has one flag per sample, limits are judged on its share."""
    bad = first_true(~np.asarray(finite, bool))
    if bad is not None:
        return "diverged", bad * dt, f"non-finite state at t = {bad * dt:.3g} s"
    if fell is not None:
        k = first_true(fell)
        if k is not None:
            return "fell", k * dt, f"fell at t = {k * dt:.3g} s"
    k = first_true(np.asarray(tracking_error) > TRACKING_LOST)
    if k is not None:
        return ("tracking-lost", k * dt, f"joint error above {TRACKING_LOST} rad at t = {k * dt:.3g} s")
    share = float(np.mean(at_limit)) if len(at_limit) else 0.0
    if share > LIMITS_SHARE:
        k = first_true(at_limit)
        return "limits", k * dt, f"at a joint or effort limit in {share:.0%} of the samples (> {LIMITS_SHARE:.0%})"
    return "ok", None, "ok"


def execution_metrics(problem, X: np.ndarray, X_plan: np.ndarray, tau: np.ndarray, robot, dt: float,
                      effort_at_limit: np.ndarray, floating: dict | None = None, effort_is_limit: bool = True,
                      effort_clamped: ArrayLike | None = None, X_track: np.ndarray | None = None) -> dict:
    """Metrics of one execution (``X (T+1, n_x)`` executed, ``tau (T, n_q)`` applied torques N m,
    ``effort_at_limit (T, n_q)`` per joint, or ``(T,)``): status (module docstring), via-point errors, planned-vs-executed
    RMSE and largest error (rad), largest torque (N m), limit shares; for a floating robot
    (``floating``: per-sample ``cog``, ``corners``, ``sole_force``, torso and planned values) the CoG
    against the contact polygon, the feet's drift and whether it stood. ``effort_is_limit`` False:
    effort saturation is reported (``torque_saturation``) but does not count towards ``limits``
    (the pendulum, whose torque bound is its task's control limit). ``effort_clamped (T,)``: some motor clamped
    the command plus the noise in step k (``effort_clamped_fraction``, per sample as the limit shares).
    ``X_track (T+1, n_x)``: what the controller aimed at, where it is not the plan (a receding-horizon
    controller's own predictions): ``tracking-lost`` and a joint held at a limit it was not aimed at are
    judged against it; the planned-vs-executed errors stay against the plan."""
    n = X.shape[1] // 2
    K = len(X)
    finite = np.all(np.isfinite(X), axis=1)
    Q, Qp = X[:, :n], X_plan[:, :n]
    Qt = Qp if X_track is None else X_track[:, :n]    # the controller's aim
    prismatic = prismatic_joints(robot)
    # a joint's error in TRACKING_LOST's terms: a prismatic joint's m scaled by TRACKING_LOST / TRACKING_LOST_M
    lost_scale = np.where(prismatic, TRACKING_LOST / TRACKING_LOST_M, 1.0)
    with np.errstate(invalid="ignore"):
        err = np.nanmax(np.abs(Q - Qp), axis=1) if finite.any() else np.full(K, np.inf)
        lost_err = np.nanmax(np.abs(Q - Qt) * lost_scale, axis=1) if finite.any() else np.full(K, np.inf)
        rmse = float(np.sqrt(np.mean((Q - Qp) ** 2))) if finite.all() else float("inf")
    pos_lim = position_limit_flags(Q, Qt, robot.lower, robot.upper)
    e = np.asarray(effort_at_limit, bool).reshape(len(effort_at_limit), -1)[:K - 1]
    eff_j = np.zeros((K, e.shape[1]), bool)  # sample k + 1 ends step k
    eff_j[1:1 + len(e)] = e
    eff = eff_j.any(axis=1)
    pos_j = position_limit_joints(Q, Qt, robot.lower, robot.upper)
    at_limit = pos_lim | eff if effort_is_limit else pos_lim
    fell = None
    m: dict = {}
    if floating is not None:
        flags = fall_flags(floating["torso_height"], floating["torso_height_plan"], floating["torso_z"], floating["torso_z_plan"],
                           floating["corners"][..., 2], floating["corners_plan"][..., 2])
        flags["initial_posture_does_not_stand"] = np.arange(K) == (0 if not bool(floating.get("start_stands", True))
                                                                     else -1)
        fell = flags["torso_dropped"] | flags["torso_tilted"] | flags["foot_lifted"] | \
            flags["initial_posture_does_not_stand"]
        m["fall_conditions"] = {k: first_true(v) * dt if first_true(v) is not None else None for k, v in flags.items()}
    status, t_fail, reason = execution_status(finite, fell, lost_err, at_limit, dt)
    limited = {}
    for i, name in enumerate(robot.joint_names):
        shares = {"position": float(np.mean(pos_j[:, i]))}
        if effort_is_limit and eff_j.shape[1] == len(robot.joint_names):
            shares["effort"] = float(np.mean(eff_j[:, i]))
        if any(v > 0 for v in shares.values()):
            limited[name] = shares
    if status == "limits":
        worst = sorted(limited.items(), key=lambda kv: -max(kv[1].values()))[:3]
        reason += ": " + ", ".join(f"{j} " + " and ".join(f"{k} {v:.0%}" for k, v in sh.items() if v > 0)
                                   for j, sh in worst)
    if status == "tracking-lost":  # the joint that lost it, in its unit
        k = int(round(t_fail / dt))
        j = int(np.nanargmax(np.abs(Q[k] - Qt[k]) * lost_scale))
        if prismatic.any():
            reason = reason.replace(f"above {TRACKING_LOST} rad",
                                    f"above {TRACKING_LOST} rad ({TRACKING_LOST_M} m on a prismatic joint)")
        aim = "its plan" if X_track is None else "the controller's prediction"
        reason += f": {robot.joint_names[j]} {abs(Q[k, j] - Qt[k, j]):.2f} {'m' if prismatic[j] else 'rad'} from {aim}"
    if status == "fell":
        why = [k.replace("_", " ") for k, t in m["fall_conditions"].items() if t == t_fail]
        reason = f"{reason}: {', '.join(why)}"
    m = {"status": status, "failure_time": t_fail, "reason": reason,
         "via_point_errors": via_point_errors(problem, X),
         "rmse_planned_executed": rmse,
         "max_tracking_error": float(np.max(err)) if finite.all() else float("inf"),
         "max_abs_torque": float(np.nanmax(np.abs(tau))) if tau.size else 0.0,
         "torque_saturation": float(np.mean(e.any(axis=1))) if len(e) else 0.0,
         "effort_clamped_fraction": (float(np.sum(np.asarray(effort_clamped, bool)[:K - 1])) / K
                                     if effort_clamped is not None else 0.0),
         "position_limit_fraction": float(np.mean(pos_lim)),
         "limits_fraction": float(np.mean(at_limit)),
         "limited_joints": limited,
         "task": task_verdict(task_errors(problem, X)),
         "thresholds": {**used_thresholds(floating is not None),
                        **({"tracking_lost_m": TRACKING_LOST_M} if prismatic.any() else {})}, **m}
    if floating is not None:
        margin = floating["cog_margin"]
        with np.errstate(invalid="ignore"):
            inside = margin > 0
        m.update(stood=status != "fell" and status != "diverged",
                 cog_inside_fraction=float(np.mean(inside)),
                 cog_min_margin=float(np.nanmin(margin)) if np.isfinite(margin).any() else float("nan"),
                 **zmp_metrics(floating.get("zmp_margin")),
                 r_sole_drift=_relative_sole_drift(robot, X),
                 sole_world_drift=_world_drift(floating["corners"]))
    return m


ZMP_EDGE = 0.005  # m: a ZMP closer than this to the contact polygon's edge counts as at the edge (tipping)


def zmp_metrics(zmp_margin: np.ndarray | None) -> dict:
    """The executed ZMP against the contact polygon, over the samples where it exists (a ground force;
    none at t = 0): ``zmp_min_margin`` (m), ``zmp_edge_fraction`` (share of them within ``ZMP_EDGE`` of
    the edge or outside: the feet about to tip). Empty without ZMP data."""
    if zmp_margin is None:
        return {}
    zm = np.asarray(zmp_margin, float)
    zm = zm[np.isfinite(zm)]
    if not zm.size:
        return {"zmp_min_margin": float("nan"), "zmp_edge_fraction": float("nan")}
    return {"zmp_min_margin": float(zm.min()), "zmp_edge_fraction": float(np.mean(zm < ZMP_EDGE))}


def plan_beyond_limits(Q_plan: np.ndarray, lower: np.ndarray, upper: np.ndarray, names) -> dict[str, float]:
    """The joints a plan ``Q_plan (K, n)`` (rad) takes past their position range, each with its largest
    excess (rad): ``{name: excess}``, only the joints that leave their range (a plan made without joint
    limits may ask for what the robot cannot do)."""
    Q = np.asarray(Q_plan, float)
    excess = np.max(np.maximum(Q - upper, lower - Q), axis=0)
    return {names[i]: float(excess[i]) for i in np.flatnonzero(excess > 0)}


def cog_via_point_margins(problem, poly: np.ndarray) -> dict[str, float]:
    """Each CoG via-point's target ground projection against the support polygon ``poly (k, 2)`` (the feet
    at the start): ``{"<term>@<t>": signed margin (m), > 0 inside}``; how near the plan's request lies to the
    feet's edge (a stabilizer holds the CoG some margin inside)."""
    from raico.planning.costs import ViaPoint
    from raico.plants.taskmaps import CenterOfMass

    out = {}
    for term in problem.state_terms:
        taskmap = getattr(term, "taskmap", None)   # a state term has none
        axes = list(getattr(taskmap, "axes", []))
        if isinstance(term, ViaPoint) and isinstance(taskmap, CenterOfMass) and 0 in axes and 1 in axes:
            xy = term.target[[axes.index(0), axes.index(1)]]
            for t in np.flatnonzero(term.active(np.arange(problem.T + 1))):
                out[f"{term.name}@{t}"] = signed_margin(poly, xy)
    return out


LIFT = 0.02  # m, single support: the right sole's lowest corner at least this high to count as lifted


def single_support_lift(corners: np.ndarray, lift_from: int) -> dict:
    """Single support (a ``--balance single`` plan): ``r_sole_lift`` (m), the right sole's lowest corner
    height, the least over the samples from the plan's lift step ``lift_from`` to the end (``corners``
    ``(K, 2, 4, 3)`` world m; -inf where a sample is not finite), and ``lifted`` (at least ``LIFT``)."""
    z = corners[lift_from:, 1, :, 2]
    if not z.size:
        return {"r_sole_lift": float("nan"), "lifted": False}
    low = float(np.min(z)) if np.all(np.isfinite(z)) else float("-inf")
    return {"r_sole_lift": low, "lifted": bool(low >= LIFT)}


def _relative_sole_drift(robot, X: np.ndarray) -> float:
    """How far (m) the swing sole (the right one) moved relative to the stance sole, start to end (fixed-base
    kinematics of the executed joint angles: the stance sole is the fixed model's world frame)."""
    n = X.shape[1] // 2
    if not np.all(np.isfinite(X[[0, -1]])):
        return float("inf")
    sole = robot.plant.GetFrameByName(robot.feet[1])
    ctx = robot.plant.CreateDefaultContext()
    ends = []
    for k in (0, len(X) - 1):
        robot.plant.SetPositions(ctx, robot.to_plant_q(X[k, :n]))
        ends.append(sole.CalcPoseInWorld(ctx).translation())
    return float(np.linalg.norm(ends[1] - ends[0]))


def _world_drift(corners: np.ndarray) -> list[float]:
    """Per sole (left, right): how far (m) its centre moved on the ground, start to end."""
    c = corners.mean(axis=2)  # (K, 2, 3)
    if not np.all(np.isfinite(c[[0, -1]])):
        return [float("inf")] * 2
    return [float(np.linalg.norm(c[-1, s] - c[0, s])) for s in range(c.shape[1])]
