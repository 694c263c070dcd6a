"""Floating execution: a robot free on its soles with contact (``raico.plants.floating``), its plan tracked by
Drake's joint PD plus an inverse-dynamics feed-forward (``pd``) or by the whole-body stabilizer (``wbc``,
``raico.stages.execute.wbc``), or the stabilizer tracking a receding-horizon controller's window (``mpc``: the
plan's problem re-solved every planning step from the measured joint state, ``raico.planning.mpc``), from the
plan's start tipped onto its soles or a standing start, optionally pushed (docs/execution.md, docs/mpc.md)."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from raico.plants.polygons import convex_hull
from raico.plants.robots import Robot, robot_for
from raico.stages.evaluate.metrics import (
    cog_via_point_margins,
    execution_metrics,
    padded_polygons,
    plan_beyond_limits,
    point_margins,
    single_support_lift,
    support_polygons,
)
from raico.stages.execute.config import ExecuteConfig, ExecuteOutput, initial_q
from raico.stages.plan.balance import cog_margins


def feedforward(robot: Robot, X_plan: np.ndarray, U_plan: np.ndarray, control_kind: str) -> np.ndarray:
    """Feed-forward generalized forces ``(T, n_plant)`` (fixed-base plant velocity order, N m):
    inverse dynamics of the fixed-base model along the plan (acceleration plans) or the planned
    torques shared among coupled joints (torque plans)."""
    from pydrake.multibody.tree import MultibodyForces_

    P, n = robot.P, robot.n_q
    if control_kind != "acceleration":
        split = P / np.maximum(P.sum(axis=0), 1.0)
        return U_plan @ split.T
    plant = robot.plant
    ctx = plant.CreateDefaultContext()
    forces = MultibodyForces_[float](plant)
    out = np.empty((len(U_plan), plant.num_velocities()))
    for k, u in enumerate(U_plan):
        plant.SetPositions(ctx, P @ X_plan[k, :n])
        plant.SetVelocities(ctx, P @ X_plan[k, n:])
        plant.CalcForceElementsContribution(ctx, forces)
        out[k] = plant.CalcInverseDynamics(ctx, P @ u, forces)
    return out


def planned_stance(robot: Robot, X_plan: np.ndarray, spec) -> dict[str, np.ndarray]:
    """The plan on the fixed-base model (stance sole at the world origin): torso height and z axis,
    sole corner positions ``(T+1, 2, k, 3)`` (``spec``: the robot's facts: feet, sole, stand)."""
    from raico.plants.floating import sole_corners_local

    plant, n = robot.plant, robot.n_q
    ctx = plant.CreateDefaultContext()
    torso = plant.GetBodyByName(spec.stand.torso)
    K = len(X_plan)
    out = {"torso_height_plan": np.full(K, np.nan), "torso_z_plan": np.full((K, 3), np.nan),
           "corners_plan": np.full((K, 2, len(spec.sole), 3), np.nan)}
    local = sole_corners_local(spec)
    for k in range(K):
        if not np.all(np.isfinite(X_plan[k])):
            continue
        plant.SetPositions(ctx, robot.to_plant_q(X_plan[k, :n]))
        Xt = plant.EvalBodyPoseInWorld(ctx, torso)
        out["torso_height_plan"][k] = Xt.translation()[2]
        out["torso_z_plan"][k] = Xt.rotation().matrix()[:, 2]
        for s, name in enumerate(spec.feet):
            Xs = plant.GetFrameByName(name).CalcPoseInWorld(ctx)
            out["corners_plan"][k, s] = local @ Xs.rotation().matrix().T + Xs.translation()
    return out


def execute_floating(cfg: ExecuteConfig, desc: dict, plan: dict, problem, rng, progress, planning=None
                     ) -> ExecuteOutput:
    """The plan tracked on the floating robot (docs/execution.md): the start state and the
    reference, the simulator with its controller, the simulation sampled at every planning step, then
    the arrays and metrics of the rollout. ``planning``: with ``--controller mpc``, the plan's planning
    problem as a function of the start posture (``q0 (n_q,)`` rad)."""
    from raico.plants.floating import load_floating

    if cfg.controller == "mpc" and cfg.start is None:
        cfg = dataclasses.replace(cfg, start="standing")  # above the stabilizer, which needs both soles down
    spec = robot_for(desc).spec
    dt, T, step = float(desc["dt"]), int(desc["T"]), spec.time_step
    sub = int(round(dt / step))
    if abs(sub * step - dt) > 1e-9 or sub < 1:
        raise ValueError(f"the planning step {dt} s is not a multiple of the plant step {step} s")
    free = load_floating(spec, pd=cfg.controller == "pd")  # the stabilizer commands torques only: no PD actuators
    fixed = free.fixed
    X_plan, qp0, stance, tilt = _floating_start(cfg, desc, plan, free, rng)
    ff = feedforward(fixed, X_plan, np.asarray(plan["U"], float), desc["control_kind"])[:, free.act_fixed_idx]
    lift_from = _lift_step(desc)  # a single-support plan's lift step (None: both soles stay down)
    mpc = _floating_mpc(cfg, plan, X_plan, free.planning_q(qp0), planning, dt, step) if cfg.controller == "mpc" else None
    run = _FloatingRun(free, cfg, X_plan, np.asarray(plan["X"], float), dt, problem, lift_from, qp0, ff[0], mpc)
    log = _FloatingLog.empty(T + 1, fixed.n_q, free.plant.num_positions(), len(spec.sole))
    wall = time.perf_counter()
    applied, asked, U_log = run.simulate(log, ff, cfg.process_noise, rng, T, sub, progress)
    wall = time.perf_counter() - wall
    if run.stab is not None:
        _stabilizer_commands(run.stab, applied, asked, dt, step)
    aim = None
    if mpc is not None:  # an MPC run is judged against the controller's own predictions, as on a fixed base
        from raico.stages.execute.fixed import mpc_aim

        aim = mpc_aim(mpc, X_plan, 1)
    arrays, metrics, tau, at_limit = _floating_results(free, problem, plan, X_plan, log, applied, asked, dt, tilt,
                                                    stance, lift_from, run.stab, aim)
    extra = {}
    if mpc is not None:
        from raico.stages.execute.fixed import _mpc_metrics

        metrics.update(_mpc_metrics(mpc, dt), controller="mpc",
                       mpc_real_time_factor=float(np.isfinite(log.X).all(axis=1).sum() - 1) * dt / wall)
        extra = mpc.log.arrays()
    return ExecuteOutput(times=np.arange(T + 1) * dt, X=log.X, U=U_log, tau=tau, X_plan=X_plan, metrics=metrics,
                         effort_at_limit=at_limit, floating=arrays, problem=problem, robot=fixed, mpc=extra)


def _floating_mpc(cfg: ExecuteConfig, plan: dict, X_plan: np.ndarray, q_start: np.ndarray, planning, dt: float,
                  step: float):
    """The receding-horizon controller above the stabilizer: the plan's problem rebuilt from the executed start
    posture ``q_start (n_q,)`` (the planning model, stance sole fixed; its terms relative to the start made
    relative to it), warm-started from the joint reference ``X_plan`` (the plan shifted by the start
    projection: its controller's offsets shifted with it). One tick per planning step. The problem's final
    target costs the window only once the problem's end is inside it (``receding_end=False``): at the
    receding end it would ask the window's last step for the start's CoG one step after a via-point's
    (docs/mpc.md, "The Nao"). ``--window-posture`` / ``--window-damping``: a state term at every window step
    on the joints' distance from ``q_start`` and on their velocities (the plan is made without it); with
    ``--window-target plan`` on their distance from the joint reference's state at each step's absolute time
    (``X_plan``: a target per step, moving with the window)."""
    from raico.planning.mpc import MPC

    if cfg.period is not None and abs(cfg.period - dt) > 1e-12:
        raise ValueError(f"--period {cfg.period:g} s: a floating robot's MPC ticks once per planning step ({dt:g} s), "
                         "its window handed to the stabilizer")
    if planning is None:
        raise ValueError("--controller mpc needs the plan's planning problem")
    problem = planning(q_start)
    if cfg.window_posture > 0 or cfg.window_damping > 0:  # the window holds the standing start or the plan
        problem = dataclasses.replace(problem, state_terms=[*problem.state_terms, _window_hold(cfg, q_start, X_plan)])
    horizon = cfg.mpc_horizon(problem.T)
    if horizon > problem.T:
        raise ValueError(f"--horizon {horizon} is longer than the problem's {problem.T} steps")
    if cfg.window_lead + 2 > horizon:
        raise ValueError(f"--window-lead {cfg.window_lead}: the stabilizer reads three of the window's states from "
                         f"it on, past the horizon's {horizon} steps")
    mpc = MPC(problem, horizon, cfg.solver, None, iterations=cfg.iterations_per_tick, budget=dt, ticks=problem.T,
              keep_predictions=True, receding_end=cfg.receding_end("fixed"))
    O = np.asarray(plan["O"], float)
    shift = X_plan[0] - np.asarray(plan["X"], float)[0]   # the start projection (constant along the plan)
    mpc.start_from(X_plan, np.asarray(plan["U"], float), np.asarray(plan["o"], float) - O @ shift, O)
    return mpc


def _window_hold(cfg: ExecuteConfig, q_start: np.ndarray, X_plan: np.ndarray):
    """The window's state term (weights ``--window-posture`` on the joint positions, ``--window-damping`` on
    the velocities, every step): toward the standing start at rest (``--window-target start``), or toward the
    joint reference ``X_plan (T+1, 2 n_q)`` step by step (``plan``: a target per step, its absolute times)."""
    from raico.planning.costs import StateTarget

    n = len(q_start)
    target = np.r_[q_start, np.zeros(n)] if cfg.window_target == "start" else X_plan
    return StateTarget(target, None, 1.0, np.r_[np.full(n, cfg.window_posture), np.full(n, cfg.window_damping)],
                       name="window_hold")


def _floating_start(cfg: ExecuteConfig, desc: dict, plan: dict, free, rng
                    ) -> tuple[np.ndarray, np.ndarray, dict, float]:
    """The start state and the joint reference: ``(X_plan (T+1, 2 n_q), qp0 (free plant's positions),
    stance, tilt rad)``. The plan's ``q0`` plus noise, put on its feet: the standing start projects it to
    a double-support stance (``stance``: its projection's sizes) and shifts the plan by that projection
    (constant over the horizon, so that the plan's held right sole stays flat on the ground to first
    order instead of being pulled back to the uneven pose of the plan's start); the plan's start tilts
    it until it stands (``tilt``)."""
    fixed, n = free.fixed, free.fixed.n_q
    X_plan = np.asarray(plan["X"], float)
    q_start = initial_q(desc, fixed, cfg, rng)
    if cfg.start != "standing":
        qp0, tilt = free.standing_positions(q_start)
        return X_plan, qp0, {}, tilt
    qp0, stance = free.stance_positions(q_start)
    X_plan = X_plan.copy()
    X_plan[:, :n] += free.planning_q(qp0) - q_start
    return X_plan, qp0, stance, 0.0


@dataclass
class _FloatingLog:
    """What is sampled at every planning step (``K = T + 1`` samples, NaN until reached): the state in
    planning coordinates ``X (K, 2 n_q)``, the free plant's positions ``q_free (K, nq)``, the CoG
    ``(K, 3)`` m, the sole corners ``(K, 2, k, 3)`` m, the soles' normal forces ``(K, 2)`` N, the
    zero-moment point ``(K, 2)`` m, the torso's position and z axis ``(K, 3)`` each, and the contact
    points (one ``(k, 3)`` array per sample)."""

    X: np.ndarray
    q_free: np.ndarray
    cog: np.ndarray
    corners: np.ndarray
    force: np.ndarray
    zmp: np.ndarray
    torso_p: np.ndarray
    torso_z: np.ndarray
    points: list

    @classmethod
    def empty(cls, K: int, n: int, nq_free: int, n_corners: int) -> _FloatingLog:
        """A log of ``K`` samples of a plan of ``n`` planning joints on a free plant of ``nq_free`` positions
        (``n_corners`` per sole)."""
        return cls(X=np.full((K, 2 * n), np.nan), q_free=np.full((K, nq_free), np.nan), cog=np.full((K, 3), np.nan),
                   corners=np.full((K, 2, n_corners, 3), np.nan), force=np.full((K, 2), np.nan), zmp=np.full((K, 2), np.nan),
                   torso_p=np.full((K, 3), np.nan), torso_z=np.full((K, 3), np.nan), points=[])

    def sample(self, free, pctx, k: int) -> bool:
        """Sample ``k`` from the plant's context; False (nothing written) when its state is not finite."""
        plant = free.plant
        qp, vp = plant.GetPositions(pctx), plant.GetVelocities(pctx)
        if not (np.all(np.isfinite(qp)) and np.all(np.isfinite(vp))):
            return False
        self.X[k] = np.concatenate([free.planning_q(qp), free.planning_v(vp)])
        self.q_free[k] = qp
        self.cog[k] = plant.CalcCenterOfMassPositionInWorld(pctx)
        self.corners[k] = free.sole_corners(pctx)
        # contact results exist after the first plant step; at t = 0 the force is unknown (NaN)
        f, pts = free.contacts(pctx) if k > 0 else (np.full(2, np.nan), np.zeros((0, 3)))
        self.zmp[k] = free.zmp(pctx) if k > 0 else np.nan
        self.force[k] = f
        self.points.append(pts)
        Xt = free.torso_pose(pctx)
        self.torso_p[k], self.torso_z[k] = Xt.translation(), Xt.rotation().matrix()[:, 2]
        return True


class _FloatingRun:
    """The floating robot in Drake's simulator with its controller: Drake's joint PD on the plan plus the
    feed-forward (``pd``), or the whole-body stabilizer (``wbc``, ``stab``), which owns the actuation
    port and takes the process noise on its ``w`` input. Set to ``qp0`` at rest and initialized."""

    def __init__(self, free, cfg: ExecuteConfig, X_plan: np.ndarray, X_made: np.ndarray, dt: float, problem,
                 lift_from: int | None, qp0: np.ndarray, ff0: np.ndarray, mpc=None):
        """``X_plan (T+1, 2 n_q)``: the joint reference; ``X_made``: the plan as made (the stabilizer's CoG and
        frame tasks); ``ff0 (n_act,)`` N m: the first step's feed-forward; ``mpc``: a receding-horizon
        controller whose window the stabilizer tracks (ticked at every planning step), else None."""
        from pydrake.systems.analysis import Simulator

        self.free, self.X_plan, self.dt, self.mpc, self.lead = free, X_plan, dt, mpc, cfg.window_lead
        plant, fixed, n = free.plant, free.fixed, free.fixed.n_q
        self.wbc = cfg.controller in ("wbc", "mpc")
        self.stab = None
        if self.wbc:
            from raico.stages.execute.wbc import make_stabilizer

            self.stab = free.builder.AddSystem(make_stabilizer(free, X_plan, dt, X_task=X_made,
                                                               frame_maps=_frame_tasks(problem),
                                                               swing=_swing_task(lift_from, fixed)))
            free.builder.Connect(plant.get_state_output_port(), self.stab.get_input_port(0))
            free.builder.Connect(plant.get_generalized_contact_forces_output_port(free.model), self.stab.contact_port)
            free.builder.Connect(self.stab.get_output_port(0), plant.get_actuation_input_port())
        if cfg.push:
            from raico.stages.execute.fixed import _pusher

            pusher = free.builder.AddSystem(_pusher(free, cfg.pushes()))
            free.builder.Connect(pusher.get_output_port(0), plant.get_applied_spatial_force_input_port())
        self.sim = Simulator(free.builder.Build())
        self.pctx = plant.GetMyMutableContextFromRoot(self.sim.get_mutable_context())
        self.sctx = self.stab.GetMyMutableContextFromRoot(self.sim.get_mutable_context()) if self.wbc else None
        plant.SetPositions(self.pctx, qp0)
        plant.SetVelocities(self.pctx, np.zeros(plant.num_velocities()))
        self.n_act = len(free.effort)
        self.desired_port = plant.get_desired_state_input_port(free.model)
        self.actuation_port = plant.get_actuation_input_port()
        self.set_desired(np.concatenate([free.A @ np.clip(X_plan[0, :n], fixed.lower, fixed.upper),
                                         free.A @ X_plan[0, n:]]))
        self.set_actuation(ff0, np.zeros(self.n_act))
        self.sim.Initialize()

    def set_desired(self, xd: np.ndarray) -> None:
        """The PD's desired actuated state ``(2 n_act,)``; the stabilizer drives torques only (Drake's PD
        actuators stay off, their port unconnected)."""
        if not self.wbc:
            self.desired_port.FixValue(self.pctx, xd)

    def set_actuation(self, u: np.ndarray, w: np.ndarray) -> None:
        """Feed-forward ``u`` plus noise ``w`` (n_act,) N m; with the stabilizer, which owns the actuation
        port and has no feed-forward, the noise is added to its held command (and the sum clamped at the
        effort limits, as the plant clamps the PD's total)."""
        if self.wbc:
            self.stab.noise_port.FixValue(self.sctx, w)
        else:
            self.actuation_port.FixValue(self.pctx, u + w)

    def simulate(self, log: _FloatingLog, ff: np.ndarray, noise: float, rng, T: int, sub: int, progress
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Run the ``T`` planning steps (``sub`` plant steps each), sampled into ``log``, until the end or a
        non-finite state or a simulator failure. Returns the torques the plant applied ``(T, n_act)`` N m,
        the controller's command without the noise (``asked``, the PD's here; the stabilizer's is filled in
        afterwards) and the planning controls ``(T, n_q)`` (NaN where not reached)."""
        stand = self.free.spec.stand
        kp, kd, step = stand.value("gains", "kp"), stand.value("gains", "kd"), self.free.time_step

        free, plant, pctx, X_plan, dt, n_act = self.free, self.free.plant, self.pctx, self.X_plan, self.dt, self.n_act
        fixed, n, Aq = free.fixed, free.fixed.n_q, free.A
        applied = np.full((T, n_act), np.nan)
        asked = np.full((T, n_act), np.nan)  # the controller's command without the process noise, unclamped
        U_log = np.full((T, n), np.nan)
        act_q, act_v = free.joint_idx[free.act_fixed_idx], free.joint_vidx[free.act_fixed_idx]
        ok = log.sample(free, pctx, 0)
        for k in range(T):
            if not ok:
                break
            w = noise * rng.standard_normal(n_act) if noise > 0 else np.zeros(n_act)
            self.set_actuation(ff[k], w)
            U_log[k] = (ff[k] + w) @ Aq  # planning coordinates
            q_a, q_b, v_b = X_plan[k, :n], X_plan[k + 1, :n], X_plan[k + 1, n:]
            if self.mpc is not None:  # the window from the measured state, the stabilizer's reference from step k on
                self.mpc.tick(log.X[k])
                self.stab.reference.follow(k, self.mpc.X[self.lead:])
            try:
                if self.wbc:  # the stabilizer updates itself (its own period): one advance per planning step
                    self.sim.AdvanceTo((k + 1) * dt)
                for s in range(0 if self.wbc else sub):
                    a = s / sub
                    q_d = np.clip((1 - a) * q_a + a * q_b, fixed.lower, fixed.upper)  # never past a limit
                    self.set_desired(np.concatenate([Aq @ q_d, Aq @ v_b]))
                    self.sim.AdvanceTo(k * dt + (s + 1) * step)
            except RuntimeError:
                break
            applied[k] = plant.get_net_actuation_output_port().Eval(pctx)[:n_act]
            if self.wbc:  # the stabilizer's held torques plus the noise, clamped (planning coordinates)
                U_log[k] = applied[k] @ Aq
            else:  # the PD law at the step's end state (SAP's implicit PD evaluates it there) plus the feed-forward
                asked[k] = (kp * (Aq @ q_d - plant.GetPositions(pctx)[act_q])
                            + kd * (Aq @ v_b - plant.GetVelocities(pctx)[act_v]) + ff[k])
            ok = log.sample(free, pctx, k + 1)
            if progress is not None and (k + 1) % 10 == 0:
                progress(k + 1, T)
        return applied, asked, U_log


def _stabilizer_commands(stab, applied: np.ndarray, asked: np.ndarray, dt: float, time_step: float) -> None:
    """``asked (T, n_act)`` filled in place with the stabilizer's command (N m, before the noise) that the
    last plant step of each planning step applied: Drake's discrete updates at one time are simultaneous,
    so a plant step (``time_step`` s) starting at an update's time still applies the command held before
    it. Steps not reached (``applied`` not finite) stay NaN."""
    T, n_act = asked.shape
    t_cmd = np.array([c[0] for c in stab.commands])
    u_cmd = np.array([c[1] for c in stab.commands]).reshape(-1, n_act)
    i = np.searchsorted(t_cmd, np.arange(1, T + 1) * dt - time_step - 1e-9) - 1  # (T,) the last update before
    use = (i >= 0) & np.isfinite(applied).all(axis=1)
    asked[use] = u_cmd[i[use]]


def _floating_results(free, problem, plan: dict, X_plan: np.ndarray, log: _FloatingLog, applied: np.ndarray,
                      asked: np.ndarray, dt: float, tilt: float, stance: dict, lift_from: int | None, stab,
                      X_track: np.ndarray | None = None) -> tuple[dict, dict, np.ndarray, np.ndarray]:
    """The floating robot's arrays of the rollout, the execution's metrics, the applied torques in planning
    coordinates ``tau (T, n_q)`` N m and the effort-limit flags ``(T, n_q)``. ``X_track (T+1, 2 n_q)``: a
    receding-horizon controller's predictions (``mpc_aim``), what ``tracking-lost`` is judged against (else
    the joint reference ``X_plan``)."""
    from raico.plants.floating import MAX_TIP

    fixed, n = free.fixed, free.fixed.n_q
    K, T = len(log.X), len(applied)
    # an actuator at its effort limit: the controller asks for at least what the motor gives (per planning joint);
    # a motor that clamps the process noise is not the controller's limit (effort_clamped_fraction: the share of
    # samples with any motor clamped, the command plus the noise)
    at_effort = free.effort * (1 - 1e-9)  # N m per actuator: at its limit from here (rounding aside)
    at_limit = (np.abs(asked) >= at_effort) @ free.A > 0  # (T, n_q)
    tau = applied @ free.A  # planning coordinates (the coupled hip: the sum of its two joints)
    polys, margin = support_polygons(log.corners, log.force, log.cog)
    zmp_margin = point_margins(polys, log.zmp)
    planned = planned_stance(fixed, X_plan, free.spec)
    if lift_from is not None and stance:
        # single support: the swing sole's planned heights are those of the plan as made (what the stabilizer
        # tracks once it releases that sole), not of the plan shifted by the start projection
        planned["corners_plan"][:, 1] = planned_stance(fixed, np.asarray(plan["X"], float), free.spec)["corners_plan"][:, 1]
    arrays = {"q_free": log.q_free, "cog": log.cog, "cog_margin": margin, "support": padded_polygons(polys),
           "corners": log.corners, "sole_force": log.force, "contact_points": _padded_points(log.points, K),
           "zmp": log.zmp, "zmp_margin": zmp_margin, "torque_asked": asked,
           "torso_p": log.torso_p, "torso_z": log.torso_z, "torso_height_plan": planned["torso_height_plan"],
           "torso_z_plan": planned["torso_z_plan"], "corners_plan": planned["corners_plan"],
           "start_tilt": np.array(tilt), "start_stands": np.array(tilt < MAX_TIP - 1e-9)}
    if stab is not None:
        arrays["wbc_time"] = np.array([e[0] for e in stab.log])
        arrays["wbc_solve_s"] = np.array([e[1] for e in stab.log])
        arrays["wbc_corner_force"] = np.array([e[2] for e in stab.log]).reshape(-1, 2 * len(free.spec.sole), 3)
    metrics = execution_metrics(problem, log.X, X_plan, tau, fixed, dt, at_limit,
                                floating={**arrays, "torso_height": log.torso_p[:, 2]},
                                effort_clamped=np.any(np.abs(applied) >= at_effort, axis=1), X_track=X_track)
    metrics["start_tilt"] = tilt
    # what the reference asks that the free robot cannot give: joints past their range (the joint reference: the
    # plan, shifted by the start projection on the standing start), CoG via-points near the feet's edge
    metrics["reference_beyond_limits"] = plan_beyond_limits(X_plan[:, :n], fixed.lower, fixed.upper, fixed.joint_names)
    if np.all(np.isfinite(log.corners[0])):
        metrics.update(_reference_cog_metrics(problem, fixed, X_plan, log.corners[0], metrics.get("failure_time"),
                                              dt, T))
    if stance:
        arrays["X_plan_unshifted"] = np.asarray(plan["X"], float)
        metrics.update(start_projection_norm=stance["projection_norm"], start_projection_max=stance["projection_max"],
                       start_cog_margin=stance["cog_margin"], start="standing")
    if stab is not None:
        metrics.update(controller="wbc", wbc_qp_failures=stab.failures, wbc_qp_fallbacks=stab.qp.fallbacks,
                       wbc_limp_time=stab.limp, wbc_qp_relaxed=len(stab.relaxed),
                       wbc_qp_median_s=float(np.median(arrays["wbc_solve_s"])) if len(stab.log) else float("nan"))
    if lift_from is not None:  # single support: how high the right sole was held from the plan's lift step on
        metrics.update(single_support_lift(log.corners, lift_from),
                       wbc_release_time=(stab.released[0] if stab is not None and stab.released else None))
    return arrays, metrics, tau, at_limit


def _reference_cog_metrics(problem, fixed, X_plan: np.ndarray, corners0: np.ndarray, failure_time: float | None,
                           dt: float, T: int) -> dict:
    """The CoG via-points' and the joint reference's CoG margins (m) against the feet's polygon at the start
    (``corners0 (2, k, 3)`` m): the least margin and its time (s), and the margin where the run failed."""
    feet = convex_hull(corners0[:, :, :2].reshape(-1, 2))
    out: dict[str, Any] = {"cog_via_point_margins": cog_via_point_margins(problem, feet)}
    ref_margin = cog_margins(fixed, X_plan, feet)
    k_min = int(np.nanargmin(ref_margin))
    out.update(reference_cog_min_margin=float(ref_margin[k_min]), reference_cog_min_margin_time=k_min * dt)
    if failure_time is not None:  # where the reference's CoG was when the run failed
        k_fail = min(int(round(failure_time / dt)), T)
        out["reference_cog_margin_at_failure"] = float(ref_margin[k_fail])
    return out


def _lift_step(desc: dict) -> int | None:
    """The first step of the plan's right-sole lift (a ``--balance single`` plan), else None."""
    if (desc.get("balance") or {}).get("mode") != "single":
        return None
    term = next((t for t in desc["terms"] if t["name"] == "r_sole_lift"), None)
    return None if term is None else int(term["times"]["from"])


def _swing_task(lift_from: int | None, fixed):
    """The right sole's corners (``FramePoints`` of the fixed model) the stabilizer tracks once it releases
    that sole, for a single-support plan; None (both soles held) otherwise."""
    if lift_from is None:
        return None
    from raico.plants.floating import sole_corners_local
    from raico.plants.taskmaps import FramePoints

    return FramePoints(fixed, fixed.feet[1], sole_corners_local(fixed.spec), name="r_sole_swing")


def _frame_tasks(problem) -> list:
    """The frame-point maps of the problem's via-points (``FramePoints``), the held right sole left
    out (the stabilizer holds both soles by contact)."""
    from raico.planning.costs import ViaPoint
    from raico.plants.taskmaps import FramePoints

    return [t.taskmap for t in problem.state_terms if isinstance(t, ViaPoint) and isinstance(t.taskmap, FramePoints)
            and not t.name.startswith("r_sole")]


def _padded_points(points: list[np.ndarray], K: int) -> np.ndarray:
    """Per-sample contact points as one ``(K, kmax, 3)`` array, NaN-padded (m)."""
    kmax = max([len(p) for p in points] + [1])
    out = np.full((K, kmax, 3), np.nan)
    for k, p in enumerate(points):
        out[k, :len(p)] = p
    return out
